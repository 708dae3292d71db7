"""The real Dev Containers CLI (`devcontainer`, @devcontainers/cli from npm) on the bundled
example plus a `.repos` file importing one package (`up_a`, from a local bare git repository
that a git daemon serves), with the devcontainer.json docker-ros writes for host user 4242
(the tests run as root: the user is given). Proven:

- `up` builds the dev image through the initializeCommand (its clone step imports `up_a` into
  the image's workspace) and starts it;
- `exec colcon build`, in the workspace folder, builds the repository and the imported
  package as the host user (UID 4242: a file it makes in the repository is theirs);
- ROS, the workspace's packages and the imported one are on PATH in `exec`, nothing sourced
  by hand;
- the example's talker and listener hear each other;
- a new dependency in a package.xml is in the image the next `up` gets.

One dev image build, one rebuild (from cache: the new dependency's layers)."""

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
from tests.rosfixtures import free_port, git_daemon, make_git_repo, make_package, write_repos

pytestmark = pytest.mark.docker

IMAGE = "docker-ros-test/devcontainer:latest"
DEV = f"{IMAGE}-dev"
UID = 4242
BUILD = "colcon build"  # in the workspace folder (/docker-ros/ws), as a user types it
IMPORTED = "up_a"  # the package the .repos file imports
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
    """The example with a .repos file importing up_a over git:// from a local bare repository
    (the build's clone step reaches it with BUILD_NETWORK=host), opened with `devcontainer up`."""
    if not shutil.which("devcontainer"):
        pytest.fail("no `devcontainer` command: scripts/setup.sh installs @devcontainers/cli")
    base = tmp_path_factory.mktemp("devcontainer")
    make_package(base / "libs" / IMPORTED, IMPORTED)
    make_git_repo(base / "libs", {}, bare_copy_to=base / "remotes" / "libs.git")
    port = free_port()
    root = copy_example(base / "robot")
    write_repos(root / ".repos", {"libs": {"url": f"git://127.0.0.1:{port}/libs.git",
                                           "version": "main"}})
    (root / ".env").write_text(f"BASE_IMAGE={ros1_base_image}\nIMAGE={IMAGE}\nTARGET=dev\n"
                               "BUILD_NETWORK=host\n"
                               "COMMAND=roslaunch docker_ros_example talker_listener.launch\n")
    # the rule of the dependency a test adds later (rosdep is offline here)
    (root / "docker" / "rosdep.yaml").write_text("json_tool:\n  debian: [jq]\n")
    write_devcontainer(root)
    subprocess.run(["chown", "-R", f"{UID}:{UID}", str(root)], check=True)
    remove_image(DEV)
    daemon = git_daemon(base / "remotes", port)
    try:
        up(root)
        yield root
    finally:
        daemon.terminate()
        daemon.wait(timeout=30)
        for container in containers_of(root):
            subprocess.run(["docker", "rm", "-f", container], capture_output=True)
        remove_image(DEV)
        print("\ndevcontainer CLI times:\n  " + "\n  ".join(TIMES))


def test_up_starts_the_dev_image(repo: Path) -> None:
    """`devcontainer up` (its initializeCommand built the dev image) runs the image the build
    tagged; the imported package is in its workspace (src/upstream), not in the repository."""
    (container,) = containers_of(repo)
    image = subprocess.run(["docker", "inspect", "-f", "{{.Image}}", container],
                           capture_output=True, text=True).stdout.strip()
    dev = subprocess.run(["docker", "image", "inspect", "-f", "{{.Id}}", DEV],
                         capture_output=True, text=True).stdout.strip()
    assert image and image == dev
    listed = subprocess.run(["docker", "exec", container, "ls", "/docker-ros/ws/src/upstream/libs"],
                            capture_output=True, text=True)
    assert listed.stdout.split() == [IMPORTED], listed.stdout + listed.stderr
    assert not (repo / "libs").exists()


def test_exec_builds_the_workspace_as_the_host_user(repo: Path) -> None:
    """`devcontainer exec colcon build` (in the workspace folder) builds the example and the
    imported package as UID 4242, and a file it makes in the mounted repository is 4242's on
    the host."""
    done = run_in(repo, f"{BUILD} && id -u && touch src/target/made-in-the-container")
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert done.stdout.split()[-1] == str(UID)
    assert "Finished <<< docker_ros_example" in done.stdout, done.stdout[-3000:]
    assert f"Finished <<< {IMPORTED}" in done.stdout, done.stdout[-3000:]
    assert not (repo / "build").exists() and not (repo / "install").exists()
    made = (repo / "made-in-the-container").stat()
    assert (made.st_uid, made.st_gid) == (UID, UID)


def test_ros_and_the_workspace_are_on_path_without_sourcing(repo: Path) -> None:
    """roscore, roslaunch, the built workspace's package and the imported package's program
    are found by `exec` of a plain command (no shell, nothing sourced by hand)."""
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
    imported = cli("exec", "--workspace-folder", str(repo), f"{IMPORTED}_node")
    assert imported.returncode == 0, imported.stdout[-3000:] + imported.stderr[-3000:]


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
