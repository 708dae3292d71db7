"""The entrypoint's user mapping (DOCKER_UID/DOCKER_GID/DOCKER_USER) never stops a container:
every collision with an existing user or group warns and goes on. The real entrypoint script
runs in the ROS 1 base image (Debian bookworm's passwd/group), no image build needed.

proves (each a container of the base image with the real entrypoint; no image build):
- every collision of DOCKER_USER/UID/GID with the image's users and groups warns and goes on,
  one warning each, none where nothing collides: test_user_mapping_collisions_warn_and_go_on
- a restarted container maps again without warnings: test_restarted_container_maps_again_...
- a renamed user owns what it writes in a mount: test_renamed_user_owns_the_files_it_writes_...
- the mapped user is in sudo, video and dialout: test_mapped_user_is_in_the_sudo_video_and_...
- a home docker made for a mount below it becomes the user's: test_a_home_docker_made_for_...
- the mapped user gets root's .bashrc: test_mapped_user_gets_roots_bashrc
- the sourced entrypoint only sets up the environment: test_sourced_entrypoint_only_sets_up_...
- an unwritable HOME becomes /tmp, said once; a writable one stays silently:
  test_unwritable_home_becomes_tmp_so_ros_can_log
- --read-only without a writable /tmp names the --tmpfs to add:
  test_read_only_without_a_writable_tmp_names_the_tmpfs"""

from __future__ import annotations

import subprocess
import uuid
from pathlib import Path
from typing import List, Optional

import pytest

from docker_ros.host.buildcontext import PACKAGE_DIR

pytestmark = pytest.mark.docker

ENTRYPOINT = PACKAGE_DIR / "docker" / "entrypoint.sh"
PROBE = ('u=$(getent passwd "$(id -u)" | cut -d: -f1); g=$(getent group "$(id -g)" | cut -d: -f1);'
         ' echo "$(id -u) $(id -g) ${u:--} ${g:--}"')


def mapped(base: str, user: str, uid: int, gid: Optional[int], *docker_args: str,
           script: str = PROBE, rm: bool = True) -> subprocess.CompletedProcess:
    env: List[str] = ["-e", f"DOCKER_USER={user}", "-e", f"DOCKER_UID={uid}"]
    env += ["-e", f"DOCKER_GID={gid}"] if gid is not None else []
    return subprocess.run(
        ["docker", "run", *(["--rm"] if rm else []), "--network", "none",
         "-v", f"{ENTRYPOINT}:/docker-ros/entrypoint.sh:ro",
         "--entrypoint", "/docker-ros/entrypoint.sh", *env, *docker_args, base,
         "bash", "-c", script],
        capture_output=True, text=True, timeout=120,
    )


# (DOCKER_USER, DOCKER_UID, DOCKER_GID) -> "uid gid user group", a warning expected or None.
# bookworm has user daemon (1:1), group users (100), group staff (50) without a user staff.
TABLE = [
    pytest.param("robot", 1234, 1234, "1234 1234 robot robot", None, id="all-new"),
    pytest.param("robot", 1236, None, "1236 1236 robot robot", None, id="gid-defaults-to-uid"),
    pytest.param("daemon", 1237, 1237, "1237 1237 daemon_1237 daemon_1237",
                 "user 'daemon' exists with another UID", id="user-name-exists-gid-new"),
    pytest.param("robot", 1238, 100, "1238 100 robot users",
                 "GID 100 exists already (users)", id="gid-exists-other-name"),
    pytest.param("robot", 1, 1, "1 1 daemon daemon", "UID 1 exists already (daemon)",
                 id="uid-exists"),
    pytest.param("staff", 1239, 1239, "1239 1239 staff staff_1239",
                 "group 'staff' exists with another GID", id="group-name-exists"),
    pytest.param("root", 0, 0, "0 0 root root", None, id="root"),
    pytest.param("dockeruser", 0, 0, "0 0 root root", "UID 0 exists already (root)",
                 id="uid-0-for-another-name"),
    pytest.param("bad:name", 1240, 1240, "1240 1240 - -", "could not create user",
                 id="useradd-fails-runs-unnamed"),
]


