"""A docker-ros before-dependency-identification hook that changes the system (issue 19): it
adds an apt source (a local flat repository) and a rosdep sources list whose rules map a key to
a package of that repository, and runs `rosdep update`, as docker-ros users do. Resolution and
both images' installs must use them; the run image still holds no sources."""

from __future__ import annotations

import hashlib
import subprocess
import uuid
from pathlib import Path
from typing import Iterator

import pytest

from tests.docker.buildhelp import docker_ros, remove_image, sh, write_env
from tests.rosfixtures import make_package

pytestmark = pytest.mark.docker
RUN_ID = uuid.uuid4().hex[:8]
IMAGE = f"docker-ros-test/hooked-system-{RUN_ID}:1"
DEB = "docker-ros-hooked-tool"
KEY = "docker_ros_hooked_tool"
REPO_DIR = "/opt/docker-ros-hooked-repo"

# (runs from the workspace, as in docker-ros; `rosdep update` cannot reach the public rosdistro
# index here, as on an offline runner, so its failure is tolerated)
HOOK = f"""\
set -e
here="$(dirname "$0")"
mkdir -p {REPO_DIR} /etc/ros/rosdep/sources.list.d
cp "$here"/apt-repo/* {REPO_DIR}/
echo "deb [trusted=yes] file:{REPO_DIR} ./" > /etc/apt/sources.list.d/docker-ros-hooked.list
cp "$here"/hooked-rules.yaml /etc/ros/rosdep/docker-ros-hooked.yaml
echo "yaml file:///etc/ros/rosdep/docker-ros-hooked.yaml" \\
    > /etc/ros/rosdep/sources.list.d/50-docker-ros-hooked.list
rosdep update || echo "rosdep update failed (offline)"
"""


def make_deb(directory: Path, version: str) -> Path:
    """A real .deb of DEB (one marker file) and a flat repository index beside it."""
    root = directory / "pkgroot"
    (root / "DEBIAN").mkdir(parents=True)
    (root / "usr/share" / DEB).mkdir(parents=True)
    (root / "usr/share" / DEB / "marker").write_text(f"{version}\n")
    control = (f"Package: {DEB}\nVersion: {version}\nArchitecture: all\n"
               "Maintainer: tests <tests@docker-ros.invalid>\n"
               "Description: docker-ros test package from a hook's apt source\n")
    (root / "DEBIAN" / "control").write_text(control)
    repo = directory / "apt-repo"
    repo.mkdir()
    deb = repo / f"{DEB}_{version}_all.deb"
    subprocess.run(["dpkg-deb", "--root-owner-group", "--build", str(root), str(deb)],
                   check=True, capture_output=True)
    data = deb.read_bytes()
    (repo / "Packages").write_text(
        control + f"Filename: ./{deb.name}\nSize: {len(data)}\n"
        f"SHA256: {hashlib.sha256(data).hexdigest()}\n\n")
    return repo


@pytest.fixture(scope="module")
def hooked(ros1_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    base = tmp_path_factory.mktemp("hooked")
    repo = base / "repo"
    make_package(repo / "hooked_app", "hooked_app", exec_depends=[KEY])
    docker = repo / "docker"
    docker.mkdir()
    make_deb(base, "1.0-" + RUN_ID).rename(docker / "apt-repo")
    (docker / "hooked-rules.yaml").write_text(f"{KEY}:\n  debian: [{DEB}]\n")
    (docker / "before_dependency_identification.sh").write_text(HOOK)
    write_env(repo, BASE_IMAGE=ros1_base_image, IMAGE=IMAGE, TARGET="dev,run",
              COMMAND="hooked_app_node")
    built = docker_ros(repo, "build")
    try:
        yield {"repo": repo, "log": built.stdout, "code": built.returncode}
    finally:
        remove_image(IMAGE)
        remove_image(IMAGE.replace(":1", ":1-dev"))


def test_the_hooks_rules_and_apt_source_reach_resolution_and_both_images(hooked: dict) -> None:
    log = hooked["log"]
    assert hooked["code"] == 0, log[-6000:]
    assert f"{KEY} -> apt: {DEB}" in log, log[-6000:]
    assert "the hook changed" in log and "/etc/ros/rosdep/sources.list.d" in log
    for ref in (IMAGE, IMAGE.replace(":1", ":1-dev")):
        installed = sh(ref, f"dpkg-query -W -f '${{Version}}' {DEB} && "
                            f"cat /usr/share/{DEB}/marker")
        assert installed.returncode == 0, (ref, installed.stdout, installed.stderr)
        assert RUN_ID in installed.stdout
    # the run image: the installed package and the install space, no sources
    run = sh(IMAGE, "test ! -e /docker-ros/ws/src && hooked_app_node")
    assert run.returncode == 0, run.stdout + run.stderr


def test_without_the_hook_the_key_does_not_resolve(hooked: dict, tmp_path: Path) -> None:
    """The same repository without its hook fails at resolution, naming the key: the test
    above passes because of the hook's system changes, not because of anything else."""
    repo = tmp_path / "repo"
    subprocess.run(["cp", "-a", str(hooked["repo"]), str(repo)], check=True)
    (repo / "docker" / "before_dependency_identification.sh").unlink()
    image = f"docker-ros-test/hooked-system-{RUN_ID}-nohook:1"
    write_env(repo, BASE_IMAGE=(hooked["repo"] / ".env").read_text().split("BASE_IMAGE=")[1]
              .splitlines()[0], IMAGE=image, TARGET="run", COMMAND="hooked_app_node")
    try:
        failed = docker_ros(repo, "build")
    finally:
        remove_image(image)
    assert failed.returncode != 0
    assert f"cannot resolve rosdep key '{KEY}'" in failed.stdout, failed.stdout[-4000:]
