"""One step at a time in a container (`--in-container`), `build --until <step>` in the middle of
a stage, and `--shell-on-failure` with and without a terminal, on the example workspace."""

from __future__ import annotations

import itertools
import os
import re
import shlex
import subprocess
import sys
import uuid
from pathlib import Path
from typing import Dict, Iterator, List, Tuple

import pexpect
import pytest

from tests.docker.buildhelp import (
    copy_example,
    docker_ros,
    image_exists,
    remove_image,
    sh,
    write_env,
)

pytestmark = pytest.mark.docker

NAME = "docker-ros-test/inside-a"
PROMPT = r"root@\w+:/docker-ros/ws# "
COMMAND = "roslaunch docker_ros_example talker_listener.launch"
SUFFIXES = [f"after-{s}" for s in ("blacklist", "rosdep", "files", "custom")] + [
    "until-rosdep", "failed-custom", "1-dev"]


def step_block(log: str, step: str) -> List[str]:
    """The lines of the step's last run (Starting >>> to Finished <<<): in a BuildKit log only
    its RUN's lines (`#N 1.23 ` prefix, stripped: stages run in parallel), up to the next step
    or the RUN's end (its standard output, apart from standard error, may come after
    Finished); without the time."""
    lines = log.splitlines()
    begin = max(i for i, line in enumerate(lines) if line.endswith(f"Starting >>> {step}"))
    vertex = re.match(r"#\d+ ", lines[begin])
    if vertex:
        lines = [line for line in lines[begin:] if line.startswith(vertex.group(0))]
        lines = [re.sub(r"^#\d+ \d+\.\d+ ", "", line) for line in lines]
    else:
        lines = lines[begin:]
    end = next(i for i, line in enumerate(lines) if line.startswith(f"Finished <<< {step}"))
    block = lines[:end] + [re.sub(r" \[.*\]$", "", lines[end])]
    if vertex:  # the RUN's standard output may reach the log after the step's last line
        block += itertools.takewhile(lambda line: not line.startswith(("Starting >>> ", "#")),
                                     lines[end + 1:])
    return block


def step_streams(log: str, step: str) -> Tuple[List[str], List[str]]:
    """The step block's lines of the step's log (standard error) and the rest (its commands'
    standard output), each in order. A BuildKit RUN carries the two streams apart, and its log
    may show a command's output before the step's line naming the command."""
    lines = step_block(log, step)
    logged = [line for line in lines
              if line.startswith((f"{step}:", "Starting >>> ", "Finished <<< "))]
    return logged, [line for line in lines if line not in logged]


def project(root: Path, image: str, custom: str) -> Path:
    """A copy of the example with its own image name, a blacklist and a custom.sh. A fresh
    token in custom.sh makes every session build (and log) the steps for real."""
    path = copy_example(root)
    (path / "docker" / "additional-debs.txt").write_text("jq\n")
    (path / "docker" / "blacklisted-packages.txt").write_text("# none of ours\nno_such_pkg\n")
    (path / "docker" / "custom.sh").write_text(f"# {uuid.uuid4()}\n{custom}")
    write_env(path, BASE_IMAGE="docker-ros-test/ros1:bookworm", COMMAND=COMMAND, IMAGE=image)
    return path


def cleanup(image: str) -> None:
    for suffix in SUFFIXES:
        remove_image(f"{image}-{suffix}")
    remove_image(f"{image}-dev")


@pytest.fixture(scope="module")
def good(ros1_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Dict]:
    """The example built as a dev image, then rosdep run alone in a container."""
    image = f"{NAME}-good:1"
    path = project(tmp_path_factory.mktemp("good") / "example", image,
                   'echo "custom says hi from $(pwd)"\ntouch /custom-was-here\n')
    full = docker_ros(path, "build", "--target", "dev")
    assert full.returncode == 0, full.stdout[-3000:]
    rosdep = docker_ros(path, "rosdep", "--in-container")
    assert rosdep.returncode == 0, rosdep.stdout[-3000:]
    yield {"path": path, "image": image, "full": full.stdout, "rosdep": rosdep.stdout}
    cleanup(image)


@pytest.fixture(scope="module")
def failing(ros1_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Dict]:
    """The example with a custom.sh that fails; the steps before custom run in a container."""
    image = f"{NAME}-failing:1"
    path = project(tmp_path_factory.mktemp("failing") / "example", image,
                   'echo "custom is about to fail"\nexit 3\n')
    files = docker_ros(path, "files", "--in-container")
    assert files.returncode == 0, files.stdout[-3000:]
    yield {"path": path, "image": image}
    cleanup(image)


