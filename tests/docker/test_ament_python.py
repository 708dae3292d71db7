"""A ROS 2 Python (ament_python) repository on the Debian ROS 2 base: what the daily loop
(edit, rebuild the run image) leaves in the image."""

from __future__ import annotations

import uuid
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
    # sources of this run only: a rerun in the same folder (pytest's numbering starts again
    # on a fresh /tmp) would otherwise take each build from BuildKit's cache of the last run
    util = repo / "demo_py/demo_py/util.py"
    util.write_text(util.read_text() + f"# run {uuid.uuid4().hex}\n")
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


def test_inv_test_names_failed_pytest_cases_and_packages_where_no_test_ran(
        ros2_base_image: str, tmp_path: Path) -> None:
    repo = make_ros2_python_repo(tmp_path / "ament_repo")
    write_env(repo, BASE_IMAGE=ros2_base_image, IMAGE=IMAGE)
    util_test = repo / "demo_py/test/test_util.py"
    util_test.write_text(util_test.read_text().replace("== 5", "== 6"))
    util = repo / "demo_py/demo_py/util.py"
    util.write_text(util.read_text().replace('"""Helpers."""\n', '"""Helpers."""\nimport os\n'))
    try:
        failed = docker_ros(repo, "test", "--results-dir", str(tmp_path / "results"))
        assert failed.returncode != 0, failed.stdout[-4000:]
        assert "1 passed, 2 failed, 0 skipped" in failed.stdout, failed.stdout[-4000:]
        # the linter test's failure with its first finding, not only "Found 1 ...:"
        assert ("2 test(s) failed: demo_py.test.test_flake8.test_flake8 (AssertionError: Found "
                "1 code style errors / warnings: ./demo_py/util.py:2:1: F401 'os' imported but "
                "unused), demo_py.test.test_util.test_add (assert 5 == 6)") \
            in failed.stdout, failed.stdout[-4000:]
        util.write_text(util.read_text().replace("import os\n", ""))

        # the ROS 2 Humble/Jazzy template's tests_require, which setuptools >= 72 drops:
        # colcon falls back to unittest, which finds none of the pytest functions
        setup = repo / "demo_py/setup.py"
        setup.write_text(setup.read_text().replace('extras_require={"test": ["pytest"]}',
                                                   'tests_require=["pytest"]'))
        none = docker_ros(repo, "test", "--results-dir", str(tmp_path / "results"))
        assert none.returncode != 0, none.stdout[-4000:]
        assert "0 passed, 0 failed, 0 skipped" in none.stdout, none.stdout[-4000:]
        assert ("colcon test failed (exit code 5): demo_py: no tests ran (colcon ran "
                "`python3 -m unittest`, which finds only unittest.TestCase classes; it runs "
                "pytest when setup.py declares it: extras_require={'test': ['pytest']}"
                in none.stdout), none.stdout[-4000:]
    finally:
        remove_image(IMAGE.replace(":1", ":1-dev"))
        remove_image(IMAGE.replace(":1", ":1-dev-test"))


def test_dev_shell_warns_when_the_dev_image_predates_a_dependency_change(
        ros2_base_image: str, tmp_path: Path) -> None:
    repo = make_ros2_python_repo(tmp_path / "ament_repo")
    write_env(repo, BASE_IMAGE=ros2_base_image, IMAGE=IMAGE)
    stale = "was built before the repository's dependency inputs changed"
    try:
        first = docker_ros(repo, "dev-shell", "-c", "true")  # builds the missing dev image
        assert first.returncode == 0 and stale not in first.stdout, first.stdout[-4000:]
        same = docker_ros(repo, "dev-shell", "-c", "true")
        assert same.returncode == 0 and stale not in same.stdout, same.stdout[-4000:]
        source = repo / "demo_py/demo_py/util.py"  # a source edit: the mounted repository has it
        source.write_text(source.read_text() + "\n\nLIMIT = 3\n")
        edited = docker_ros(repo, "dev-shell", "-c", "true")
        assert edited.returncode == 0 and stale not in edited.stdout, edited.stdout[-4000:]

        # a new dependency: the dev image does not have it until it is built again
        manifest = repo / "demo_py/package.xml"
        manifest.write_text(manifest.read_text().replace(
            "<exec_depend>python3-yaml</exec_depend>",
            "<exec_depend>python3-yaml</exec_depend>\n  <exec_depend>python3-numpy</exec_depend>"))
        rules = repo / "docker/rosdep.yaml"
        rules.write_text(rules.read_text() + "python3-numpy:\n  debian: [python3-numpy]\n")
        old = docker_ros(repo, "dev-shell", "-c", "python3 -c 'import numpy'")
        assert old.returncode != 0 and "No module named 'numpy'" in old.stdout, old.stdout[-4000:]
        assert f"docker-ros dev-shell: {IMAGE.replace(':1', ':1-dev')} {stale}" in old.stdout \
            and "`inv dev-shell --rebuild` builds it again" in old.stdout, old.stdout[-4000:]
        new = docker_ros(repo, "dev-shell", "--rebuild", "-c", "python3 -c 'import numpy'")
        assert new.returncode == 0 and stale not in new.stdout, new.stdout[-4000:]
    finally:
        remove_image(IMAGE.replace(":1", ":1-dev"))
