"""The bench's count of what a rebuild walks through (issue 49): the Dockerfile's stages and
the BuildKit steps each rebuild resolved, read from a real bake log's lines."""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "scripts"))

import io  # noqa: E402

import pytest  # noqa: E402
from bench.buildlog import (  # noqa: E402
    dependency_layers,
    stage_count,
    steps_resolved,
    steps_run,
)

from docker_ros.host import build, unchanged  # noqa: E402

# Lines as `docker buildx bake` prints them (two invocations: vertex numbers restart)
LOG = """\
#1 [internal] load local bake definitions
#1 DONE 0.0s
#5 [dev internal] load build context
#12 [dev base 2/5] RUN --mount=type=bind,from=tools python3 -m docker_ros.in_image.steps prepare
#12 CACHED
#13 [dev upstream 1/2] COPY --from=imports /docker-ros/imports /docker-ros/imports
#13 CACHED
#12 [dev base 2/5] RUN --mount=type=bind,from=tools python3 -m docker_ros.in_image.steps prepare
#21 [run build 1/1] RUN --mount=type=bind,from=tools python3 -m docker_ros.in_image.steps colcon
#21 DONE 7.2s
#22 [run tools 1/1] FROM docker.io/library/docker-ros-tools:1-amd64
#22 DONE 0.0s
#33 [run] exporting to image
#1 [internal] load build definition from Dockerfile
#12 [base 2/5] RUN true
"""


def test_each_instruction_vertex_counts_once_per_invocation_and_nothing_else():
    assert steps_resolved(LOG) == 4
    assert steps_resolved("") == 0


def test_the_steps_that_ran_are_named_with_their_seconds():
    assert steps_run(LOG) == [("[run build 1/1] RUN", 7.2)]
    assert steps_run(LOG.replace("#13 CACHED", "#13 DONE 0.1s")) == [
        ("[dev upstream 1/2] COPY", 0.1), ("[run build 1/1] RUN", 7.2)]
    assert steps_run("") == []


def test_the_stages_are_the_dockerfile_s_from_lines():
    dockerfile = REPO / "src" / "docker_ros" / "docker" / "Dockerfile"
    text = dockerfile.read_text()
    froms = [line for line in text.splitlines() if line.upper().startswith("FROM ")]
    assert stage_count(dockerfile) == len(froms) > 20


def test_images_up_to_date_read_as_kept(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """What the tool prints when the record says the images are up to date (BuildKit not
    started) is what the bench reads as 'kept'."""
    record = tmp_path / "record.json"
    unchanged.write(record, {"x:1": {"inputs": "a", "id": "sha256:1", "digest": ""}})
    monkeypatch.setattr(build, "image_id", lambda ref: "sha256:1")
    out = io.StringIO()
    kept = build.up_to_date(record, {"x:1": "a"}, {"run": "x:1"}, "amd64", out)
    assert [image.reused for image in kept] == [True]
    assert dependency_layers(out.getvalue()) == "kept"
    assert dependency_layers(LOG) == "?"  # (no dependencies RUN in it)
