"""docker-ros.lock in image builds (issue 23), with real material: an upstream repository on a
local git server, real apt in the images, a local wheel index for pip. One module-scoped
sequence: `inv lock` (resolved in the image's lock stages), then a new upstream commit and a
newer wheel: the locked build keeps the locked commit and versions (dpkg-query / pip in both
images equal the lock's entries; both carry the lock's digest), an unlocked dev build takes the
new ones; a new debs line or a version the archive no longer has stop a locked build, named.
The base image lacks tini, so prepare installs it (and the dev image's toolchain): the lock
holds what prepare installed too.

proves (each line: where; "image" = a test here, on the module's images or builds):
- `inv lock` resolves dev and run in the lock stages (commit, apt, pip, inputs, base digest,
  prepare's packages, the toolchain in dev only): image, test_inv_lock_resolves_each_target_...
- `inv lock --check` names the moved upstream commit and the newer wheel, then says stale:
  image, test_lock_check_names_the_new_upstream_commit
- a locked build installs exactly the lock (labels, dpkg, pip, no pins left, the locked
  commit): image, test_locked_build_installs_exactly_the_lock
- a pip requirement Debian satisfies keeps Debian's version, locked and built: image,
  test_a_pip_requirement_debian_satisfies_keeps_debian_s_version
- a locked build from scratch (NO_CACHE, another copy) installs the same: image,
  test_a_locked_build_from_scratch_installs_the_same
- a locked lean run image has the locked dev image's versions: image,
  test_a_locked_lean_run_image_has_the_locked_dev_image_versions
- an unlocked build takes the new commit and wheel: image, test_unlocked_build_takes_the_new_
  commit_and_wheel (now in a copy under its own name: it overwrote the module's locked dev
  image that four tests read, which passed only when they ran first)
- a new debs line stops a locked build in the lock stage, named, before any install stage:
  image, test_locked_build_stops_on_a_new_dependency_naming_it (the wording of every change:
  unit, tests/unit/test_lock.py::test_stale_inputs_name_each_change)
- a locked apt version the archive dropped stops the build naming it and the image's real apt
  sources: image, test_locked_version_no_longer_available_is_named_with_its_source (the
  wording: unit, tests/unit/test_lock_messages.py)
- a locked pip version the index dropped is named with pip's sources: unit,
  tests/unit/test_lock_messages.py (check_pip_available's message) and tests/unit/test_lock.py
  (unavailable_pins on pip's own words); it reaches the user the way the apt one does (image
  test above). Was a failing image build of its own.
- a locked prepare version no longer available stops prepare, naming it with the sources:
  unit, tests/unit/test_prepare.py (held_to_lock's check and message); real apt with a pin to
  a version its sources lack installs the newest (what that check then sees): image,
  test_apt_installs_the_pinned_version_where_a_newer_one_is_offered. Was a failing image build.
- apt_preferences' pins hold real apt to the locked version where a newer one is offered:
  image, test_apt_installs_the_pinned_version_where_a_newer_one_is_offered"""

from __future__ import annotations

import json
import subprocess
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Dict, Iterator, Tuple

import pytest

from docker_ros.core.loading import host_platform
from docker_ros.host import engine
from docker_ros.in_image.runtime.lockapt import apt_preferences
from docker_ros.in_image.runtime.lockfile import LOCK_FILE, dump_lock, local_base_tag, lock_digest
from tests.docker.buildhelp import (
    docker_ros,
    dpkg_versions,
    own_copy,
    remove_image,
    sh,
    write_env,
)
from tests.rosfixtures import (
    file_http_server,
    git,
    git_http_server,
    make_git_repo,
    make_package,
    make_wheel,
    write_repos,
)

pytestmark = pytest.mark.docker
IMAGE = "docker-ros-test/lock-ws:1"
BASE = f"docker-ros-test/lock-base:{uuid.uuid4().hex[:8]}"
USER, PASSWORD = "robot", "lock-test-secret"
WHEEL = "docker-ros-lock-probe"
MODULE = "docker_ros_lock_probe"
LABEL = "org.docker-ros.lock"


