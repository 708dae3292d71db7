"""Proofs that the shared Docker fixtures give what the other tests rely on.

proves (each line: the test; all Docker-level, no image build of docker-ros):
- the ROS 1 base round-trips a message through roscore, ROS from Debian in /usr:
  test_ros1_image_round_trips_a_message_through_roscore
- the ROS 2 base builds an ament_cmake package with colcon:
  test_ros2_image_builds_an_ament_cmake_package
- the local registry takes a push and gives the same image back:
  test_local_registry_pushes_and_pulls
- pip in a container reaches PyPI with the host's CA bundle mounted:
  test_pip_in_a_container_trusts_pypi_only_with_the_host_ca
- pip in a container fails (CERTIFICATE_VERIFY_FAILED) on a server signed by a CA it is not
  given, and passes with that CA (was a test that skipped on machines without an extra CA: now
  the test's own CA and server):
  test_pip_in_a_container_trusts_an_intercepting_proxy_only_with_its_ca
- the end of a run removes the images it left and nothing else:
  test_a_run_removes_the_images_it_left_and_nothing_else"""

from __future__ import annotations

import json
import os
import subprocess
import urllib.request
import uuid
from pathlib import Path

import docker
import pytest

from docker_ros.host.buildcontext import IMPORTS_LABEL, imports_owner
from tests import leftovers
from tests.docker.buildhelp import import_one_file_image, remove_image
from tests.docker.test_extra_ca_certs import https_wheel  # noqa: F401 (a fixture)

pytestmark = pytest.mark.docker

PIP_INSTALL_SIX = (
    "pip install --no-cache-dir --retries 0 --timeout 30 --break-system-packages"
    " --ignore-installed --no-deps six"
)
TINY_PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>tiny</name>
  <version>0.0.1</version>
  <description>A tiny ament_cmake package</description>
  <maintainer email="dev@example.com">dev</maintainer>
  <license>MIT</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""
TINY_CMAKELISTS = """cmake_minimum_required(VERSION 3.10)
project(tiny CXX)
find_package(ament_cmake REQUIRED)
ament_package()
"""


def run(client: docker.DockerClient, image: str, script: str, **kwargs: object) -> str:
    """Output of `bash -c script` in a throwaway container; fails the test with its stderr."""
    try:
        out = client.containers.run(image, ["bash", "-c", script], remove=True, **kwargs)
    except docker.errors.ContainerError as exc:
        stderr = exc.stderr.decode(errors="replace") if exc.stderr else ""
        pytest.fail(f"container exited with {exc.exit_status}:\n{stderr}")
    return out.decode(errors="replace")


def test_ros1_image_round_trips_a_message_through_roscore(
    docker_client: docker.DockerClient, ros1_base_image: str
) -> None:
    script = """set -e
        test -z "${ROS_DISTRO:-}" && test ! -e /opt/ros  # Debian's ROS 1 lives in /usr
        roscore >/tmp/roscore.log 2>&1 &
        for _ in $(seq 60); do rostopic list >/dev/null 2>&1 && break; sleep 0.5; done
        rostopic pub -r 5 /chatter std_msgs/String "data: hello from roscore" >/dev/null &
        timeout 30 rostopic echo -n 1 /chatter
    """
    assert 'data: "hello from roscore"' in run(docker_client, ros1_base_image, script)


def test_ros2_image_builds_an_ament_cmake_package(
    docker_client: docker.DockerClient, ros2_base_image: str, tmp_path: Path
) -> None:
    package = tmp_path / "src" / "tiny"
    package.mkdir(parents=True)
    (package / "package.xml").write_text(TINY_PACKAGE_XML)
    (package / "CMakeLists.txt").write_text(TINY_CMAKELISTS)
    script = """set -e
        colcon build --event-handlers console_direct-
        source install/setup.bash
        echo "AMENT_PREFIX_PATH=$AMENT_PREFIX_PATH"
        python3 -c 'import ament_index_python as a; print(a.get_package_prefix("tiny"))'
    """
    out = run(
        docker_client,
        ros2_base_image,
        script,
        volumes={str(tmp_path): {"bind": "/ws", "mode": "rw"}},
        working_dir="/ws",
        user=f"{os.getuid()}:{os.getgid()}",
        environment={"HOME": "/tmp"},
    )
    assert "AMENT_PREFIX_PATH=/ws/install/tiny" in out
    assert out.rstrip().endswith("/ws/install/tiny")
    assert (tmp_path / "install" / "setup.bash").is_file()


