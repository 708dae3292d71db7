"""ROS installation decisions of the image's prepare stage (the ROS apt paths cannot run here)."""

import pytest

from docker_ros.in_image.runtime.prepare import (
    allow_pip_system_installs,
    distro_problem,
    plan_rmw_installation,
    plan_ros_installation,
    plan_tool_packages,
    ros_package_names,
    ros_present,
)
from docker_ros.in_image.runtime.workspace import StepError


def plan(**kw):
    args = {"ros_installed": False, "disabled": False, "distro": "jazzy",
            "rmw_implementation": "rmw_fastrtps_cpp", "apt_source_version": "1.1.0",
            "os_codename": "noble"}
    args.update(kw)
    return plan_ros_installation(**args)


def test_ros_present_or_disabled_installs_nothing():
    assert plan(ros_installed=True) == []
    assert plan(disabled=True) == []
    assert plan(disabled=True, distro=None) == []


def test_ros2_installation_commands_use_pinned_apt_source_and_rmw():
    commands = plan(distro="jazzy", rmw_implementation="rmw_cyclonedds_cpp")
    download = next(c for c in commands if c[0] == "curl")
    assert download[-1] == (
        "https://github.com/ros-infrastructure/ros-apt-source/releases/download/"
        "1.1.0/ros2-apt-source_1.1.0.noble_all.deb"
    )
    assert ["apt-get", "install", "-y", "/tmp/ros2-apt-source.deb"] in commands
    assert commands[-1][-2:] == ["ros-jazzy-ros-core", "ros-jazzy-rmw-cyclonedds-cpp"]


def test_ros1_uses_ros_apt_source_and_no_rmw():
    commands = plan(distro="noetic", os_codename="focal")
    assert any("ros-apt-source_1.1.0.focal_all.deb" in c[-1] for c in commands)
    assert commands[-1][-1] == "ros-noetic-ros-core"
    assert ros_package_names("noetic", "rmw_fastrtps_cpp") == ["ros-noetic-ros-core"]


def test_missing_ros_without_distro_is_a_clear_error():
    with pytest.raises(StepError, match="ROS_DISTRO"):
        plan(distro=None)


@pytest.mark.parametrize(
    "rmw, package",
    [("rmw_fastrtps_cpp", "ros-humble-rmw-fastrtps-cpp"),
     ("rmw_zenoh_cpp", "ros-humble-rmw-zenoh-cpp"),
     ("rmw_cyclonedds_cpp", "ros-humble-rmw-cyclonedds-cpp")],
)
def test_rmw_package_names(rmw, package):
    assert ros_package_names("humble", rmw)[-1] == package


def test_ros_present_detects_opt_ros_and_debian_ros(tmp_path):
    assert not ros_present(tmp_path)
    (tmp_path / "opt/ros/jazzy").mkdir(parents=True)
    (tmp_path / "opt/ros/jazzy/setup.bash").write_text("")
    assert ros_present(tmp_path, "jazzy")
    debian = tmp_path / "debian"
    (debian / "usr/bin").mkdir(parents=True)
    (debian / "usr/bin/roscore").write_text("")
    assert ros_present(debian)


def test_tool_packages_prefer_ros_repo_then_debian():
    assert plan_tool_packages(["rosdep"], ["python3-rosdep", "python3-rosdep2"]) == [
        "python3-rosdep"
    ]
    debian = plan_tool_packages(["colcon", "vcs"], ["colcon", "vcstool", "python3-colcon-ros"])
    assert debian == ["colcon", "python3-colcon-ros", "vcstool"]
    with pytest.raises(StepError, match="no apt package provides 'vcs'"):
        plan_tool_packages(["vcs"], [])


def test_image_installs_skip_dpkg_syncs_host_installs_do_not():
    from docker_ros.in_image.runtime.apt import install_options

    unsafe = ["-o", "Dpkg::Options::=--force-unsafe-io"]
    assert install_options("image")[-2:] == unsafe
    assert "Dpkg::Options::=--force-unsafe-io" not in install_options("host")
    assert install_options("host") == ["-y", "--no-install-recommends"]
    # prepare runs in images only: every package install of its ROS plan skips the syncs
    installs = [c for c in plan(distro="jazzy") if c[:2] == ["apt-get", "install"]
                and "--no-install-recommends" in c]
    assert installs and all(c[2:6] == ["-y", "--no-install-recommends", *unsafe]
                            for c in installs)


