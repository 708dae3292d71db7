"""The real Dev Containers CLI (`devcontainer`, @devcontainers/cli from npm) on the bundled
example with the devcontainer.json docker-ros writes: `up` builds the dev image through the
initializeCommand and starts it, `exec` builds the workspace as the host user (UID 4242: the
repository copy is theirs) with ROS and the workspace on PATH, talker and listener hear each
other, and a new dependency in a package.xml is in the image the next `up` gets. One dev image
build, one rebuild (from cache: the new dependency's layers)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
from pathlib import Path
from typing import Dict, Iterator, List

import pytest

from docker_ros.host import devcontainer
from docker_ros.host.config import read_settings
from docker_ros.host.devshell import HostUser, ShellOptions
from tests.docker.buildhelp import REPO, copy_example, remove_image

pytestmark = pytest.mark.docker

IMAGE = "docker-ros-test/devcontainer:latest"
DEV = f"{IMAGE}-dev"
UID = 4242
BUILD = "cd /docker-ros/ws && colcon build --base-paths src"  # as the image's colcon step
TIMES: List[str] = []  # each CLI call and its seconds, printed at the end


def cli_env() -> Dict[str, str]:
    """The editor's environment: docker-ros of this checkout for the initializeCommand."""
    env = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), str(REPO)])
    env["ENABLE_SLIM"] = "false"
    return env


def cli(*args: str, timeout: int = 1200) -> subprocess.CompletedProcess:
    start = time.monotonic()
    done = subprocess.run(["devcontainer", *args], capture_output=True, text=True,
                          env=cli_env(), timeout=timeout)
    TIMES.append(f"{' '.join(args[:1] + args[3:5])}: {time.monotonic() - start:.1f} s")
    return done


def outcome(done: subprocess.CompletedProcess) -> Dict[str, str]:
    """The JSON line `devcontainer up` ends its stdout with."""
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    assert lines, done.stdout[-3000:] + done.stderr[-3000:]
    return json.loads(lines[-1])


def up(repo: Path, *extra: str) -> Dict[str, str]:
    done = cli("up", "--workspace-folder", str(repo), *extra)
    result = outcome(done)
    assert result.get("outcome") == "success", done.stdout[-4000:] + done.stderr[-4000:]
    return result


def run_in(repo: Path, script: str, timeout: int = 600) -> subprocess.CompletedProcess:
    return cli("exec", "--workspace-folder", str(repo), "bash", "-c", script, timeout=timeout)


def containers_of(repo: Path) -> List[str]:
    found = subprocess.run(["docker", "ps", "-aq", "--filter",
                            f"label=devcontainer.local_folder={repo}"],
                           capture_output=True, text=True)
    return found.stdout.split()


def write_devcontainer(repo: Path) -> Dict[str, object]:
    """devcontainer.json as `inv devcontainer` writes it for host user 4242 (the tests run as
    root: its user is given, as dev-shell's tests give theirs)."""
    settings = read_settings({}, {}, project_dir=repo, environ={"BUILD_CONTEXT": str(repo)})
    config, _notes = devcontainer.config_for(
        settings, DEV, ShellOptions(), user=HostUser(UID, UID, "alice"), display="",
        gpus="none", image_present=False)
    result = devcontainer.plan(settings, config)
    devcontainer.write(result)
    return result.content


