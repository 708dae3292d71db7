"""`docker-ros test` and `docker-ros dev-shell` on a real engine, with one ament_python package
(on the ROS 2 tooling base image) whose tests pass, fail and skip: one dev image, built once."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from docker_ros.core.loading import load_settings
from docker_ros.host.devshell import HostUser, ShellOptions, dev_shell_argv
from docker_ros.host.refs import image_ref
from docker_ros.in_image.testing import MARKER, summarize
from tests.docker.buildhelp import docker_ros, remove_image, write_env

pytestmark = pytest.mark.docker

IMAGE = "docker-ros-test/inside-b-tests:latest"
TESTS = '''import pytest


def test_passes():
    assert 1 + 1 == 2


def test_fails():
    assert 1 + 1 == 3, "deliberately failing"


@pytest.mark.skip(reason="deliberately skipped")
def test_skipped():
    pass
'''


def python_package(root: Path, name: str) -> Path:
    """An ament_python package with pytest tests (colcon runs pytest, writes JUnit XML)."""
    pkg = root / name
    for folder in (name, "test", "resource"):
        (pkg / folder).mkdir(parents=True)
    (pkg / "package.xml").write_text(
        f'<?xml version="1.0"?>\n<package format="3">\n  <name>{name}</name>\n'
        "  <version>0.0.1</version>\n  <description>tests</description>\n"
        '  <maintainer email="t@example.com">t</maintainer>\n  <license>MIT</license>\n'
        "  <export><build_type>ament_python</build_type></export>\n</package>\n")
    (pkg / "setup.py").write_text(
        "from setuptools import setup\n"
        f"setup(name={name!r}, version='0.0.1', packages=[{name!r}],\n"
        "      extras_require={'test': ['pytest']},\n"
        f"      data_files=[('share/ament_index/resource_index/packages', ['resource/{name}']),\n"
        f"                  ('share/{name}', ['package.xml'])])\n")
    (pkg / "resource" / name).write_text("")
    (pkg / name / "__init__.py").write_text("")
    (pkg / "test" / "test_things.py").write_text(TESTS)
    return pkg


@pytest.fixture(scope="module")
def project(ros2_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("inside-b") / "robot"
    python_package(root, "pkg_tests")
    write_env(root, BASE_IMAGE=ros2_base_image, IMAGE=IMAGE, TARGET="dev", COMMAND="true")
    built = docker_ros(root, "build")
    assert built.returncode == 0, built.stdout[-4000:]
    yield root
    remove_image(f"{IMAGE}-dev")


def test_failing_test_fails_the_task_and_results_reach_the_host(
    project: Path, tmp_path: Path
) -> None:
    results = tmp_path / "results"
    result = docker_ros(project, "test", "--results-dir", str(results))
    assert result.returncode != 0, result.stdout[-3000:]
    assert "docker-ros test (amd64): 1 passed, 1 failed, 1 skipped" in result.stdout
    assert ("docker-ros test: 1 test(s) failed: pkg_tests.test.test_things.test_fails "
            "(AssertionError: deliberately failing) (amd64)") in result.stdout, (
        result.stdout[-2000:])
    junit = results / "junit" / "pkg_tests" / "pytest.xml"
    assert "deliberately failing" in junit.read_text()
    assert (summarize(results / "junit")) == (1, 1, 1)
    assert (results / "log" / "test" / "pkg_tests" / "stdout_stderr.log").is_file()
    assert "1 failure" in (results / "test-result.txt").read_text()
    assert not (project / "test-results").exists()  # nothing written into the sources


def test_passing_tests_pass_and_replace_the_earlier_results(
    project: Path, tmp_path: Path
) -> None:
    fixed = tmp_path / "robot"
    subprocess.run(["cp", "-a", str(project), str(fixed)], check=True)
    tests = fixed / "pkg_tests" / "test" / "test_things.py"
    tests.write_text(tests.read_text().replace("1 + 1 == 3", "1 + 1 == 2"))
    results = tmp_path / "results"
    results.mkdir()
    (results / MARKER).write_text("")
    (results / "stale.xml").write_text("<testsuite><testcase><failure/></testcase></testsuite>")
    result = docker_ros(fixed, "test", "--results-dir", str(results))
    assert result.returncode == 0, result.stdout[-3000:]
    assert "docker-ros test (amd64): 2 passed, 0 failed, 1 skipped" in result.stdout
    assert not (results / "stale.xml").exists()


def test_enable_industrial_ci_runs_the_tests_after_the_build(project: Path,
                                                            tmp_path: Path) -> None:
    # (the results go to WORKSPACE/test-results: this run's own, not ~/.cache/docker-ros/ws/)
    result = docker_ros(project, "build", env={"ENABLE_INDUSTRIAL_CI": "true",
                                                "WORKSPACE": str(tmp_path / "ws")})
    assert result.returncode != 0
    assert "1 passed, 1 failed, 1 skipped" in result.stdout
    assert "latest-dev" in result.stdout[: result.stdout.index("docker-ros test (amd64)")]
    assert (tmp_path / "ws" / "test-results" / "junit").is_dir()
    assert (tmp_path / "ws" / "src" / "target").resolve() == project.resolve()  # claimed


def test_dev_shell_command_passes_its_exit_code_and_options(
    project: Path, tmp_path: Path
) -> None:
    (tmp_path / "extra.txt").write_text("mounted")
    script = 'cat /extra/extra.txt; echo " $GREETING"; ls src/target; exit 7'
    result = docker_ros(project, "dev-shell", "-c", script, "--volume",
                        f"{tmp_path}:/extra:ro", "--env", "GREETING=hello", "--network", "none",
                        "--x11", "false", "--gpus", "none")
    assert result.returncode == 7, result.stdout
    assert "mounted hello" in result.stdout and "pkg_tests" in result.stdout


def test_dev_shell_as_a_host_user_builds_and_owns_its_files(project: Path) -> None:
    """The host user (uid 1234 here, the tests run as root) builds in the workspace and
    the files it creates in the mounted repository belong to it on the host."""
    os.chmod(project, 0o777)
    settings = load_settings(environ={"BUILD_CONTEXT": str(project), "IMAGE": IMAGE},
                             project_dir=project)
    script = "colcon build --base-paths src >/dev/null && ls install && touch src/target/made"
    options = ShellOptions(command=script, network="none")
    argv = dev_shell_argv(settings, image_ref(settings, "dev"), options,
                          HostUser(1234, 1234, "alice"))
    result = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "pkg_tests" in result.stdout
    made = (project / "made").stat()
    assert (made.st_uid, made.st_gid) == (1234, 1234)
    (project / "made").unlink()