@pytest.mark.parametrize("user,uid,gid,expected,warning", TABLE)
def test_user_mapping_collisions_warn_and_go_on(
    ros1_base_image: str, user: str, uid: int, gid: Optional[int], expected: str,
    warning: Optional[str],
) -> None:
    result = mapped(ros1_base_image, user, uid, gid)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == expected, result.stderr
    if warning:
        assert warning in result.stderr
    else:
        assert result.stderr == ""


@pytest.mark.parametrize("user,uid", [("robot", 1244), ("daemon", 1245), ("staff", 1246)])
def test_restarted_container_maps_again_without_warnings(
    ros1_base_image: str, user: str, uid: int
) -> None:
    """`docker restart` and `--restart unless-stopped` run the entrypoint again in the same
    container: the user and group it made at the first start (also renamed ones) are no
    collision, and a robot's logs get no warning at each restart."""
    name = f"docker-ros-test-remap-{uuid.uuid4().hex[:8]}"
    first = mapped(ros1_base_image, user, uid, uid, "--name", name, rm=False)
    try:
        again = subprocess.run(["docker", "start", "-a", name], capture_output=True, text=True,
                               timeout=120)
    finally:
        subprocess.run(["docker", "rm", "-f", name], capture_output=True)
    assert first.returncode == 0 and again.returncode == 0, first.stderr + again.stderr
    assert again.stdout == first.stdout, (first.stdout, again.stdout)
    assert again.stderr == "", again.stderr


def test_renamed_user_owns_the_files_it_writes_in_a_mount(
    ros1_base_image: str, tmp_path: Path
) -> None:
    tmp_path.chmod(0o777)
    result = mapped(ros1_base_image, "daemon", 1241, 1241, "-v", f"{tmp_path}:/data",
                    script="touch /data/made")
    assert result.returncode == 0, result.stderr
    made = (tmp_path / "made").stat()
    assert (made.st_uid, made.st_gid) == (1241, 1241)


def test_mapped_user_is_in_the_sudo_video_and_dialout_groups(ros1_base_image: str) -> None:
    """As docker-ros's `useradd --groups sudo,video`: cameras and GPUs (/dev/video*, /dev/dri,
    group video) work for the mapped user; and serial devices (`--device /dev/ttyUSB0` keeps
    the host's group dialout, which the dev shell's `--device` passes: docs/guide/daily-work.md)."""
    result = mapped(ros1_base_image, "robot", 1242, 1242, script="id -nG")
    assert result.returncode == 0, result.stderr
    assert set(result.stdout.split()) == {"robot", "sudo", "video", "dialout"}, result.stdout
    # a UID the image has already (daemon, 1): that user joins them (ubuntu, 1000, in Noble)
    existing = mapped(ros1_base_image, "robot", 1, 1, script="id -nG")
    assert existing.returncode == 0, existing.stderr
    assert {"sudo", "video", "dialout"} <= set(existing.stdout.split()), existing.stdout


def test_a_home_docker_made_for_a_mount_below_it_is_the_users(ros1_base_image: str,
                                                             tmp_path: Path) -> None:
    """`inv dev-shell --volume ~/.ssh:/home/robot/.ssh:ro`: docker makes /home/robot (root's)
    for the mount, useradd keeps it, and ROS could not write ~/.ros (root's `-w` said yes)."""
    (tmp_path / "ssh").mkdir()
    (tmp_path / "ssh" / "config").write_text("Host *\n")
    result = mapped(ros1_base_image, "robot", 1245, 1245,
                    "-v", f"{tmp_path / 'ssh'}:/home/robot/.ssh:ro",
                    script='mkdir -p ~/.ros && echo "$HOME $(stat -c %u ~) $(ls ~/.ssh)"')
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["/home/robot", "1245", "config"], result.stdout
    assert "not writable" not in result.stderr, result.stderr