def pip_versions(ref: str) -> Dict[str, str]:
    frozen = sh(ref, "python3 -m pip freeze --all 2>/dev/null")
    assert frozen.returncode == 0, frozen.stderr
    return {n.lower().replace("_", "-"): v for n, _, v in
            (line.partition("==") for line in frozen.stdout.splitlines()) if v}


@pytest.fixture(scope="module")
def base_image(ros1_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The ROS 1 test base without tini: the base stage's prepare installs it."""
    context = tmp_path_factory.mktemp("lock-base")
    (context / "Dockerfile").write_text(f"FROM {ros1_base_image}\nRUN dpkg --purge tini\n")
    subprocess.run(["docker", "buildx", "build", "--load", "-q", "-t", BASE, str(context)],
                   check=True, capture_output=True)
    yield BASE
    remove_image(BASE)


@pytest.fixture(scope="module")
def project(base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    base = tmp_path_factory.mktemp("lock-ws")
    libs = base / "work" / "upstream_libs"
    make_package(libs / "up_a", "up_a")
    (libs / "VERSION").write_text("one\n")
    remotes = base / "remotes"
    remotes.mkdir()
    make_git_repo(libs, {}, bare_copy_to=remotes / "upstream_libs.git")
    server = git_http_server(remotes, USER, PASSWORD)
    host = f"127.0.0.1:{server.server_address[1]}"
    # a wheel index of this run (a new path: no cached layer of an earlier run stands for it)
    served = base / "served"
    wheels = served / uuid.uuid4().hex
    wheels.mkdir(parents=True)
    make_wheel(wheels, MODULE, "1.0")
    index = file_http_server(served)

    repo = base / "repo"
    # rosdep keys my_tool -> sl and my_dev_lib -> libyaml-cpp-dev (exec: dev and run; a lean
    # run image drops the -dev package), from the repository's own rules
    make_package(repo / "app", "app", exec_depends=["my_tool", "my_dev_lib"])
    (repo / "docker").mkdir()
    (repo / "docker" / "rosdep.yaml").write_text(
        f"# run {uuid.uuid4().hex}\nmy_tool:\n  debian: [sl]\n"
        "my_dev_lib:\n  debian: [libyaml-cpp-dev]\n")
    # termcolor: from Debian (python3-termcolor) before the pip step, whose requirement it
    # satisfies, though the index has a newer one
    make_wheel(wheels, "termcolor", "99.0")
    (repo / "docker" / "additional-debs.txt").write_text("cmatrix\npython3-termcolor\n")
    (repo / "docker" / "additional-pip-requirements.txt").write_text(
        f"--no-index --find-links http://127.0.0.1:{index.server_address[1]}/{wheels.name}/\n"
        f"{MODULE}\ntermcolor\n")
    write_repos(repo / ".repos", {"upstream_libs": {"url": f"http://{host}/upstream_libs.git",
                                                    "version": "main"}})
    write_env(repo, BASE_IMAGE=base_image, IMAGE=IMAGE, TARGET="dev,run",
              COMMAND="up_a_node", BUILD_NETWORK="host", GIT_HTTPS_SERVER=host,
              GIT_HTTPS_USER=USER)
    env = {"GIT_HTTPS_PASSWORD": PASSWORD}
    locked = docker_ros(repo, "lock", env=env)
    assert locked.returncode == 0, locked.stdout[-5000:]
    first = git(["rev-parse", "HEAD"], libs).strip()
    # then upstream and the index move on: a new commit, a newer wheel
    (libs / "VERSION").write_text("two\n")
    git(["commit", "-qam", "two"], libs)
    git(["push", "-q", str(remotes / "upstream_libs.git"), "HEAD:main"], libs)
    make_wheel(wheels, MODULE, "1.1")
    build = docker_ros(repo, "build", "--set", "LOCKED=true", env=env)
    try:
        yield {"repo": repo, "env": env, "lock_log": locked.stdout, "build": build,
               "first": first, "newest": git(["rev-parse", "HEAD"], libs).strip()}
    finally:
        server.shutdown()
        server.server_close()
        index.shutdown()
        index.server_close()
        for ref in (IMAGE, IMAGE + "-dev"):
            remove_image(ref)
        # the tag a locked build gave the local base image (an untag: the image stays)
        remove_image(local_base_tag(base_image, engine.inspect_image(base_image)["Id"]))


def entries(project: dict) -> Dict[str, dict]:
    return json.loads((project["repo"] / LOCK_FILE).read_text())["targets"]


def test_inv_lock_resolves_each_target_in_the_images(project: dict) -> None:
    arch = host_platform()
    targets = entries(project)
    assert sorted(targets) == [f"dev/{arch}", f"run/{arch}"]
    assert "lock-results" in project["lock_log"]  # the lock stages, not an image build
    assert "lock: " in project["lock_log"].strip().splitlines()[-1]
    for entry in targets.values():
        assert entry["repos"]["upstream/upstream_libs"]["commit"] == project["first"]
        assert {"sl", "cmatrix"} <= set(entry["apt"])
        assert entry["pip"][WHEEL]["version"] == "1.0"
        assert entry["inputs"]["debs"] == ["cmatrix", "python3-termcolor"]
        assert entry["inputs"]["rosdep_rules"].startswith("sha256:")
        assert entry["base_image"]["digest"].startswith("sha256:")
        assert "tini" in entry["prepare"]  # installed by prepare: not in the base image
    dev, run = targets[f"dev/{arch}"], targets[f"run/{arch}"]
    assert "g++" in dev["prepare"] and "g++" not in run["prepare"]  # the toolchain: dev only
    assert run["prepare"].items() <= dev["prepare"].items()


def test_lock_check_names_the_new_upstream_commit(project: dict) -> None:
    checked = docker_ros(project["repo"], "lock", "--check", env=project["env"])
    assert checked.returncode != 0, checked.stdout[-3000:]
    lines = checked.stdout.splitlines()
    arch = host_platform()
    moved = [line for line in lines
             if line.startswith(f"dev/{arch}: repos upstream/upstream_libs ")]
    assert moved and project["first"] in moved[0] and project["newest"] in moved[0], lines[-20:]
    newer = [line for line in lines if line.startswith(f"run/{arch}: pip {WHEEL} ")]
    assert newer and "'version': '1.0'" in newer[0] and "'version': '1.1'" in newer[0], lines[-20:]
    assert "docker-ros.lock is stale: run `inv lock`" in checked.stdout.strip().splitlines()[-1]


def test_locked_build_installs_exactly_the_lock(project: dict) -> None:
    build = project["build"]
    assert build.returncode == 0, build.stdout[-5000:]
    assert "lock: locked build, docker-ros.lock sha256:" in build.stdout
    digest = lock_digest((project["repo"] / LOCK_FILE).read_text())
    arch = host_platform()
    for ref, target in ((IMAGE + "-dev", "dev"), (IMAGE, "run")):
        entry = entries(project)[f"{target}/{arch}"]
        inspected = json.loads(subprocess.run(["docker", "image", "inspect", ref],
                                              capture_output=True, text=True).stdout)
        assert inspected[0]["Config"]["Labels"][LABEL] == digest
        installed = dpkg_versions(ref)
        for kind in ("prepare", "apt"):
            assert {n: installed.get(n) for n in entry[kind]} == entry[kind], (target, kind)
        # the pins held apt while prepare ran, and went with it
        assert sh(ref, "ls /etc/apt/preferences.d").stdout.split() == [], target
        pips = pip_versions(ref)
        assert {n: pips.get(n) for n in entry["pip"]} == {
            n: e["version"] for n, e in entry["pip"].items()}, target
    # the locked commit, not upstream's newest
    version = sh(IMAGE + "-dev", "cat /docker-ros/ws/src/upstream/upstream_libs/VERSION")
    assert version.stdout.strip() == "one", version.stdout + version.stderr


def test_a_pip_requirement_debian_satisfies_keeps_debian_s_version(project: dict) -> None:
    """As the pip step finds termcolor installed from Debian, so does the lock's dry run: no
    pip entry, and the locked images keep Debian's termcolor, not the index's 99.0."""
    assert project["build"].returncode == 0
    for ref, target in ((IMAGE + "-dev", "dev"), (IMAGE, "run")):
        entry = entries(project)[f"{target}/{host_platform()}"]
        assert "python3-termcolor" in entry["apt"] and "termcolor" not in entry["pip"], target
        assert WHEEL in entry["pip"], target  # what only the index has stays pip's
        frozen, debian = pip_versions(ref)["termcolor"], entry["apt"]["python3-termcolor"]
        assert frozen != "99.0" and debian.startswith(frozen + "-"), (ref, frozen, debian)


def install_space(ref: str) -> str:
    listed = sh(ref, "cd /docker-ros/ws/install && find . | LC_ALL=C sort")
    assert listed.returncode == 0, listed.stderr
    return listed.stdout


@contextmanager
def built_copy(project: dict, tmp_path: Path, name: str, *args: str, locked: bool = True
               ) -> Iterator[Tuple[str, subprocess.CompletedProcess]]:
    """A build (locked unless told; args added) of a copy of the project, its images tagged
    with a new name starting with `name`, so that the module's locked images stay what the
    other tests read, in any order: (the run image's tag, the build); the images go
    afterwards."""
    image = f"docker-ros-test/{name}-{uuid.uuid4().hex[:8]}:1"
    copy = own_copy(project["repo"], tmp_path / "repo", image)
    lock = ["--set", "LOCKED=true"] if locked else []
    try:
        yield image, docker_ros(copy, "build", *lock, *args, env=project["env"])
    finally:
        remove_image(image)
        remove_image(image + "-dev")


def test_a_locked_build_from_scratch_installs_the_same(project: dict, tmp_path: Path) -> None:
    """The module's locked build and another locked build of the dev and run images in a copy
    that reuses no layer of it (NO_CACHE; another folder and name: a colcon build cache of its
    own), made after upstream and the wheel index moved on: in each image the same Debian and
    pip packages at the same versions, the same imported commit, and in the run image the same
    install-space file list."""
    assert project["build"].returncode == 0
    with built_copy(project, tmp_path, "lock-ws-again", "--target", "dev,run",
                    "--set", "NO_CACHE=true") as (again, built):
        assert built.returncode == 0, built.stdout[-5000:]
        # the dependency steps ran again (no cached layer), installing the locked versions
        assert "rosdep: apt-get install -y --no-install-recommends" in built.stdout
        for ours, theirs in ((again + "-dev", IMAGE + "-dev"), (again, IMAGE)):
            for listing in (dpkg_versions, pip_versions):
                assert listing(ours) == listing(theirs), (ours, listing.__name__)
        assert install_space(again) == install_space(IMAGE)
        upstream = "cat /docker-ros/ws/src/upstream/upstream_libs/VERSION"
        assert sh(again + "-dev", upstream).stdout.strip() == "one"


def test_a_locked_lean_run_image_has_the_locked_dev_image_versions(
        project: dict, tmp_path: Path) -> None:
    """ENABLE_LEAN_RUN_IMAGE with LOCKED: the lean set (sl, not libyaml-cpp-dev, which nothing
    in install/ links) and what it depends on, each at the locked dev image's version."""
    assert project["build"].returncode == 0
    with built_copy(project, tmp_path, "lock-lean", "--target", "run",
                    "--set", "ENABLE_LEAN_RUN_IMAGE=true") as (lean, built):
        assert built.returncode == 0, built.stdout[-5000:]
        assert "lock: locked build" in built.stdout
        installed, dev = dpkg_versions(lean), dpkg_versions(IMAGE + "-dev")
        assert "sl" in installed and "libyaml-cpp-dev" not in installed
        assert "libyaml-cpp-dev" in dpkg_versions(IMAGE)  # the locked run image, not lean
        assert {n: dev.get(n) for n in installed} == installed


def test_unlocked_build_takes_the_new_commit_and_wheel(project: dict, tmp_path: Path) -> None:
    """An unlocked build takes upstream's new commit and the index's newer wheel (built in a
    copy under a name of its own: the module's dev image stays the locked one the other tests
    read, in any order)."""
    with built_copy(project, tmp_path, "lock-unlocked", "--target", "dev",
                    locked=False) as (image, unlocked):
        assert unlocked.returncode == 0, unlocked.stdout[-5000:]
        assert "lock: not in use" in unlocked.stdout
        version = sh(image + "-dev", "cat /docker-ros/ws/src/upstream/upstream_libs/VERSION")
        assert version.stdout.strip() == "two", version.stdout + version.stderr
        assert pip_versions(image + "-dev")[WHEEL] == "1.1"


def locked_build_with(project: dict, path: Path, text: str) -> subprocess.CompletedProcess:
    """A locked build with `path` holding `text`, then the file as it was."""
    before = path.read_text()
    path.write_text(text)
    try:
        return docker_ros(project["repo"], "build", "--set", "LOCKED=true", env=project["env"])
    finally:
        path.write_text(before)


def locked_build_with_versions(project: dict, kind: str, name: str, version: object
                               ) -> subprocess.CompletedProcess:
    """A locked build with the lock's `kind` record of `name` at `version` in every entry."""
    path = project["repo"] / LOCK_FILE
    data = json.loads(path.read_text())
    for entry in data["targets"].values():
        entry[kind][name] = version
    return locked_build_with(project, path, dump_lock(data))


def test_locked_build_stops_on_a_new_dependency_naming_it(project: dict) -> None:
    debs = project["repo"] / "docker" / "additional-debs.txt"
    failed = locked_build_with(project, debs, debs.read_text() + "figlet\n")
    assert failed.returncode != 0, failed.returncode
    lines = failed.stdout.strip().splitlines() or [f"(no output, exit {failed.returncode})"]
    last = lines[-1]
    # in the resolve stage, after the collect phases: before any install stage starts
    assert "failed in step lock: LOCKED: the repository no longer matches docker-ros.lock " \
           "(debs: added figlet): run `inv lock`" in last, failed.stdout[-3000:]


def test_locked_version_no_longer_available_is_named_with_its_source(project: dict) -> None:
    failed = locked_build_with_versions(project, "apt", "cmatrix", "0.0-gone1")
    assert failed.returncode != 0
    assert "LOCKED: cmatrix=0.0-gone1 no longer available from apt's sources (" in failed.stdout, \
        failed.stdout[-3000:]
    assert "deb.debian.org" in failed.stdout.split("cmatrix=0.0-gone1 no longer available")[1]


# two versions of a package in a flat apt repository of the container's own, then an install
PROBE_REPOSITORY = r"""set -e
mkdir -p /tmp/repo && cd /tmp/repo
for v in 1.0 1.1; do
  mkdir -p p$v/DEBIAN
  printf 'Package: docker-ros-probe\nVersion: %s\nArchitecture: all\n' $v > p$v/DEBIAN/control
  printf 'Maintainer: t <t@t.t>\nDescription: probe\n' >> p$v/DEBIAN/control
  dpkg-deb -b p$v probe_$v.deb >/dev/null
done
dpkg-scanpackages -m . > Packages 2>/dev/null
echo 'deb [trusted=yes] file:/tmp/repo ./' > /etc/apt/sources.list.d/probe.list
apt-get update -o Dir::Etc::sourceparts=- \
    -o Dir::Etc::sourcelist=/etc/apt/sources.list.d/probe.list >/dev/null
printf '%s' "$PREFERENCES" > /etc/apt/preferences.d/docker-ros-lock
apt-get install -y docker-ros-probe >/dev/null
dpkg-query -W -f '${Version}' docker-ros-probe"""


def test_apt_installs_the_pinned_version_where_a_newer_one_is_offered(project: dict) -> None:
    """What held_to_lock writes (apt_preferences) in real apt: the locked 1.0, not 1.1; a pin
    to a version the sources no longer have holds nothing (apt installs 1.1, which held_to_lock
    then names: tests/unit/test_prepare.py)."""
    assert project["build"].returncode == 0
    for pins, expected in (({"docker-ros-probe": "1.0"}, "1.0"), ({}, "1.1"),
                           ({"docker-ros-probe": "0.9-gone1"}, "1.1")):
        installed = sh(IMAGE + "-dev", PROBE_REPOSITORY,
                       "-e", f"PREFERENCES={apt_preferences(pins)}")
        assert installed.returncode == 0, installed.stderr[-2000:]
        assert installed.stdout.strip().splitlines()[-1] == expected, installed.stdout