def test_a_locked_prepare_installs_under_the_pins_and_stops_on_a_difference(
        tmp_path, monkeypatch):
    """held_to_lock around an install: the pins are apt's preferences meanwhile and gone after;
    what was installed is compared with them from the state before (real apt behaviour under
    the pins: tests/docker/test_lock.py)."""
    from docker_ros.in_image.runtime import lockapt, prepare
    from docker_ros.in_image.runtime.workspace import StepError

    status = tmp_path / "status"
    preferences = tmp_path / "preferences.d" / "docker-ros-lock"
    pins = tmp_path / "pins"
    pins.mkdir()
    (pins / "base.pref").write_text(lockapt.apt_preferences({"tini": "1"}))
    monkeypatch.setattr(prepare, "LOCK_PINS", pins)
    monkeypatch.setattr(prepare, "BEFORE_PREPARE", tmp_path / "absent")
    monkeypatch.setattr(prepare, "DPKG_STATUS", status)
    monkeypatch.setattr(prepare, "LOCK_PREFERENCES", preferences)
    monkeypatch.setattr(prepare, "apt_sources", lambda: ["http://deb.debian.org/debian bookworm"])

    def installing(version, types="exec", held=True):
        status.write_text("")
        with prepare.held_to_lock(types, dry_run=False):
            assert preferences.is_file() == held
            if held:
                assert lockapt.parse_apt_preferences(preferences.read_text()) == {"tini": "1"}
            status.write_text(f"Package: tini\nStatus: install ok installed\nVersion: {version}\n")

    installing("1")
    assert not preferences.exists()
    with pytest.raises(StepError, match=r"LOCKED: prepare installed otherwise than docker-ros"
                       r".lock: tini=1 \(installed 2\)\. .*\(http://deb.debian.org/debian "
                       r"bookworm\).*run `inv lock`"):
        installing("2")
    assert not preferences.exists()
    # the toolchain pass reads dev.pref: none, or an empty file (a mount's stub), holds and
    # checks nothing; a lock of no package holds apt to installing none
    installing("2", types="all", held=False)
    (pins / "dev.pref").write_text("")
    installing("2", types="all", held=False)
    (pins / "dev.pref").write_text(lockapt.apt_preferences({}))
    with pytest.raises(StepError, match=r"tini 2 \(not in docker-ros.lock\)"):
        status.write_text("")
        with prepare.held_to_lock("all", dry_run=False):
            status.write_text("Package: tini\nStatus: install ok installed\nVersion: 2\n")


def rmw_plan(**kw):
    args = {"ros_installed": True, "disabled": False, "distro": "jazzy",
            "rmw_implementation": "rmw_zenoh_cpp", "chosen": True, "installed": []}
    args.update(kw)
    return plan_rmw_installation(**args)


def test_chosen_rmw_is_installed_on_a_ros2_base_that_lacks_it():
    """docker-ros installed RMW_IMPLEMENTATION's package on bases with ROS too."""
    assert rmw_plan()[-1][-1] == "ros-jazzy-rmw-zenoh-cpp"
    assert rmw_plan()[0] == ["apt-get", "update"]


def test_rmw_installs_nothing_when_not_needed():
    assert rmw_plan(installed=["ros-jazzy-rmw-zenoh-cpp"]) == []
    assert rmw_plan(chosen=False) == []  # the default keeps the base image's middleware
    assert rmw_plan(disabled=True) == []
    assert rmw_plan(distro=None) == []  # the package cannot be named (prepare warns)
    assert rmw_plan(distro="noetic") == []  # ROS 1 has no RMW
    assert rmw_plan(ros_installed=False) == []  # installed with ROS (plan_ros_installation)
def test_a_ros_distro_the_base_image_does_not_have_is_named(tmp_path):
    # ROS_DISTRO=noetic over Debian's ROS (docker-ros/ros1:bookworm) failed only in colcon,
    # in catkin ("ROS_DISTRO was set to 'noetic' before"); over /opt/ros/jazzy, humble was
    # not installed (ROS was "present") and the build mixed the two
    assert distro_problem("noetic", tmp_path) is None  # no ROS: prepare installs it
    (tmp_path / "usr/bin").mkdir(parents=True)
    (tmp_path / "usr/bin/roscore").touch()
    assert "Debian's ROS packages in /usr" in distro_problem("noetic", tmp_path)
    assert distro_problem(None, tmp_path) is None
    (tmp_path / "opt/ros/jazzy").mkdir(parents=True)
    (tmp_path / "opt/ros/jazzy/setup.bash").touch()
    assert distro_problem("humble", tmp_path) == (
        "ROS_DISTRO=humble, but BASE_IMAGE has ROS jazzy in /opt/ros: set ROS_DISTRO=jazzy, "
        "or leave it unset")
    assert distro_problem("jazzy", tmp_path) is None


def test_pip_may_install_into_the_system_as_in_docker_ros(tmp_path):
    conf = tmp_path / "pip.conf"
    conf.write_text("[global]\nindex-url = https://mirror.example/simple\n")
    allow_pip_system_installs(conf, dry_run=False)
    allow_pip_system_installs(conf, dry_run=False)  # (twice: written once)
    text = conf.read_text()
    assert "index-url = https://mirror.example/simple" in text
    assert text.count("break-system-packages = true") == 1
    fresh = tmp_path / "none.conf"
    allow_pip_system_installs(fresh, dry_run=False)
    assert fresh.read_text() == "[global]\nbreak-system-packages = true\n\n"
