"""package.xml parsing, conditions (checked against catkin_pkg) and key selection."""

import pytest
from catkin_pkg.condition import evaluate_condition as catkin_evaluate

from docker_ros.runtime.packages import (
    blacklisted_dependents,
    condition_context,
    evaluate_condition,
    find_package_dirs,
    parse_package_xml,
    select_keys,
)

FORMAT3 = """<?xml version="1.0"?>
<?xml-model href="http://download.ros.org/schema/package_format3.xsd"?>
<package format="3">
  <name>talker</name>
  <version>1.0.0</version>
  <description>d</description>
  <maintainer email="ros@example.com">m</maintainer>
  <license>MIT</license>
  <buildtool_depend condition="$ROS_VERSION == 1">catkin</buildtool_depend>
  <buildtool_depend condition="$ROS_VERSION == 2">ament_cmake</buildtool_depend>
  <depend>std_msgs</depend>
  <build_depend>libboost-dev</build_depend>
  <build_export_depend>eigen</build_export_depend>
  <exec_depend condition="$ROS_PYTHON_VERSION == 3">python3-yaml</exec_depend>
  <exec_depend condition="$ROS_PYTHON_VERSION == 2">python-yaml</exec_depend>
  <test_depend>gtest</test_depend>
  <doc_depend>doxygen</doc_depend>
  <exec_depend condition="$ROS_DISTRO == humble or ($ROS_DISTRO != noetic and $X == y)">
    newer
  </exec_depend>
  <export>
    <build_type condition="$ROS_VERSION == 1">catkin</build_type>
    <build_type condition="$ROS_VERSION == 2">ament_cmake</build_type>
  </export>
</package>
"""

FORMAT1 = """<package>
  <name>old_pkg</name>
  <version>0.1.0</version>
  <description>d</description>
  <maintainer email="ros@example.com">m</maintainer>
  <license>BSD</license>
  <buildtool_depend>catkin</buildtool_depend>
  <build_depend>roscpp</build_depend>
  <run_depend>roscpp</run_depend>
  <run_depend>rospy</run_depend>
  <test_depend>rostest</test_depend>
</package>
"""

CONDITIONS = [
    "$ROS_VERSION == 2",
    "$ROS_VERSION != 2",
    "$ROS_VERSION == 1 or $ROS_VERSION == 2",
    "$ROS_VERSION == 2 and $ROS_DISTRO == humble",
    "$ROS_VERSION == 1 or $ROS_VERSION == 2 and $ROS_DISTRO == foxy",
    "($ROS_VERSION == 1 or $ROS_VERSION == 2) and $ROS_DISTRO == foxy",
    "$ROS_DISTRO >= humble",
    "$ROS_DISTRO < foxy",
    "$UNSET == ''",
    '$ROS_DISTRO == "humble"',
    "humble == $ROS_DISTRO",
    "$ROS_PYTHON_VERSION <= 2",
    "$A-B == x",
]
CONTEXTS = [
    {"ROS_VERSION": "2", "ROS_DISTRO": "humble", "ROS_PYTHON_VERSION": "3"},
    {"ROS_VERSION": "1", "ROS_DISTRO": "noetic", "ROS_PYTHON_VERSION": "3"},
    {"ROS_VERSION": "2", "ROS_DISTRO": "foxy"},
    {},
]


@pytest.mark.parametrize("condition", CONDITIONS)
@pytest.mark.parametrize("context", CONTEXTS)
def test_conditions_evaluate_like_catkin_pkg(condition, context):
    try:
        expected = catkin_evaluate(condition, context)
    except ValueError:
        with pytest.raises(ValueError):
            evaluate_condition(condition, context)
        return
    assert evaluate_condition(condition, context) is expected


@pytest.mark.parametrize("bad", ["$ROS_VERSION ==", "(ROS == 1", "a b", "== 2", "1 == 2 )"])
def test_bad_conditions_are_errors(bad):
    with pytest.raises(ValueError):
        evaluate_condition(bad, {})


