"""A ROS 2 Python (ament_python) repository on the Debian ROS 2 base: what the daily loop
(edit, rebuild the run image) leaves in the image."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.docker.buildhelp import docker_ros, remove_image, sh, write_env
from tests.rosfixtures import make_ros2_python_repo

pytestmark = pytest.mark.docker

IMAGE = "docker-ros-test/ament-python:1"
SITE = "/docker-ros/ws/install/demo_py/lib/python3.13/site-packages/demo_py"
SHARE = "/docker-ros/ws/install/demo_py/share/demo_py"


def test_files_removed_from_sources_leave_the_run_image(ros2_base_image: str,
                                                         tmp_path: Path) -> None:
    repo = make_ros2_python_repo(tmp_path / "ament_repo")
    (repo / "demo_py/demo_py/old.py").write_text('"""Gone soon."""\n')
    (repo / "demo_py/demo_py/older.py").write_text('"""Gone later."""\n')
    write_env(repo, BASE_IMAGE=ros2_base_image, IMAGE=IMAGE,
              COMMAND="/docker-ros/ws/install/demo_py/lib/demo_py/talker")
    try:
        first = docker_ros(repo, "build", "--target", "run")
        assert first.returncode == 0, first.stdout[-4000:]
        listed = sh(IMAGE, f"ls {SITE}; ls {SHARE}/config")
        assert listed.stdout.split() == ["__init__.py", "old.py", "older.py", "talker.py",
                                         "util.py", "params.yaml"], listed

        # a module deleted and a data file renamed: an incremental build over the last
        # install space must not ship them
        (repo / "demo_py/demo_py/old.py").unlink()
        config = repo / "demo_py/config"
        (config / "params.yaml").rename(config / "params2.yaml")
        second = docker_ros(repo, "build", "--target", "run")
        assert second.returncode == 0, second.stdout[-4000:]
        assert "demo_py changed: building them and their dependents only" in second.stdout
        listed = sh(IMAGE, f"ls {SITE}; ls {SHARE}/config")
        assert listed.stdout.split() == ["__init__.py", "older.py", "talker.py", "util.py",
                                         "params2.yaml"], listed

        # a full build (other CMAKE_ARGS) reuses the build/ cache: setuptools' build/lib
        # there must not bring a deleted module back
        (repo / "demo_py/demo_py/older.py").unlink()
        third = docker_ros(repo, "build", "--target", "run", "--set",
                           "CMAKE_ARGS=-DCMAKE_BUILD_TYPE=Debug")
        assert third.returncode == 0, third.stdout[-4000:]
        assert "full build: the colcon arguments" in third.stdout
        listed = sh(IMAGE, f"ls {SITE}")
        assert listed.stdout.split() == ["__init__.py", "talker.py", "util.py"], listed
    finally:
        remove_image(IMAGE)
