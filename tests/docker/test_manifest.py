"""`docker-ros manifest` against a real registry: one list per name over the platform images the
registry holds now, also where a per-architecture ref is itself an index (as the containerd
image store and attestations push them; `docker manifest create` refuses those)."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import uuid
from pathlib import Path
from typing import Tuple

import pytest

from docker_ros.core.loading import load_settings
from docker_ros.host.push import manifest
from docker_ros.host.slim import LABEL_SOURCE

pytestmark = pytest.mark.docker

LIST_TYPES = ("application/vnd.docker.distribution.manifest.list.v2+json",
              "application/vnd.oci.image.index.v1+json")


def push_one_file_image(ref: str, platform: str, content: str, context: Path,
                        slimmed_from: str = "") -> str:
    """Build an image of one file for platform straight into the registry (slimmed_from: with
    the label slim gives its images, naming the run image's local ID); its digest."""
    context.mkdir(exist_ok=True)
    (context / "hello.txt").write_text(content)
    label = f"LABEL {LABEL_SOURCE}={slimmed_from}\n" if slimmed_from else ""
    (context / "Dockerfile").write_text(f"FROM scratch\nCOPY hello.txt /\n{label}")
    subprocess.run(["docker", "buildx", "build", "--quiet", "--provenance=false", "--platform",
                    f"linux/{platform}", "--tag", ref, "--push", str(context)],
                   check=True, capture_output=True)
    return raw_manifest(ref)[0]


def raw_manifest(ref: str) -> Tuple[str, dict]:
    """(digest, manifest) of ref as the registry holds it."""
    raw = subprocess.run(["docker", "buildx", "imagetools", "inspect", "--raw", ref],
                         check=True, capture_output=True).stdout
    return "sha256:" + hashlib.sha256(raw).hexdigest(), json.loads(raw)


def wrap_in_index(ref: str, source: str, config: Path) -> None:
    """ref: a list holding only source (what a per-architecture push of the containerd store
    looks like), written with the CLI's own manifest store in config."""
    env = {**os.environ, "DOCKER_CONFIG": str(config)}
    for argv in (["create", "--insecure", ref, source], ["push", "--insecure", "--purge", ref]):
        subprocess.run(["docker", "manifest", *argv], env=env, check=True, capture_output=True)


def test_manifest_lists_the_platform_images_the_registry_holds_now(
    local_registry: str, tmp_path: Path
) -> None:
    name = f"{local_registry}/docker-ros-test/manifest:{uuid.uuid4().hex[:8]}"
    first = push_one_file_image(f"{name}-amd64", "amd64", "first build\n", tmp_path / "a")
    arm64 = push_one_file_image(f"{name}-arm64-image", "arm64", "arm64\n", tmp_path / "b")
    wrap_in_index(f"{name}-arm64", f"{name}-arm64-image", tmp_path / "docker-config")
    assert raw_manifest(f"{name}-arm64")[1]["mediaType"] in LIST_TYPES
    settings = load_settings(environ={"BASE_IMAGE": "b:1", "COMMAND": "c", "IMAGE": name,
                                      "TARGET": "run", "PLATFORM": "amd64,arm64"},
                             project_dir=tmp_path)

    def listed() -> dict:
        entries = raw_manifest(name)[1]["manifests"]
        assert all(e["mediaType"] not in LIST_TYPES for e in entries), entries  # flat
        return {e["platform"]["architecture"]: e["digest"] for e in entries}

    written = manifest(settings, ["run"], dry_run=False)
    assert written == {name: raw_manifest(name)[0]}  # (the list's digest, as the registry has it)
    assert listed() == {"amd64": first, "arm64": arm64}
    # The next pipeline's amd64 image: the list written again names it, not the first one.
    second = push_one_file_image(f"{name}-amd64", "amd64", "second build\n", tmp_path / "a")
    assert list(manifest(settings, ["run"], dry_run=False)) == [name]
    assert listed() == {"amd64": second, "arm64": arm64}


def test_the_slim_lists_leave_out_an_earlier_pipelines_slim_image(
    local_registry: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A slim image joins the slim lists only when it was slimmed from the `-<arch>` run image
    the registry holds now (its label names the run image's local ID: the configuration's
    digest in the classic store, the manifest's or index's in the containerd one). A job on a
    runner of another architecture slims nothing, so an earlier pipeline's `-slim-arm64`
    stays in the registry: it is left out, saying so, not joined with today's amd64 one."""
    name = f"{local_registry}/docker-ros-test/manifest:{uuid.uuid4().hex[:8]}"
    push_one_file_image(f"{name}-amd64", "amd64", "run amd64\n", tmp_path / "a")
    push_one_file_image(f"{name}-arm64-image", "arm64", "run arm64\n", tmp_path / "b")
    wrap_in_index(f"{name}-arm64", f"{name}-arm64-image", tmp_path / "docker-config")
    amd64_config = raw_manifest(f"{name}-amd64")[1]["config"]["digest"]  # classic store's ID
    arm64_index = raw_manifest(f"{name}-arm64")[0]  # the containerd store's ID
    slim_amd64 = push_one_file_image(f"{name}-slim-amd64", "amd64", "slim amd64\n",
                                     tmp_path / "c", slimmed_from=amd64_config)
    slim_arm64 = push_one_file_image(f"{name}-slim-arm64", "arm64", "slim arm64\n",
                                     tmp_path / "d", slimmed_from=arm64_index)
    settings = load_settings(environ={"BASE_IMAGE": "b:1", "COMMAND": "c", "IMAGE": name,
                                      "TARGET": "run", "PLATFORM": "amd64,arm64"},
                             project_dir=tmp_path)

    def slim_listed() -> dict:
        entries = raw_manifest(f"{name}-slim")[1]["manifests"]
        return {e["platform"]["architecture"]: e["digest"] for e in entries}

    assert list(manifest(settings, ["run", "slim"], dry_run=False)) == [name, f"{name}-slim"]
    assert slim_listed() == {"amd64": slim_amd64, "arm64": slim_arm64}
    assert "leave it out" not in capsys.readouterr().out
    # The next pipeline: both run images again, the arm64 one on an amd64 runner (no slim).
    push_one_file_image(f"{name}-amd64", "amd64", "run amd64, next\n", tmp_path / "a")
    push_one_file_image(f"{name}-arm64", "arm64", "run arm64, next\n", tmp_path / "b")
    slim_again = push_one_file_image(
        f"{name}-slim-amd64", "amd64", "slim amd64, next\n", tmp_path / "c",
        slimmed_from=raw_manifest(f"{name}-amd64")[1]["config"]["digest"])
    assert list(manifest(settings, ["run", "slim"], dry_run=False)) == [name, f"{name}-slim"]
    assert slim_listed() == {"amd64": slim_again}
    assert (f"manifest: {name}-slim-arm64 was not slimmed from {name}-arm64 (it is an earlier "
            "pipeline's; this one slimmed nothing for it): the slim lists leave it out"
            ) in capsys.readouterr().out
