"""A buildx docker-container builder (BUILDER), the kind GitHub's docker/setup-buildx-action
makes: BuildKit in a container of its own, with no image store. Its buildkitd is built from
Debian's source (tests.engines.buildkit_image: moby/buildkit cannot be pulled here) and runs on
Engine 26 (Engine 20.10 here cannot start the privileged container it needs)."""

from __future__ import annotations

import re
import subprocess
import uuid
from pathlib import Path
from typing import Dict

import pytest

from tests import engines
from tests.ci.cihelp import EXAMPLE_COMMAND, assert_pulled_image_runs, registry_tags
from tests.docker.buildhelp import (
    cached_vertices,
    copy_example,
    docker_ros,
    not_from_cache,
    write_env,
)
from tests.engines import ENGINE26_HOST, container_builder

pytestmark = pytest.mark.docker

REGISTRY_CACHE = "CACHE_TO: registry cache of every stage (mode=max)"


def on_engine26(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(["docker", *argv], env=engines.env_for(ENGINE26_HOST),
                          capture_output=True, text=True)


def targets(log: str) -> Dict[str, str]:
    """A build's log per target (`==> docker-ros build (amd64) run -> ...`)."""
    parts = re.split(r"^==> docker-ros build \(\w+\) ([\w-]+) -> .*$", log, flags=re.MULTILINE)
    return dict(zip(parts[1::2], parts[2::2]))


def last_step(vertex: str, target: str) -> bool:
    """Is the vertex (`[run 3/3] RUN ...`) the last step of the target's own stage?"""
    match = re.match(rf"\[{re.escape(target)} (\d+)/(\d+)\]", vertex)
    return bool(match) and match.group(1) == match.group(2)


def test_a_docker_container_builder_pushes_and_an_empty_one_builds_from_its_cache(
    buildkit_image: str, kept_builder: str, ros1_base_image: str, local_registry: str,
    tmp_path: Path
) -> None:
    """BUILDER names a docker-container builder: dev and run are built there (the tools and
    imports images reach its BuildKit as OCI layouts: a FROM of a local image would look for it
    on Docker Hub), loaded into the engine and pushed with a registry cache of every stage; the
    run image runs. A new, empty builder (a fresh CI runner's) then takes every step of dev and
    run from that cache: the tools and imports images it gets have the digests of the first.
    (The first builder is the one kept between runs: what it pushes is the registry cache of
    every stage whether it built the steps or had them cached; the second starts empty.)"""
    base = f"{local_registry}/docker-ros-test/buildkit-base:bookworm"
    ref = f"{local_registry}/docker-ros-test/buildkit-{uuid.uuid4().hex[:8]}:1"
    project = copy_example(tmp_path / "example")
    write_env(project, BASE_IMAGE=base, IMAGE=ref, TARGET="dev,run", COMMAND=EXAMPLE_COMMAND,
              CACHE_TO=f"{ref}-cache")
    try:
        # the builder pulls BASE_IMAGE: it sees no engine's images
        assert on_engine26("tag", ros1_base_image, base).returncode == 0
        pushed = on_engine26("push", base)
        assert pushed.returncode == 0, pushed.stderr
        on_engine26("rmi", base)
        name = kept_builder
        result = docker_ros(project, "push", env={"DOCKER_HOST": ENGINE26_HOST, "BUILDER": name})
        assert result.returncode == 0, result.stdout[-6000:]
        assert f"builder: {name} (built in its own BuildKit" in result.stdout
        assert REGISTRY_CACHE in result.stdout
        repository, tag = ref.split("/", 1)[1].rsplit(":", 1)
        assert {tag, f"{tag}-dev", f"{tag}-cache-run-amd64", f"{tag}-cache-dev-amd64"} <= set(
            registry_tags(local_registry, repository))
        on_engine26("rmi", ref, f"{ref}-dev")
        with container_builder(ENGINE26_HOST, buildkit_image) as name:
            again = docker_ros(project, "build",
                               env={"DOCKER_HOST": ENGINE26_HOST, "BUILDER": name})
        assert again.returncode == 0, again.stdout[-6000:]
        built = targets(again.stdout)
        assert set(built) == {"dev", "run"}, again.stdout[-3000:]
        for target, log in built.items():
            assert len(cached_vertices(log)) >= 5, log[-3000:]
            # A target's last step was sometimes run again by the empty builder while every step
            # before it came from the cache: run's COMMAND check (a RUN that leaves no file) in
            # one full run of 2026-11-26, dev's COPY of blacklist.json in CI's run of c4279ef.
            # Either compiles nothing and takes a second; any other step must be cached.
            missed = [v for v in not_from_cache(log) if not last_step(v, target)]
            assert missed == [], (target, log[-3000:])
        assert "Starting >>> colcon" not in again.stdout
    finally:
        on_engine26("rmi", base, ref, f"{ref}-dev")
    assert_pulled_image_runs(ref)


def test_a_local_base_image_a_docker_container_builder_cannot_see_is_named(
    kept_builder: str, ros1_base_image: str, tmp_path: Path
) -> None:
    """BASE_IMAGE is an image of the local engine only (bootstrapped here): the builder's own
    BuildKit looks for it in a registry, and the message says why it failed and what to do."""
    project = copy_example(tmp_path / "example")
    write_env(project, BASE_IMAGE=ros1_base_image, TARGET="run", COMMAND=EXAMPLE_COMMAND,
              IMAGE=f"docker-ros-test/buildkit-unseen-{uuid.uuid4().hex[:8]}:1")
    name = kept_builder
    env = {"DOCKER_HOST": ENGINE26_HOST, "BUILDER": name}
    shown = docker_ros(project, "build", "--dry-run", env=env)
    result = docker_ros(project, "build", env=env)
    # the dry run shows the build as it would run: through the builder, with its registry
    # cache choice, the tools and imports images as OCI layouts
    assert shown.returncode == 0, shown.stdout[-3000:]
    assert f"[dry-run] build: docker buildx --builder {name} bake" in shown.stdout, shown.stdout
    assert '"docker-ros-tools:<hash>": "oci-layout://<temporary>/layouts/' in shown.stdout
    assert '"docker-ros-imports:<hash>": "oci-layout://' in shown.stdout, shown.stdout
    assert result.returncode != 0, result.stdout[-3000:]
    assert (f"{ros1_base_image} is an image of the local engine, which a builder with a "
            "BuildKit of its own (docker-container, remote) does not see: push it to a "
            "registry") in result.stdout, result.stdout[-3000:]
