"""`docker-ros test` on a ROS 1 (catkin) repository: a message package, and a rostest and a
gtest with one failing case each (tests/rosfixtures.py make_ros1_repo). One dev image."""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import pytest

from tests.docker.buildhelp import docker_ros, remove_image, write_env
from tests.rosfixtures import make_ros1_repo

pytestmark = pytest.mark.docker

IMAGE = "docker-ros-test/ros1-tests:latest"


@pytest.fixture(scope="module")
def project(ros1_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    root = make_ros1_repo(tmp_path_factory.mktemp("ros1-tests") / "robot", failing=True)
    write_env(root, BASE_IMAGE=ros1_base_image, IMAGE=IMAGE, TARGET="dev",
              COMMAND="roslaunch demo_nodes demo.launch")
    built = docker_ros(root, "build")
    assert built.returncode == 0, built.stdout[-4000:]
    yield root
    remove_image(f"{IMAGE}-dev")


def test_rostest_and_gtest_failures_are_counted_and_named(project: Path, tmp_path: Path) -> None:
    """rostest's own passing case per <test> is not a test of its own (before: 3 passed), the
    failure message names the failed cases, and test-result.txt keeps colcon's lines."""
    results = tmp_path / "results"
    result = docker_ros(project, "test", "--results-dir", str(results))
    assert result.returncode != 0, result.stdout[-3000:]
    assert "docker-ros test (amd64): 2 passed, 2 failed, 0 skipped" in result.stdout
    assert ("docker-ros test: 2 test(s) failed: demo_nodes: Utils.Multiplies, "
            "demo_nodes: GreetingTest.test_add_two (amd64)") in result.stdout
    reports = results / "junit" / "demo_nodes" / "test_results" / "demo_nodes"
    assert sorted(p.name for p in reports.iterdir()) == [
        "gtest-utils_test.xml", "rostest-test_demo.xml", "rosunit-greeting_test.xml"]
    lines = (results / "test-result.txt").read_text().splitlines()
    assert any(line.startswith("Summary: ") for line in lines), lines
