"""CI on empty runners (issue 21): the build state travels through the registry next to the
run image; the next build, on a build cache that holds nothing of this project, compiles only
what changed, and builds everything, saying why, when the state does not fit or is missing.
A build state whose build/ cache holds another build's sources (the build RUN cached, the
cache pruned or used since) is built again from its own sources before it is pushed."""

from __future__ import annotations

import re
import shutil
import subprocess
import uuid
from pathlib import Path
from typing import Iterator, List

import pytest

from docker_ros.core.loading import load_settings
from docker_ros.host.buildplan import cache_id
from tests.conftest import cache_record_ids
from tests.docker.buildhelp import docker_ros, write_env
from tests.docker.test_fast_rebuilds import compiled_objects
from tests.rosfixtures import make_package

pytestmark = pytest.mark.docker
PACKAGES = ("pkg_a", "pkg_b", "pkg_c", "pkg_d")


@pytest.fixture
def cache_ids() -> Iterator[List[str]]:
    """The build cache ids the test's copies use; their cache records go after the test."""
    ids: List[str] = []
    yield ids
    for each in ids:
        for record in cache_record_ids(f"docker-ros-build-{each}"):
            subprocess.run(["docker", "buildx", "prune", "-f", "--filter", f"id={record}"],
                           capture_output=True, check=False)


def runner(source: Path, destination: Path, ids: List[str], **env: str) -> Path:
    """The repository as an empty runner checks it out: another path, so a build cache of its
    own (build.cache_id), with .env for this job."""
    shutil.copytree(source, destination)
    write_env(destination, **env)
    settings = load_settings(environ={}, project_dir=destination)
    ids.append(cache_id(settings, "amd64"))
    return destination


def remove_images(ref: str) -> None:
    """Every image of ref's repository (the build state's earlier ones are left untagged)."""
    repository = ref.rsplit(":", 1)[0]
    listed = subprocess.run(["docker", "images", "-q", repository], capture_output=True,
                            text=True)
    subprocess.run(["docker", "rmi", "-f", *set(listed.stdout.split())], capture_output=True,
                   check=False)


def test_build_state_from_the_registry_compiles_only_the_changed_package(
    ros1_base_image: str, local_registry: str, cache_ids: List[str], tmp_path: Path
) -> None:
    ref = f"{local_registry}/docker-ros-test/state-{uuid.uuid4().hex[:8]}:1"
    state = f"{ref}-build-state"
    repo = tmp_path / "repo"
    for name in PACKAGES:
        make_package(repo / name, name)
    env = dict(BASE_IMAGE=ros1_base_image, IMAGE=ref, TARGET="run", BUILD_STATE_FROM=state,
               COMMAND="pkg_a_node && pkg_b_node")
    secret = f"secret-{uuid.uuid4().hex}"
    try:
        first = runner(repo, tmp_path / "job1", cache_ids, **env)
        # built before without a build state, then with one file edited, then that edit undone:
        # push's build RUN is cached (the first build's), its build/ cache holds the edited
        # build; the state is brought back to the sources (pushed as it was, it would hold what
        # no image has been built from, or nothing after BuildKit's GC pruned the cache)
        write_env(first, **{k: v for k, v in env.items() if k != "BUILD_STATE_FROM"})
        source = first / "pkg_b" / "main.cpp"
        original = source.read_text()
        for text in (original, original.replace('"pkg_b', '"pkg_b edited'), original):
            source.write_text(text)
            built = docker_ros(first, "build")
            assert built.returncode == 0, built.stdout[-4000:]
            assert "build-state ->" not in built.stdout
        write_env(first, **env)
        pushed = docker_ros(first, "push", env={"GIT_HTTPS_PASSWORD": secret})
        assert pushed.returncode == 0, pushed.stdout[-4000:]
        assert re.search(r"^#\d+ [\d.]+ build-state: the build cache holds another build's",
                         pushed.stdout, re.MULTILINE), pushed.stdout[-4000:]
        assert "colcon: pkg_b changed: building them and their dependents only" in pushed.stdout
        # (the state's own name, not a longer one; its registry digest follows when known)
        assert re.search(rf"^pushed {re.escape(state)}-amd64( \(sha256:[0-9a-f]+\))?$",
                         pushed.stdout, re.MULTILINE), pushed.stdout[-3000:]
        saved = subprocess.run(["docker", "save", f"{state}-amd64"], capture_output=True,
                               check=True)
        assert secret.encode() not in saved.stdout  # never a secret in the build state
        assert b".docker-ros-install.json" in saved.stdout
        remove_images(ref)

        # the next job on an empty runner: one file edited; the first candidate is missing
        # (a new branch's own state), the second (the default branch's) is taken
        second = runner(repo, tmp_path / "job2", cache_ids,
                        **{**env, "BUILD_STATE_FROM": f"{ref}-none-build-state,{state}"})
        source = second / "pkg_b" / "main.cpp"
        source.write_text(source.read_text().replace('"pkg_b', '"pkg_b changed'))
        edited = docker_ros(second, "build")
        assert edited.returncode == 0, edited.stdout[-4000:]
        assert "starting from the pulled build state" in edited.stdout, [
            line for line in edited.stdout.splitlines() if "colcon:" in line or "state" in line]
        assert list(compiled_objects(edited.stdout)) == ["pkg_b"], compiled_objects(edited.stdout)
        ran = subprocess.run(["docker", "run", "--rm", ref], capture_output=True, text=True,
                             timeout=120)
        assert ran.stdout.split() == ["pkg_a", "pkg_b", "changed"], ran
        remove_images(ref)

        # CMAKE_ARGS changed: everything compiles, and the log says why
        third = runner(repo, tmp_path / "job3", cache_ids, **env,
                       CMAKE_ARGS="-DCMAKE_CXX_FLAGS=-DDOCKER_ROS_X=1")
        changed = docker_ros(third, "build")
        assert changed.returncode == 0, changed.stdout[-4000:]
        assert changed.stdout.count("full build: the colcon arguments") == 1
        assert sorted(compiled_objects(changed.stdout)) == list(PACKAGES)
        remove_images(ref)

        # no build state in the registry: everything compiles, and the log says why
        fourth = runner(repo, tmp_path / "job4", cache_ids,
                        **{**env, "BUILD_STATE_FROM": f"{ref}-none-build-state"})
        missing = docker_ros(fourth, "build")
        assert missing.returncode == 0, missing.stdout[-4000:]
        assert "could not be pulled" in missing.stdout
        assert missing.stdout.count("full build: no build state") == 1
        assert sorted(compiled_objects(missing.stdout)) == list(PACKAGES)
    finally:
        remove_images(ref)