@pytest.fixture(scope="module")
def repo(ros1_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    if not shutil.which("devcontainer"):
        pytest.fail("no `devcontainer` command: scripts/setup.sh installs @devcontainers/cli")
    root = copy_example(tmp_path_factory.mktemp("devcontainer") / "robot")
    (root / ".env").write_text(f"BASE_IMAGE={ros1_base_image}\nIMAGE={IMAGE}\nTARGET=dev\n"
                               "COMMAND=roslaunch docker_ros_example talker_listener.launch\n")
    # the rule of the dependency a test adds later (rosdep is offline here)
    (root / "docker" / "rosdep.yaml").write_text("json_tool:\n  debian: [jq]\n")
    write_devcontainer(root)
    subprocess.run(["chown", "-R", f"{UID}:{UID}", str(root)], check=True)
    remove_image(DEV)
    try:
        up(root)
        yield root
    finally:
        for container in containers_of(root):
            subprocess.run(["docker", "rm", "-f", container], capture_output=True)
        remove_image(DEV)
        print("\ndevcontainer CLI times:\n  " + "\n  ".join(TIMES))


def test_up_starts_the_dev_image(repo: Path) -> None:
    """`devcontainer up` (its initializeCommand built the dev image) runs the image the build
    tagged."""
    (container,) = containers_of(repo)
    image = subprocess.run(["docker", "inspect", "-f", "{{.Image}}", container],
                           capture_output=True, text=True).stdout.strip()
    dev = subprocess.run(["docker", "image", "inspect", "-f", "{{.Id}}", DEV],
                         capture_output=True, text=True).stdout.strip()
    assert image and image == dev


def test_exec_builds_the_workspace_as_the_host_user(repo: Path) -> None:
    """`devcontainer exec` runs colcon as the image's colcon step does, as UID 4242, and a file
    it makes in the mounted repository is 4242's on the host."""
    done = run_in(repo, f"{BUILD} && id -u && touch src/target/made-in-the-container")
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert done.stdout.split()[-1] == str(UID)
    made = (repo / "made-in-the-container").stat()
    assert (made.st_uid, made.st_gid) == (UID, UID)


def test_ros_and_the_workspace_are_on_path_without_sourcing(repo: Path) -> None:
    """roscore, roslaunch and the built workspace's package are found by `exec` of a plain
    command (no shell, nothing sourced by hand)."""
    built = run_in(repo, f"test -d /docker-ros/ws/install || {BUILD} >/dev/null")
    assert built.returncode == 0, built.stderr[-3000:]
    # (exec runs no shell of its own: the environment is the login shell's, probed)
    done = cli("exec", "--workspace-folder", str(repo), "rospack", "find", "docker_ros_example")
    assert done.returncode == 0, done.stderr[-3000:]
    found = done.stdout.strip()
    assert found.startswith("/docker-ros/ws/install/") and found.endswith(
        "/share/docker_ros_example"), found
    which = cli("exec", "--workspace-folder", str(repo), "which", "roscore", "roslaunch")
    assert which.returncode == 0 and len(which.stdout.split()) == 2, which.stderr[-3000:]


def test_talker_and_listener_hear_each_other(repo: Path) -> None:
    """The example's launch file, run by `exec`: the listener hears the talker."""
    built = run_in(repo, f"test -d /docker-ros/ws/install || {BUILD} >/dev/null")
    assert built.returncode == 0, built.stderr[-3000:]
    script = ("roslaunch docker_ros_example talker_listener.launch > /tmp/launch.log 2>&1 & "
              "for _ in $(seq 120); do grep -m 1 'I heard' /tmp/launch.log && break; sleep 0.5; "
              "done; kill -INT %1; wait")
    done = run_in(repo, script, timeout=120)
    assert "I heard: hello from docker-ros" in done.stdout, done.stderr[-3000:]


def test_a_new_dependency_is_in_the_image_opened_again(repo: Path) -> None:
    """The package.xml gets a dependency; "Rebuild Container" (`up --remove-existing-container`)
    runs the initializeCommand, whose build installs it, and starts the new image."""
    package = repo / "docker_ros_example" / "package.xml"
    package.write_text(package.read_text().replace(
        "<exec_depend>rospy</exec_depend>",
        "<exec_depend>rospy</exec_depend>\n  <exec_depend>json_tool</exec_depend>"))
    missing = run_in(repo, "command -v jq")
    assert missing.returncode != 0
    up(repo, "--remove-existing-container")
    done = run_in(repo, "command -v jq")
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
