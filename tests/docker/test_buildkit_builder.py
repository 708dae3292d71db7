"""A buildx docker-container builder (BUILDER), the kind GitHub's docker/setup-buildx-action
makes: BuildKit in a container of its own, with no image store. Its buildkitd is built from
Debian's source (tests.engines.buildkit_image: moby/buildkit cannot be pulled here) and runs on
Engine 26 (Engine 20.10 here cannot start the privileged container it needs).

Building there, pushing with a registry cache of every stage and an empty builder (a fresh
runner's) taking every step from that cache: tests/ci/test_multiarch_builder.py's container builder
test, for both platforms at once, TARGET=run (one cold builder build per run, not two; dev
goes through the same OCI layouts of the tools and imports images)."""

from __future__ import annotations

import uuid
from pathlib import Path

import pytest

from tests.ci.cihelp import EXAMPLE_COMMAND
from tests.docker.buildhelp import copy_example, docker_ros, write_env
from tests.engines import ENGINE26_HOST

pytestmark = pytest.mark.docker


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