def test_local_registry_pushes_and_pulls(
    docker_client: docker.DockerClient, local_registry: str
) -> None:
    repository = f"{local_registry}/docker-ros-test/tiny"
    tag = uuid.uuid4().hex[:12]
    ref = f"{repository}:{tag}"
    import_one_file_image(docker_client, ref, f"pushed as {ref}\n")
    image_id = docker_client.images.get(ref).id
    try:
        for line in docker_client.images.push(repository, tag=tag, stream=True, decode=True):
            assert "error" not in line, line
        docker_client.images.remove(ref)
        assert docker_client.images.pull(repository, tag=tag).id == image_id
        opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
        with opener.open(f"http://{local_registry}/v2/docker-ros-test/tiny/tags/list") as answer:
            assert tag in json.load(answer)["tags"]
    finally:
        docker_client.images.remove(ref, force=True)


def test_pip_in_a_container_trusts_pypi_only_with_the_host_ca(
    docker_client: docker.DockerClient, ros1_base_image: str, host_ca_bundle: Path
) -> None:
    ca = "/run/host-ca/ca-certificates.crt"
    out = run(
        docker_client,
        ros1_base_image,
        f"{PIP_INSTALL_SIX} && python3 -c 'import six; print(six.__file__)'",
        volumes={str(host_ca_bundle): {"bind": ca, "mode": "ro"}},
        environment={"PIP_CERT": ca, "SSL_CERT_FILE": ca},
    )
    assert "/usr/local/lib/python3" in out


def test_pip_in_a_container_trusts_an_intercepting_proxy_only_with_its_ca(
    docker_client: docker.DockerClient, ros1_base_image: str, https_wheel: tuple  # noqa: F811
) -> None:
    """pip in a container fails with CERTIFICATE_VERIFY_FAILED on an HTTPS server whose CA it is
    not given, and downloads from it with that CA (PIP_CERT). Why the host's CA bundle is mounted
    above, proven on any machine, a TLS-intercepting proxy or none: the test's own CA signed the
    server's certificate."""
    pki, url, _ = https_wheel
    download = f"pip download --no-cache-dir --retries 0 --timeout 30 --no-deps -d /tmp/got {url}"
    out = run(docker_client, ros1_base_image, f"{download} 2>&1 || echo PIP FAILED",
              network_mode="host")
    assert "CERTIFICATE_VERIFY_FAILED" in out, out
    assert out.rstrip().endswith("PIP FAILED")
    ca = "/run/test-ca/ca.crt"
    out = run(docker_client, ros1_base_image, f"{download} && ls /tmp/got", network_mode="host",
              volumes={str(pki.ca): {"bind": ca, "mode": "ro"}}, environment={"PIP_CERT": ca})
    assert out.rstrip().endswith(url.rsplit("/", 1)[1]), out


def test_a_run_removes_the_images_it_left_and_nothing_else(
    docker_client: docker.DockerClient, ros1_base_image: str, tmp_path: Path
) -> None:
    """leftovers.remove_run_images, which this suite and the bench call at their end: the
    imports images of the run's repositories and the images that became dangling during the
    run go (a rebuild untagged them: made by the run, or by an earlier run under the same test
    name); another repository's imports image and an image dangling before the run stay."""
    name = f"docker-ros-test/leftovers-{uuid.uuid4().hex[:8]}"
    # (the test's own label: the other processes of the run build on the same base meanwhile,
    # and an image of theirs is dangling until they tag it)
    label = f"org.docker-ros.test.leftovers={name}"

    def build(tag: str) -> str:
        dockerfile = (f"FROM {ros1_base_image}\nLABEL {label}\n"
                      f"RUN echo {uuid.uuid4().hex} > /leftover\n")
        subprocess.run(["docker", "build", "-q", "-t", f"{name}:{tag}", "-"], input=dockerfile,
                       text=True, capture_output=True, check=True)
        return str(docker_client.images.get(f"{name}:{tag}").id)

    def imports_image(tag: str, repository: Path) -> str:
        import_one_file_image(docker_client, f"{name}:{tag}", "imports\n",
                              changes=[f"LABEL {IMPORTS_LABEL}={imports_owner(repository)}"])
        return str(docker_client.images.get(f"{name}:{tag}").id)

    old = build("old")
    build("old")  # untags `old` before the run begins
    earlier = build("earlier")  # an earlier run's image under a test name
    before = leftovers.untagged(docker_client, label)
    build("earlier")  # untags `earlier`: the run did
    rebuilt = build("rebuilt")
    build("rebuilt")  # untags `rebuilt`, made by the run
    root = tmp_path / "run"
    (root / "tests" / "repository").mkdir(parents=True)
    mine = imports_image("mine", root / "tests" / "repository")
    other = imports_image("other", tmp_path / "elsewhere")
    try:
        assert old in before and earlier not in before
        leftovers.remove_run_images(docker_client, [root], before, label)
        left = {image["Id"] for image in docker_client.api.images(all=True)}
        assert earlier not in left and rebuilt not in left and mine not in left
        assert old in left and other in left
    finally:
        for ref in (old, earlier, rebuilt, mine, other, *(f"{name}:{tag}" for tag in
                                                          ("old", "earlier", "rebuilt"))):
            remove_image(ref)