def test_format3_with_conditions_for_ros2():
    ctx = condition_context("humble", {"X": "y"})
    package = parse_package_xml(FORMAT3, ctx)
    assert package.name == "talker" and package.format == 3
    assert package.build_type == "ament_cmake"
    assert package.depends["buildtool_depend"] == ("ament_cmake",)
    assert package.depends["exec_depend"] == ("python3-yaml", "newer")
    assert package.depends["depend"] == ("std_msgs",)


def test_format3_for_ros1_without_distro():
    # Debian's ROS 1: no ROS_DISTRO; ROS_VERSION defaults to 1.
    package = parse_package_xml(FORMAT3, condition_context(None, {}))
    assert package.depends["buildtool_depend"] == ("catkin",)
    assert package.build_type == "catkin"
    assert "newer" not in package.depends["exec_depend"]


def test_format1_run_depend():
    package = parse_package_xml(FORMAT1, {})
    assert package.format == 1 and package.build_type == "catkin"
    assert package.depends["run_depend"] == ("roscpp", "rospy")
    assert select_keys([package], "exec") == {"roscpp": ["old_pkg"], "rospy": ["old_pkg"]}
    assert sorted(select_keys([package], "all")) == ["catkin", "roscpp", "rospy", "rostest"]


def test_matches_catkin_pkg_parser():
    from catkin_pkg.package import parse_package_string

    ctx = condition_context("humble", {"X": "y"})
    theirs = parse_package_string(FORMAT3)
    theirs.evaluate_conditions(ctx)
    ours = parse_package_xml(FORMAT3, ctx)
    exec_theirs = sorted(d.name for d in theirs.exec_depends if d.evaluated_condition)
    exec_ours = sorted(ours.depends["exec_depend"] + ours.depends["depend"])
    assert exec_ours == exec_theirs


@pytest.mark.parametrize("text", ["<package><name>x</name>", "<manifest/>", "<package/>"])
def test_invalid_package_xml(text):
    with pytest.raises(ValueError):
        parse_package_xml(text, {})


def pkg(name, **depends):
    text = (
        f"<package format='3'><name>{name}</name>"
        + "".join(f"<{tag}>{key}</{tag}>" for tag, keys in depends.items() for key in keys)
        + "</package>"
    )
    return parse_package_xml(text, {})


def test_select_keys_exec_all_blacklist_and_local_packages():
    packages = [
        pkg(
            "app",
            depend=["lib", "boost"],
            exec_depend=["python3-yaml"],
            test_depend=["gtest"],
            doc_depend=["doxygen"],
            build_depend=["eigen"],
        ),
        pkg("lib", exec_depend=["libfoo"], build_export_depend=["libfoo-dev"]),
        pkg("vendored", exec_depend=["only_vendored"]),
        pkg("user", exec_depend=["vendored"]),
    ]
    assert select_keys(packages, "exec", ["vendored"]) == {
        "boost": ["app"],
        "libfoo": ["lib"],
        "python3-yaml": ["app"],
    }  # the blacklisted package's name is no key: see blacklisted_dependents
    assert blacklisted_dependents(packages, "exec", ["vendored"]) == {"vendored": ["user"]}
    assert blacklisted_dependents(packages, "all", ["lib", "app"]) == {}
    all_keys = select_keys(packages, "all", ["vendored"])
    assert sorted(all_keys) == [
        "boost",
        "eigen",
        "gtest",
        "libfoo",
        "libfoo-dev",
        "python3-yaml",
    ]
    assert "doxygen" not in all_keys  # rosdep leaves doc dependencies out too
    with pytest.raises(ValueError):
        select_keys(packages, "build")


def test_find_package_dirs_respects_ignore_markers_and_nesting(tmp_path):
    for path in ["a", "b/inner", "ignored/c", "x/build/d", "e/.git/f"]:
        (tmp_path / path).mkdir(parents=True)
        (tmp_path / path / "package.xml").write_text("<package/>")
    (tmp_path / "b" / "package.xml").write_text("<package/>")  # b/inner is inside package b
    (tmp_path / "ignored" / "COLCON_IGNORE").write_text("")
    found = [p.relative_to(tmp_path).as_posix() for p in find_package_dirs(tmp_path)]
    assert found == ["a", "b"]