def test_mapped_user_gets_roots_bashrc(ros1_base_image: str, tmp_path: Path) -> None:
    """As docker-ros (`cp /root/.bashrc /home/$DOCKER_USER`): what a custom.sh added to root's
    ~/.bashrc (an alias, an export) reaches the mapped user's interactive shells."""
    bashrc = tmp_path / "bashrc"
    bashrc.write_text("export FROM_CUSTOM_SH=yes\n")
    result = mapped(ros1_base_image, "robot", 1244, 1244,
                    "-v", f"{bashrc}:/root/.bashrc:ro",
                    script='bash -i -c \'echo "$FROM_CUSTOM_SH $(stat -c %u ~/.bashrc)"\'')
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["yes", "1244"], result.stdout + result.stderr


def test_sourced_entrypoint_only_sets_up_the_environment(
    ros1_base_image: str, tmp_path: Path
) -> None:
    """/etc/bash.bashrc sources the entrypoint (interactive shells, `docker exec`): it sources
    the workspace and returns, without mapping a user or running a command."""
    setup = tmp_path / "setup.bash"
    setup.write_text("export WORKSPACE_SOURCED=yes\n")
    result = subprocess.run(
        ["docker", "run", "--rm", "--network", "none",
         "-v", f"{ENTRYPOINT}:/docker-ros/entrypoint.sh:ro",
         "-v", f"{setup}:/docker-ros/ws/install/setup.bash:ro", "-e", "DOCKER_UID=1243",
         "--entrypoint", "bash", ros1_base_image, "-c",
         'source /docker-ros/entrypoint.sh; echo "$WORKSPACE_SOURCED $(id -u)"; '
         'if type _dros_map_user >/dev/null 2>&1; then echo functions-left; fi; '
         'echo "setup=${setup-unset}"'],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 0, result.stderr
    # (no function and no variable of the entrypoint's is left in the shell)
    assert result.stdout.split() == ["yes", "0", "setup=unset"], result.stdout + result.stderr


def unmapped(base: str, *docker_args: str) -> subprocess.CompletedProcess:
    """The entrypoint without DOCKER_UID: writes ~/.ros as roslaunch does and prints HOME."""
    return subprocess.run(
        ["docker", "run", "--rm", "--network", "none",
         "-v", f"{ENTRYPOINT}:/docker-ros/entrypoint.sh:ro",
         "--entrypoint", "/docker-ros/entrypoint.sh", *docker_args, base,
         "bash", "-c", 'mkdir -p "$HOME/.ros/log" && echo "$HOME"'],
        capture_output=True, text=True, timeout=120,
    )


@pytest.mark.parametrize("docker_args,home", [
    pytest.param(("--user", "1000:1000"), "/", id="user-without-passwd-entry"),
    pytest.param(("--read-only", "--tmpfs", "/tmp"), "/root", id="read-only-root"),
])
def test_unwritable_home_becomes_tmp_so_ros_can_log(
    ros1_base_image: str, docker_args: tuple, home: str
) -> None:
    """`docker run --user 1000:1000` (HOME=/) or `--read-only` (/root read-only): roslaunch's
    ~/.ros would fail with a PermissionError; the entrypoint uses HOME=/tmp and says so."""
    result = unmapped(ros1_base_image, *docker_args)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "/tmp"
    assert f"HOME ({home}) is not writable; using HOME=/tmp" in result.stderr
    # a writable HOME stays, without a word
    plain = unmapped(ros1_base_image)
    assert (plain.returncode, plain.stdout.strip(), plain.stderr) == (0, "/root", "")


def test_read_only_without_a_writable_tmp_names_the_tmpfs(ros1_base_image: str) -> None:
    result = unmapped(ros1_base_image, "--read-only")
    assert result.returncode != 0
    assert "ROS cannot write its logs (~/.ros); with --read-only, add --tmpfs /tmp" in result.stderr
