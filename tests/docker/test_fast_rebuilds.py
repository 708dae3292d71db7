"""Fast rebuilds (issue 5): cache mounts recompile one package, a registry image serves as
cache on an empty machine (the CA setting of the same issue: test_extra_ca_certs.py)."""

from __future__ import annotations

import os
import re
import subprocess
import uuid
from pathlib import Path
from typing import Dict, List

import pytest

from tests.docker.buildhelp import cached_vertices, docker_ros, run_unique, write_env
from tests.rosfixtures import make_package

pytestmark = pytest.mark.docker


def compiled_objects(log: str) -> Dict[str, List[str]]:
    """colcon's per-package output (console_cohesion+) -> the objects make compiled."""
    compiled: Dict[str, List[str]] = {}
    package = None
    for line in log.splitlines():
        text = re.sub(r"^#\d+ [\d.]+ ", "", line)
        started = re.match(r"--- output: (\S+)", text)
        if started:
            package = started.group(1)
            continue
        if package and "Building CXX object" in text:
            compiled.setdefault(package, []).append(text.split("Building CXX object")[-1])
    return compiled


def test_one_file_change_recompiles_one_package(ros1_base_image: str, tmp_path: Path) -> None:
    for name in ("pkg_a", "pkg_b", "pkg_c"):
        make_package(tmp_path / name, name)
    run_unique(tmp_path / "pkg_a" / "main.cpp")
    write_env(tmp_path, BASE_IMAGE=ros1_base_image, IMAGE="docker-ros-test/fast:1",
              COMMAND="pkg_a_node && pkg_b_node && pkg_c_node")
    first = docker_ros(tmp_path, "build", "--target", "run")
    assert first.returncode == 0, first.stdout[-4000:]

    source = tmp_path / "pkg_b" / "main.cpp"
    source.write_text(source.read_text().replace('"pkg_b', '"pkg_b changed'))
    second = docker_ros(tmp_path, "build", "--target", "run")
    assert second.returncode == 0, second.stdout[-4000:]
    assert list(compiled_objects(second.stdout)) == ["pkg_b"], compiled_objects(second.stdout)
    # the source stage starts from the skeleton (manifests, list files): a .cpp edit runs
    # neither clone nor blacklist nor resolve
    states = cached_vertices(second.stdout)
    source_runs = {n: c for n, c in states.items() if n.startswith(("[source ", "[resolve "))}
    assert len(source_runs) == 2 and all(source_runs.values()), source_runs

    ran = subprocess.run(["docker", "run", "--rm", "docker-ros-test/fast:1"],
                         capture_output=True, text=True, timeout=120)
    assert ran.stdout.split() == ["pkg_a", "pkg_b", "changed", "pkg_c"], ran
    assert "pkg_b changed: building them and their dependents only" in second.stdout

    # A package removed: a full build, and the install space (kept in the cache for
    # incremental builds) no longer holds it.
    for path in sorted((tmp_path / "pkg_c").rglob("*"), reverse=True):
        path.unlink() if path.is_file() else path.rmdir()
    (tmp_path / "pkg_c").rmdir()
    write_env(tmp_path, BASE_IMAGE=ros1_base_image, IMAGE="docker-ros-test/fast:1",
              COMMAND="ls /docker-ros/ws/install")
    third = docker_ros(tmp_path, "build", "--target", "run")
    assert third.returncode == 0, third.stdout[-4000:]
    assert "--packages-above" not in third.stdout and not compiled_objects(third.stdout)
    listed = subprocess.run(["docker", "run", "--rm", "docker-ros-test/fast:1"],
                            capture_output=True, text=True, timeout=120)
    assert "pkg_a" in listed.stdout.split() and "pkg_c" not in listed.stdout.split(), listed


def test_registry_images_serve_as_cache_on_an_empty_machine(
    ros1_base_image: str, local_registry: str, empty_engine: str, tmp_path: Path
) -> None:
    """CACHE_FROM with the dev and the run image, as CI jobs default to: on a machine with an
    empty build cache the dependency layers of both images come from the registry (the run
    image's because its chain starts from base-run, see the Dockerfile). The local_registry
    fixture removes the images named after the registry."""
    ref = f"{local_registry}/docker-ros-test/cached:latest"
    make_package(tmp_path / "pkg", "pkg")
    (tmp_path / "docker").mkdir()
    (tmp_path / "docker" / "additional-debs.txt").write_text("jq\n")
    # new to the engine: no dependency layer of an earlier run serves the first build
    (tmp_path / "docker" / "additional-files").mkdir()
    (tmp_path / "docker" / "additional-files" / "run-id").write_text(uuid.uuid4().hex)
    write_env(tmp_path, BASE_IMAGE=ros1_base_image, IMAGE=ref, COMMAND="jq --version",
              CACHE_FROM=f"{ref}-dev,{ref}", TARGET="dev,run", BUILD_NETWORK="host")
    pushed = docker_ros(tmp_path, "push")
    assert pushed.returncode == 0, pushed.stdout[-4000:]
    assert f"pushed {ref}" in pushed.stdout and f"pushed {ref}-dev" in pushed.stdout

    # An empty machine: a daemon of its own with no image but the base and no build cache
    # (host network, on both machines as it is part of the cache keys: what is not cached
    # installs from the apt sources).
    rebuilt = docker_ros(tmp_path, "build", env={"DOCKER_HOST": empty_engine})
    assert rebuilt.returncode == 0, rebuilt.stdout[-4000:]
    dev, run = rebuilt.stdout.split("==> docker-ros build (amd64) run")
    installs = {name: cached for name, cached in cached_vertices(dev).items()
                if name.startswith(("[dependencies-dev", "[resolved-dev"))}
    assert len(installs) == 3 and all(installs.values()), installs
    installs = {name: cached for name, cached in cached_vertices(run).items()
                if name.startswith(("[dependencies-run", "[base-run")) and " FROM " not in name}
    # base-run's prepare, entrypoint, bash.bashrc line and WORKDIR, and dependencies-run's
    # install (the base image's FROM is one vertex for base and base-run, named after either)
    assert len(installs) == 5 and all(installs.values()), installs
    on_empty = {**os.environ, "DOCKER_HOST": empty_engine}
    jq = subprocess.run(["docker", "run", "--rm", ref, "jq", "--version"], env=on_empty,
                        capture_output=True, text=True)
    assert jq.stdout.startswith("jq-"), jq.stderr