def test_step_in_container_has_the_output_of_the_full_build(good: Dict) -> None:
    assert step_block(good["rosdep"], "rosdep") and "Starting >>> debs" not in good["rosdep"]
    custom = docker_ros(good["path"], "custom", "--in-container")
    assert custom.returncode == 0, custom.stdout[-3000:]
    # resumed on top of rosdep's state: debs..files ran here, scripts and rosdep did not again
    assert f"starting from {good['image']}-after-rosdep" in custom.stdout
    assert "Starting >>> rosdep" not in custom.stdout and "Starting >>> debs" in custom.stdout
    assert step_streams(custom.stdout, "custom") == step_streams(good["full"], "custom")
    assert "custom says hi from /docker-ros/ws\n" in custom.stdout
    blacklist = docker_ros(good["path"], "blacklist", "--in-container")
    assert blacklist.returncode == 0, blacklist.stdout[-3000:]
    assert step_streams(blacklist.stdout, "blacklist") == step_streams(good["full"], "blacklist")
    assert "'no_such_pkg' matches no package" in blacklist.stdout
    tag = f"{good['image']}-after-custom"
    assert f"tagged {tag}" in custom.stdout
    # the committed state: custom's effect, jq from debs, the step modules usable as written
    state = sh(tag, "ls /custom-was-here && jq --version && python3 -m docker_ros.in_image.steps "
               "custom --phase apply --dry-run")
    assert state.returncode == 0, state.stdout + state.stderr
    assert "[dry-run]" in state.stdout + state.stderr


def test_until_a_step_in_the_middle_of_a_stage(good: Dict) -> None:
    result = docker_ros(good["path"], "build", "--until", "rosdep")
    assert result.returncode == 0, result.stdout[-3000:]
    tag = f"{good['image']}-until-rosdep"
    assert "Starting >>> debs" not in result.stdout
    state = sh(tag, "dpkg -s libroscpp-dev >/dev/null && echo rosdep-done; "
               "command -v jq || echo no-jq; ls src 2>&1 || true")
    assert "rosdep-done" in state.stdout and "no-jq" in state.stdout, state.stdout + state.stderr
    # the next step by hand, exactly as printed
    line = next(x for x in result.stdout.splitlines() if x.strip().startswith("next step:"))
    argv = shlex.split(line.split("next step:", 1)[1])
    assert argv[-4:] == ["docker_ros.in_image.steps", "debs", "--phase", "apply"]
    after = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert after.returncode == 0, after.stdout + after.stderr
    assert "Finished <<< debs" in after.stdout + after.stderr
    assert "Setting up jq" in after.stdout + after.stderr


def test_shell_on_failure_in_a_terminal(failing: Dict) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    child = pexpect.spawn(sys.executable, ["-m", "docker_ros", "custom", "--in-container",
                                           "--shell-on-failure"],
                          cwd=str(failing["path"]), env=env, encoding="utf-8", timeout=600)
    log: List[str] = []
    child.logfile_read = _Collect(log)
    child.expect("custom is about to fail")
    child.expect(r"failed with exit code 3: "
                 r"python3 -m docker_ros.in_image.steps custom --phase apply")
    child.expect(PROMPT)
    child.sendline("echo shell-in-$(pwd); ls /docker-ros/ws/.docker-ros/hooks/custom")
    child.expect("shell-in-/docker-ros/ws")
    child.expect("01-custom.sh")
    child.sendline("exit")
    child.expect(pexpect.EOF)
    child.close()
    assert child.exitstatus == 3, "".join(log)[-3000:]
    assert ("docker-ros custom: python3 -m docker_ros.in_image.steps custom --phase apply "
            "failed with "
            "exit code 3") in "".join(log)
    assert not image_exists(f"{failing['image']}-after-custom")


def test_build_shell_on_failure_without_terminal(failing: Dict) -> None:
    result = docker_ros(failing["path"], "build", "--target", "dev", "--shell-on-failure")
    assert result.returncode == 3, result.stdout[-3000:]  # the step's, as in a terminal
    assert "failed in step custom" in result.stdout.splitlines()[-1]
    tag = f"{failing['image']}-failed-custom"
    assert f"the state just before the failed command is {tag}" in result.stdout
    enter = next(x for x in result.stdout.splitlines() if x.strip().startswith("enter it:"))
    assert shlex.split(enter.split(":", 1)[1]) == ["docker", "run", "--rm", "-it", tag, "bash"]
    # entering it as printed, in a terminal: the failing command runs again there
    child = pexpect.spawn(enter.split(":", 1)[1].strip(), encoding="utf-8", timeout=120)
    child.expect(PROMPT)
    child.sendline("python3 -m docker_ros.in_image.steps custom --phase apply; echo exit=$?")
    child.expect("custom is about to fail")
    child.expect("exit=3")
    child.sendline("exit")
    child.expect(pexpect.EOF)
    rerun = next(x for x in result.stdout.splitlines() if x.strip().startswith("re-run it:"))
    again = subprocess.run(shlex.split(rerun.split(":", 1)[1]), capture_output=True, text=True,
                           timeout=120)
    assert again.returncode == 3 and "custom is about to fail" in again.stdout
    assert not image_exists(f"{failing['image']}-dev")


class _Collect:
    """pexpect logfile that keeps what was read (shown when an assertion fails)."""

    def __init__(self, lines: List[str]) -> None:
        self.lines = lines

    def write(self, text: str) -> None:
        self.lines.append(text)

    def flush(self) -> None:
        pass
