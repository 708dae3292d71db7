"""`docker-ros manifest` against a real registry: the list names what the registry holds now,
whatever the docker CLI's local manifest store kept from an earlier run."""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
import tarfile
import uuid
from pathlib import Path
from typing import Dict

import docker
import pytest

from docker_ros.push import manifest
from docker_ros.settings import load_settings

pytestmark = pytest.mark.docker


def pushed_tiny_image(client: docker.DockerClient, ref: str, content: str) -> None:
    """A one-file image imported and pushed as ref (architecture of this machine)."""
    repository, tag = ref.rsplit(":", 1)
    payload = io.BytesIO()
    with tarfile.open(fileobj=payload, mode="w") as tar:
        data = content.encode()
        info = tarfile.TarInfo("hello.txt")
        info.size = len(data)
        tar.addfile(info, io.BytesIO(data))
    client.api.import_image_from_data(payload.getvalue(), repository=repository, tag=tag)
    for line in client.images.push(repository, tag=tag, stream=True, decode=True):
        assert "error" not in line, line


def inspect(ref: str, env: Dict[str, str]) -> dict:
    out = subprocess.run(["docker", "manifest", "inspect", "--insecure", "--verbose", ref],
                         capture_output=True, text=True, check=True, env=env).stdout
    return json.loads(out)


def test_manifest_ignores_a_stale_local_list(
    docker_client: docker.DockerClient, local_registry: str, tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    config = tmp_path / "docker-config"  # the CLI's manifest store of this test only
    config.mkdir()
    monkeypatch.setenv("DOCKER_CONFIG", str(config))
    env = {"PATH": "/usr/local/bin:/usr/bin:/bin", "DOCKER_CONFIG": str(config)}
    name = f"{local_registry}/docker-ros-test/manifest:{uuid.uuid4().hex[:8]}"
    arch = docker_client.version()["Arch"]
    arch_ref = f"{name}-{arch}"
    try:
        pushed_tiny_image(docker_client, arch_ref, "first build\n")
        stale = subprocess.run(["docker", "manifest", "create", "--insecure", name, arch_ref],
                               capture_output=True, text=True, env=env)
        assert stale.returncode == 0, stale.stderr
        assert any((config / "manifests").iterdir())
        pushed_tiny_image(docker_client, arch_ref, "second build\n")  # the CI's new image
        current = inspect(arch_ref, env)["Descriptor"]["digest"]

        settings = load_settings(environ={"BASE_IMAGE": "b:1", "COMMAND": "c", "IMAGE": name,
                                          "TARGET": "run", "PLATFORM": arch},
                                 project_dir=tmp_path)
        assert manifest(settings, ["run"], dry_run=False) == [name]

        listed = subprocess.run(["docker", "manifest", "inspect", "--insecure", name],
                                capture_output=True, text=True, check=True, env=env).stdout
        assert [m["digest"] for m in json.loads(listed)["manifests"]] == [current]
        assert not any((config / "manifests").iterdir())  # pushed lists are purged
    finally:
        with contextlib.suppress(docker.errors.APIError):
            docker_client.images.remove(arch_ref, force=True)
