"""Messages of a failed `docker-ros build` that need no engine: bad input and a missing daemon
(the console script, as a user runs it), and the one line of a bake run in which one target
failed after BuildKit had tagged another or had not (run_buildx over a recorded BuildKit log).
Were docker-marked tests of tests/docker/test_image_build.py, or its race (dev tagged or not
before run failed: the test took either outcome)."""

import io
import os
import shlex
from pathlib import Path

import pytest

from docker_ros.core import errors
from docker_ros.host import build
from tests.docker.buildhelp import docker_ros, write_env

NO_DAEMON = "unix:///nonexistent.sock"  # (no engine is asked, or it is this one, which is none)


def package(root: Path, name: str) -> None:
    (root / name).mkdir(parents=True)
    (root / name / "package.xml").write_text(
        f'<?xml version="1.0"?>\n<package format="3"><name>{name}</name><version>0.0.1'
        f'</version><description>t</description><maintainer email="t@t.t">t</maintainer>'
        f"<license>MIT</license></package>\n")


def test_missing_base_image_and_command_reported_together(tmp_path: Path) -> None:
    result = docker_ros(tmp_path, "build", "--target", "dev,run", env={"DOCKER_HOST": NO_DAEMON})
    assert result.returncode != 0
    assert "missing required configuration: BASE_IMAGE, COMMAND" in result.stdout, result.stdout
    assert "Traceback" not in result.stdout and "no Docker daemon" not in result.stdout


def test_no_docker_daemon_is_one_clear_message(tmp_path: Path) -> None:
    package(tmp_path, "pkg")
    write_env(tmp_path, BASE_IMAGE="any:1", COMMAND="pkg", IMAGE="docker-ros-test/never:1")
    result = docker_ros(tmp_path, "build", env={"DOCKER_HOST": NO_DAEMON})
    assert result.returncode != 0
    assert result.stdout.strip().splitlines()[-1] == (
        f"docker-ros build: no Docker daemon answers at {NO_DAEMON}: start it, e.g. with "
        "scripts/setup.sh")


# A bake run of dev and run (BuildKit's plain log, shortened) in which run's colcon failed
COLCON_FAILED = [
    "#9 [run build 1/1] RUN --mount=... python3 -m docker_ros.in_image.steps colcon",
    "#9 2.1 Starting >>> colcon",
    "#9 3.1 docker-ros colcon: package broken_pkg failed to build (exit code 2): "
    "broken_pkg/src/main.cpp:1:15: error: 'is' does not name a type",
    "#9 ERROR: process did not complete successfully: exit code: 1",
    "ERROR: target run: failed to solve: process did not complete successfully: exit code: 1",
]
DEV_TAGGED = "#12 naming to docker.io/library/img:t-dev done"


def failed_bake(log: list) -> str:
    argv = ["bash", "-c", f"printf '%s\\n' {' '.join(shlex.quote(line) for line in log)}; exit 1"]
    with pytest.raises(errors.BuildError) as failed:
        build.run_buildx(argv, {"dev": "img:t-dev", "run": "img:t"}, "amd64", env=os.environ,
                         out=io.StringIO(), environ={})
    assert (failed.value.stage, failed.value.step) == ("build", "colcon")
    return str(failed.value)


def test_a_bake_run_failing_after_buildkit_tagged_dev_says_dev_was_built() -> None:
    cause = ("failed in step colcon: package broken_pkg failed to build (exit code 2): "
             "broken_pkg/src/main.cpp:1:15: error: 'is' does not name a type")
    assert failed_bake([DEV_TAGGED, *COLCON_FAILED]) == (
        f"building target 'run' (amd64) {cause}; 'dev' was built: img:t-dev")
    # BuildKit had not named dev when run failed: both failed, nothing said built
    assert failed_bake(COLCON_FAILED) == f"building targets 'dev', 'run' (amd64) {cause}"
