"""`docker-ros test` and the dev shell on a ROS 1 (catkin) repository: a message package, and a
rostest and a gtest with one failing case each (tests/rosfixtures.py make_ros1_repo). One dev
image."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Iterator

import pytest

from docker_ros.core.loading import load_settings
from docker_ros.host.devshell import HostUser, ShellOptions, dev_shell_argv
from docker_ros.host.refs import image_ref
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
    first = "docker-ros test: 2 test(s) failed: demo_nodes: Utils.Multiplies"
    verdict = [line for line in result.stdout.splitlines() if line.startswith(first)]
    assert verdict and verdict[0].startswith(  # gtest's failure message: its file and line
        first + " (demo_nodes/test/utils_test.cpp:3), demo_nodes: GreetingTest.test_add_two "
        "(5 != 6) (amd64)"), result.stdout[-3000:]
    reports = results / "junit" / "demo_nodes" / "test_results" / "demo_nodes"
    assert sorted(p.name for p in reports.iterdir()) == [
        "gtest-utils_test.xml", "rostest-test_demo.xml", "rosunit-greeting_test.xml"]
    lines = (results / "test-result.txt").read_text().splitlines()
    assert any(line.startswith("Summary: ") for line in lines), lines


def test_catkin_make_works_in_the_dev_shell_as_a_host_user(project: Path) -> None:
    """A host user (uid 1234; the tests run as root) may write the workspace's src/ folder,
    where catkin_make puts its toplevel CMakeLists.txt (before: Permission denied), and the
    messages it generates reach Python."""
    settings = load_settings(environ={"BUILD_CONTEXT": str(project), "IMAGE": IMAGE},
                             project_dir=project)
    script = ("catkin_make >/tmp/catkin_make.log 2>&1 || { tail -20 /tmp/catkin_make.log; "
              "exit 1; }; source devel/setup.bash && rospack find demo_nodes && "
              "python3 -c 'from demo_msgs.srv import AddTwo; print(AddTwo._type)' && "
              "stat -c %U src/target/demo_nodes")
    argv = dev_shell_argv(settings, image_ref(settings, "dev"), ShellOptions(command=script),
                          HostUser(1234, 1234, "alice"))
    result = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "/docker-ros/ws/src/target/demo_nodes\ndemo_msgs/AddTwo\n" in result.stdout
    assert result.stdout.splitlines()[-1] != "alice"  # the mounted repository keeps its owner
