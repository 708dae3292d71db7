"""`docker-ros manifest` against a real registry: the list names what the registry holds now,
whatever the docker CLI's local manifest store kept from an earlier run."""

from __future__ import annotations

import contextlib
import json
import subprocess
import uuid
from pathlib import Path

import docker
import pytest

from docker_ros.push import manifest
from docker_ros.settings import load_settings
from tests.docker.buildhelp import import_one_file_image

pytestmark = pytest.mark.docker


def pushed_one_file_image(client: docker.DockerClient, ref: str, content: str) -> None:
    import_one_file_image(client, ref, content)
    repository, tag = ref.rsplit(":", 1)
    for line in client.images.push(repository, tag=tag, stream=True, decode=True):
        assert "error" not in line, line


def manifest_inspect(ref: str, *flags: str) -> dict:
    out = subprocess.run(["docker", "manifest", "inspect", "--insecure", *flags, ref],
                         capture_output=True, text=True, check=True).stdout
    return json.loads(out)


def test_manifest_ignores_a_stale_local_list(
    docker_client: docker.DockerClient, local_registry: str, tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    config = tmp_path / "docker-config"  # the CLI's manifest store of this test only
    config.mkdir()
    monkeypatch.setenv("DOCKER_CONFIG", str(config))  # for every docker command below
    name = f"{local_registry}/docker-ros-test/manifest:{uuid.uuid4().hex[:8]}"
    arch = docker_client.version()["Arch"]
    arch_ref = f"{name}-{arch}"
    try:
        pushed_one_file_image(docker_client, arch_ref, "first build\n")
        stale = subprocess.run(["docker", "manifest", "create", "--insecure", name, arch_ref],
                               capture_output=True, text=True)
        assert stale.returncode == 0, stale.stderr
        assert any((config / "manifests").iterdir())
        pushed_one_file_image(docker_client, arch_ref, "second build\n")  # the CI's new image
        current = manifest_inspect(arch_ref, "--verbose")["Descriptor"]["digest"]

        settings = load_settings(environ={"BASE_IMAGE": "b:1", "COMMAND": "c", "IMAGE": name,
                                          "TARGET": "run", "PLATFORM": arch},
                                 project_dir=tmp_path)
        assert manifest(settings, ["run"], dry_run=False) == [name]

        assert [m["digest"] for m in manifest_inspect(name)["manifests"]] == [current]
        assert not any((config / "manifests").iterdir())  # pushed lists are purged
    finally:
        with contextlib.suppress(docker.errors.APIError):
            docker_client.images.remove(arch_ref, force=True)
