"""The example on Ubuntu, the distribution under nearly every ROS base image users have
(`ros:noetic`, `rwthika/ros2:jazzy`): Ubuntu 22.04's own ROS 1 (bootstrap's ros1-ubuntu, colcon
and vcstool from PyPI in /usr/local). The other image tests run on Debian bases: here rosdep
resolves with Ubuntu's names, apt installs from Ubuntu's archive, the lean run image maps -dev
packages to Ubuntu's run-time ones, and the slim image's trace runs on Ubuntu's libraries."""

from __future__ import annotations

from typing import Iterator

import pytest

from tests.docker.buildhelp import (
    copy_example,
    docker_ros,
    remove_image,
    run_until,
    sh,
    write_env,
)

pytestmark = pytest.mark.docker

IMAGE = "docker-ros-test/ubuntu-example:1"
HEARD = "I heard: hello from docker-ros"


@pytest.fixture(scope="module")
def built(ros1_ubuntu_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    """dev, run and slim images of the example, with the defaults (slim asked for)."""
    project = copy_example(tmp_path_factory.mktemp("ubuntu") / "example")
    write_env(project, BASE_IMAGE=ros1_ubuntu_base_image, IMAGE=IMAGE, TARGET="dev,run",
              COMMAND="roslaunch docker_ros_example talker_listener.launch")
    result = docker_ros(project, "build", env={"ENABLE_SLIM": "true"})
    assert result.returncode == 0, result.stdout[-5000:]
    yield {"project": project, "log": result.stdout}
    for ref in (IMAGE, f"{IMAGE}-dev", f"{IMAGE}-slim", f"{IMAGE}-lean"):
        remove_image(ref)


def test_the_images_are_ubuntu_and_rosdep_resolved_with_its_rules(built: dict) -> None:
    for ref in (IMAGE, f"{IMAGE}-dev"):
        assert "VERSION_CODENAME=jammy" in sh(ref, "cat /etc/os-release").stdout, ref
    # rosdep took Ubuntu's names for the example's keys (its rules for Debian are not Ubuntu's
    # list: without the base's untagged list every key fails to resolve)
    installed = sh(f"{IMAGE}-dev", "dpkg-query -W -f '${Package}\\n' libroscpp-dev ros-std-msgs")
    assert installed.stdout.split() == ["libroscpp-dev", "ros-std-msgs"], installed


def test_run_and_slim_images_run_the_nodes(built: dict) -> None:
    for ref in (IMAGE, f"{IMAGE}-slim"):
        out = run_until(ref, HEARD, 60)
        assert HEARD in out, (ref, out[-3000:])


def test_lean_run_image_on_ubuntu_runs_without_dev_packages(built: dict) -> None:
    lean = f"{IMAGE}-lean"
    result = docker_ros(built["project"], "build", "--target", "run", "--set", f"IMAGE={lean}",
                        "--set", "ENABLE_LEAN_RUN_IMAGE=true")
    assert result.returncode == 0, result.stdout[-5000:]
    dev_packages = sh(lean, "dpkg-query -W -f '${Package}\\n' | grep -- '-dev$'").stdout.split()
    assert "libroscpp-dev" not in dev_packages and "libstd-msgs-dev" not in dev_packages, (
        dev_packages)
    out = run_until(lean, HEARD, 60)
    assert HEARD in out, out[-3000:]
