"""Package discovery and package.xml parsing by catkin_pkg (as rosdep and colcon), conditions
evaluated for the ROS version and distribution, and key selection."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from docker_ros.in_image.runtime.packages import (
    blacklisted_dependents,
    condition_context,
    environment_packages,
    find_package_dirs,
    find_packages,
    package_search_dirs,
    parse_package_xml,
    select_keys,
)
from docker_ros.in_image.runtime.process import HOST_EXTRA
from docker_ros.in_image.runtime.workspace import StepError, Workspace

SRC = Path(__file__).resolve().parents[2] / "src"

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


def manifest(name, **depends):
    """A valid format 3 package.xml with the given dependency tags."""
    return (
        f"<package format='3'><name>{name}</name><version>1.0.0</version>"
        "<description>d</description><maintainer email='m@example.com'>m</maintainer>"
        "<license>MIT</license>"
        + "".join(f"<{tag}>{key}</{tag}>" for tag, keys in depends.items() for key in keys)
        + "</package>"
    )


def pkg(name, **depends):
    return parse_package_xml(manifest(name, **depends), {})


def test_format3_with_conditions_for_ros2():
    package = parse_package_xml(FORMAT3, condition_context("humble", {"X": "y"}))
    assert package.name == "talker" and package.format == 3
    assert package.build_type == "ament_cmake"
    assert package.depends["buildtool_depends"] == ("ament_cmake",)
    # `depend` is a build, build export and exec dependency (catkin_pkg's lists)
    assert package.depends["exec_depends"] == ("python3-yaml", "newer", "std_msgs")
    assert "std_msgs" in package.depends["build_depends"]
    assert package.depends["doc_depends"] == ("doxygen",)


def test_format3_for_ros1_without_distro():
    # Debian's ROS 1: no ROS_DISTRO; ROS_VERSION defaults to 1.
    package = parse_package_xml(FORMAT3, condition_context(None, {}))
    assert package.depends["buildtool_depends"] == ("catkin",)
    assert package.build_type == "catkin"
    assert "newer" not in package.depends["exec_depends"]


def test_format1_run_depend():
    package = parse_package_xml(FORMAT1, {})
    assert package.format == 1 and package.build_type == "catkin"
    assert package.depends["exec_depends"] == ("roscpp", "rospy")
    assert select_keys([package], "exec") == {"roscpp": ["old_pkg"], "rospy": ["old_pkg"]}
    assert sorted(select_keys([package], "all")) == ["catkin", "roscpp", "rospy", "rostest"]


@pytest.mark.parametrize(("text", "reason"), [
    ("<package><name>x</name>", "invalid XML"),
    ("<manifest/>", "package"),
    (manifest("x").replace("<version>1.0.0</version>", ""), '"version"'),
    (manifest("x", exec_depend=["a"]).replace("<exec_depend>",
                                              "<exec_depend condition='$ROS_VERSION =='>"),
     "condition"),
])
def test_invalid_package_xml_is_a_value_error_with_the_reason(text, reason):
    with pytest.raises(ValueError, match=reason):
        parse_package_xml(text, {})


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


def package_tree(root: Path) -> None:
    """Packages where colcon looks and where it does not."""
    for path in ["a", "b/inner", "ignored/c", "x/build/d", "e/.git/f", ".hidden/g",
                 "colcon/install/h"]:
        (root / path).mkdir(parents=True)
        (root / path / "package.xml").write_text(manifest(path.split("/")[-1]))
    (root / "b" / "package.xml").write_text(manifest("b"))  # b/inner is inside package b
    (root / "ignored" / "COLCON_IGNORE").write_text("")
    (root / "colcon" / "install" / "COLCON_IGNORE").write_text("")  # colcon writes one there


def test_find_package_dirs_follows_colcon_rules(tmp_path):
    package_tree(tmp_path)
    (tmp_path / "link_to_a").symlink_to(tmp_path / "a", target_is_directory=True)
    (tmp_path / "loop").symlink_to(tmp_path, target_is_directory=True)
    found = [p.relative_to(tmp_path).as_posix() for p in find_package_dirs(tmp_path)]
    # a folder named build is searched (only colcon's own carry an ignore marker), hidden ones
    # are not; each real folder once
    assert found == ["a", "b", "x/build/d"]


@pytest.mark.host
def test_find_package_dirs_finds_what_colcon_lists(tmp_path):
    root = tmp_path / "src"
    package_tree(root)
    (root / "link_to_a").symlink_to(root / "a", target_is_directory=True)
    (root / "loop").symlink_to(root, target_is_directory=True)
    listed = subprocess.run(["colcon", "--log-base", os.devnull, "list", "--paths-only",
                             "--base-paths", str(root)], capture_output=True, text=True,
                            check=True, cwd=tmp_path).stdout.split()
    assert [str(p) for p in find_package_dirs(root)] == sorted(listed)


def test_what_runs_before_prepare_sees_every_manifest_discovery_reads(tmp_path):
    package_tree(tmp_path)
    (tmp_path / "loop").symlink_to(tmp_path, target_is_directory=True)
    searched = set(package_search_dirs(tmp_path))
    assert set(find_package_dirs(tmp_path)) <= searched
    assert tmp_path / "ignored" in searched  # the marker itself is read, too
    assert not any(part.startswith(".") for p in searched for part in p.parts[-1:])


def test_invalid_manifest_names_the_file_and_the_reason(tmp_path):
    ws = Workspace(tmp_path / "ws")
    (ws.target / "good").mkdir(parents=True)
    (ws.target / "good" / "package.xml").write_text(manifest("good"))
    (ws.target / "bad").mkdir()
    (ws.target / "bad" / "package.xml").write_text(manifest("bad").replace(
        "<license>MIT</license>", ""))
    with pytest.raises(StepError) as err:
        find_packages(ws, object(), step="rosdep", environ={})
    assert err.value.message == ("src/target/bad/package.xml: The package node must contain at "
                                 "least one \"license\" tag")


def test_without_catkin_pkg_the_error_names_the_host_extra(tmp_path):
    """A real interpreter without catkin_pkg (-I -S: no site-packages), as a host without the
    `host` extra."""
    ws = Workspace(tmp_path / "ws")
    (ws.target / "a").mkdir(parents=True)
    (ws.target / "a" / "package.xml").write_text(manifest("a"))
    code = (f"import sys; sys.path.insert(0, {str(SRC)!r})\n"
            "from docker_ros.in_image.runtime.packages import find_packages\n"
            "from docker_ros.in_image.runtime.workspace import StepError, Workspace\n"
            "try:\n"
            f"    find_packages(Workspace({str(ws.root)!r}), object(), step='blacklist')\n"
            "except StepError as exc:\n"
            "    print(exc.message)\n")
    out = subprocess.run([sys.executable, "-I", "-S", "-c", code], capture_output=True,
                         text=True, check=True).stdout
    assert out.strip() == ("the Python module catkin_pkg (part of rosdep) is missing; on the "
                           f"host the steps need vcstool, rosdep and colcon: {HOST_EXTRA}")


def named_manifest(folder: Path, name: str) -> None:
    folder.mkdir(parents=True)
    (folder / "package.xml").write_text(f'<package format="3"><name>{name}</name></package>')


def test_environment_packages_are_those_rosdep_ignore_src_leaves_out(tmp_path):
    """ROS_PACKAGE_PATH folders crawled as catkin does (the name is the manifest's, not the
    folder's; nothing inside a package or below an ignore marker), and the ament index of
    each AMENT_PREFIX_PATH prefix; folders that do not exist are passed over."""
    share = tmp_path / "opt/ros/noetic/share"
    named_manifest(share / "opt_hello", "opt_hello")
    named_manifest(share / "folder_of_another_name", "renamed_pkg")
    named_manifest(share / "opt_hello" / "test" / "inner", "inner_pkg")  # inside a package
    named_manifest(share / "ignored" / "pkg", "ignored_pkg")
    (share / "ignored" / "CATKIN_IGNORE").touch()
    (share / "broken").mkdir()
    (share / "broken" / "package.xml").write_text("<package")  # passed over, as rosdep does
    index = tmp_path / "opt/ros/jazzy/share/ament_index/resource_index/packages"
    index.mkdir(parents=True)
    (index / "rclcpp").touch()
    (index / "company_msgs").touch()
    env = {"ROS_PACKAGE_PATH": f"{share}:{tmp_path / 'missing'}",
           "AMENT_PREFIX_PATH": f"{tmp_path / 'opt/ros/jazzy'}:{tmp_path / 'no-prefix'}"}
    assert environment_packages(env) == ["company_msgs", "opt_hello", "rclcpp", "renamed_pkg"]
    assert environment_packages({}) == []
