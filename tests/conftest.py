"""Shared fixtures: a Docker client, ROS base images built from Debian, a local registry, the
host's CA bundle. Tests that need Docker are marked `@pytest.mark.docker`."""

from __future__ import annotations

import shutil
import socket
import subprocess
import time
import urllib.request
from pathlib import Path
from typing import Iterator

import docker
import pytest
import yaml

from docker_ros import baseimage

ROS1_BASE_IMAGE = "docker-ros-test/ros1:bookworm"
ROS2_BASE_IMAGE = "docker-ros-test/ros2:trixie"
# dockerd treats 127.0.0.0/8 as an insecure (plain http) registry without configuration; a free
# port keeps parallel test runs (and a user's own registry on 5000) apart.
REGISTRY_HOST = "127.0.0.1"
HOST_CA_BUNDLE = Path("/etc/ssl/certs/ca-certificates.crt")
SETUP_HINT = "run `bash scripts/setup.sh` first"


@pytest.fixture(scope="session")
def docker_client() -> Iterator[docker.DockerClient]:
    """A docker SDK client (`docker.from_env()`) to a daemon that answers."""
    try:
        client = docker.from_env()
        client.ping()
    except docker.errors.DockerException as exc:
        pytest.fail(f"no Docker daemon answers ({exc}); {SETUP_HINT}")
    yield client
    client.close()


@pytest.fixture(scope="session")
def ros1_base_image(docker_client: docker.DockerClient) -> str:
    """Tag of a Debian bookworm image with ROS 1 from Debian (in /usr); built once, then reused."""
    return baseimage.bootstrap("ros1", tag=ROS1_BASE_IMAGE)


@pytest.fixture(scope="session")
def ros2_base_image(docker_client: docker.DockerClient) -> str:
    """Tag of a Debian trixie image with ROS 2 build tooling (ament, colcon); built once."""
    return baseimage.bootstrap("ros2", tag=ROS2_BASE_IMAGE)


@pytest.fixture(scope="session")
def local_registry(
    docker_client: docker.DockerClient, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[str]:
    """A private `docker-registry` on 127.0.0.1:5000 with throwaway storage; yields its address."""
    executable = shutil.which("docker-registry")
    if executable is None:
        pytest.fail(f"docker-registry (Debian package) is not installed; {SETUP_HINT}")
    address = f"{REGISTRY_HOST}:{free_port()}"
    work = tmp_path_factory.mktemp("registry")
    config = {
        "version": 0.1,
        "log": {"level": "warn"},
        "storage": {
            "filesystem": {"rootdirectory": str(work / "storage")},
            "delete": {"enabled": True},
        },
        "http": {"addr": address},
    }
    (work / "config.yml").write_text(yaml.safe_dump(config))
    log_path = work / "registry.log"
    with log_path.open("wb") as log:
        server = subprocess.Popen(
            [executable, "serve", str(work / "config.yml")], stdout=log, stderr=subprocess.STDOUT
        )
    try:
        wait_for_registry(address, server, log_path)
        yield address
    finally:
        server.terminate()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind((REGISTRY_HOST, 0))
        return int(probe.getsockname()[1])


def wait_for_registry(address: str, server: subprocess.Popen, log_path: Path) -> None:
    # No proxy for a loopback address, whatever the environment says.
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        if server.poll() is not None:
            pytest.fail(f"docker-registry exited with {server.returncode}:\n{log_path.read_text()}")
        try:
            with opener.open(f"http://{address}/v2/", timeout=2) as answer:
                if answer.status == 200:
                    return
        except OSError:
            time.sleep(0.2)
    pytest.fail(f"docker-registry did not answer on {address} within 15 s:\n{log_path.read_text()}")


@pytest.fixture(scope="session")
def host_ca_bundle() -> Path:
    """The host's CA bundle (it includes any TLS-intercepting proxy's CA the host trusts)."""
    if not HOST_CA_BUNDLE.is_file():
        pytest.fail(f"{HOST_CA_BUNDLE} not found (package ca-certificates); {SETUP_HINT}")
    return HOST_CA_BUNDLE
