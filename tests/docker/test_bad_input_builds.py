"""Bad input in real image builds (issue 11): the last line carries the cause and the fix;
Ctrl-C stops with 130, tags nothing and leaves nothing running.

proves (each line: where; "image" = a test here):
- a clone of a server on the loopback fails in an image build (its network is not the host's)
  and the last line points at BUILD_NETWORK=host: image (`--until clone`, no apt),
  test_loopback_clone_in_an_image_build_points_at_build_network; the hint's wording beside
  git's own cause: unit, tests/unit/test_bad_input.py::test_git_errors_keep_their_cause_and_
  loopback_hint
- Ctrl-C, from a terminal or to a background job, exits 130, tags nothing and leaves no
  process of the build running: image, test_ctrl_c_exits_130_tags_nothing_leaves_nothing
- a local amd64 base from no registry with PLATFORM=amd64,arm64 is refused before any build,
  with the bootstrap command: image (no build: the engine's image is the input),
  test_a_local_base_image_of_another_architecture_is_refused_before_any_build; its wording:
  unit, tests/unit/test_build_plan.py"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from tests.docker.buildhelp import docker_ros, image_exists, write_env
from tests.rosfixtures import free_port, make_package, write_repos

pytestmark = pytest.mark.docker


def test_loopback_clone_in_an_image_build_points_at_build_network(
    ros1_base_image: str, tmp_path: Path
) -> None:
    make_package(tmp_path / "pkg", "pkg")
    write_repos(tmp_path / ".repos", {"dep": {"type": "git", "version": "main",
                                               "url": f"http://127.0.0.1:{free_port()}/dep.git"}})
    write_env(tmp_path, BASE_IMAGE=ros1_base_image, IMAGE="docker-ros-test/repos-loop:1")
    result = docker_ros(tmp_path, "build", "--until", "clone")
    assert result.returncode != 0
    last = result.stdout.strip().splitlines()[-1]
    assert "failed in step clone" in last and "repository 'dep'" in last, last
    assert "unless BUILD_NETWORK=host: set it to reach a server on this machine" in last, last
    assert not image_exists("docker-ros-test/repos-loop:1-until-clone")


@pytest.mark.parametrize("handler", [signal.SIG_DFL, signal.SIG_IGN], ids=["terminal",
                                                                           "background-job"])
def test_ctrl_c_exits_130_tags_nothing_leaves_nothing(ros1_base_image: str, tmp_path: Path,
                                                      handler: signal.Handlers) -> None:
    """SIGINT to the whole process group, as Ctrl-C in a terminal sends it: the tool and buildx
    both see it (terminal), or only buildx does, the tool having started with SIGINT ignored
    as a script's background job does (buildx, Go, takes SIGINT back and stops the build)."""
    make_package(tmp_path / "pkg", "pkg")
    (tmp_path / "docker").mkdir()
    marker = f"started-{uuid.uuid4().hex}"
    pause = f"{300 + uuid.uuid4().int % 1000}.{os.getpid()}"  # a sleep nobody else runs
    (tmp_path / "docker" / "before_dependency_identification.sh").write_text(
        f"echo {marker}\nsleep {pause}\n")
    ref = f"docker-ros-test/interrupted-{handler.name.lower().replace('_', '-')}:1"
    write_env(tmp_path, BASE_IMAGE=ros1_base_image, IMAGE=ref, COMMAND="true")
    env = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    proc = subprocess.Popen([sys.executable, "-m", "docker_ros", "build"], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True,  # its own group: Ctrl-C hits it all
                            # whatever the handler pytest itself runs with
                            preexec_fn=lambda: signal.signal(signal.SIGINT, handler))
    assert proc.stdout is not None
    seen = []
    deadline = time.monotonic() + 900
    for line in proc.stdout:
        seen.append(line)
        if marker in line and "echo" not in line or time.monotonic() > deadline:
            break
    assert any(marker in line for line in seen), "".join(seen)[-3000:]
    time.sleep(1)
    os.killpg(proc.pid, signal.SIGINT)
    rest, _ = proc.communicate(timeout=120)
    out = "".join(seen) + rest
    assert proc.returncode == 130, out[-3000:]
    assert out.strip().splitlines()[-1] == "docker-ros build: interrupted"
    assert not image_exists(ref)
    time.sleep(2)
    left = subprocess.run(["pgrep", "-f", f"sleep {pause}"], capture_output=True, text=True)
    assert left.stdout == "", "the hook still runs in the build container"
    group = subprocess.run(["pgrep", "-g", str(proc.pid)], capture_output=True, text=True)
    assert group.stdout == "", "processes of the interrupted build are left"


def test_a_local_base_image_of_another_architecture_is_refused_before_any_build(
    ros1_base_image: str, tmp_path: Path
) -> None:
    """The classic store's BASE_IMAGE is amd64 and came from no registry; PLATFORM=amd64,arm64
    without `<BASE_IMAGE>-arm64` stops at once with what to do (building from it would pull
    it from Docker Hub, or an engine that cannot would use the wrong architecture)."""
    base = f"docker-ros-test/base-{uuid.uuid4().hex[:8]}:1"
    subprocess.run(["docker", "tag", ros1_base_image, base], check=True)
    try:
        make_package(tmp_path / "pkg", "pkg")
        write_env(tmp_path, BASE_IMAGE=base, IMAGE="docker-ros-test/wrong-arch:1",
                  COMMAND="true", PLATFORM="amd64,arm64")
        result = docker_ros(tmp_path, "build")
    finally:
        subprocess.run(["docker", "image", "rm", base], capture_output=True)
    assert result.returncode != 0
    last = result.stdout.strip().splitlines()[-1]
    assert f"BASE_IMAGE {base} is a local amd64 image from no registry" in last, last
    assert "`inv bootstrap-base-image --platform arm64`" in last and f"{base}-arm64" in last
    assert "==> docker-ros build" not in result.stdout  # not even the amd64 build started
    assert not image_exists("docker-ros-test/wrong-arch:1-amd64")
