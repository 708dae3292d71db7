"""Input files as real repositories write them, read in an image build as vcs and pip read
them: a .repos file in rosinstall format (flow style, a comment), and a pip requirement file
with a continuation and nested -r/-c files installed from wheels served over HTTP."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from tests.docker.buildhelp import docker_ros, remove_image, write_env
from tests.rosfixtures import (
    file_http_server,
    git_http_server,
    make_git_repo,
    make_package,
    make_wheel,
)

pytestmark = pytest.mark.docker
IMAGE = "docker-ros-test/input-files:1"
USER, PASSWORD = "robot", "input-files-secret"


def test_rosinstall_repos_and_nested_requirement_files_in_an_image(
    ros1_base_image: str, tmp_path: Path
) -> None:
    libs = tmp_path / "work" / "upstream_libs"
    make_package(libs / "up_a", "up_a")
    remotes = tmp_path / "remotes"
    remotes.mkdir()
    make_git_repo(libs, {}, bare_copy_to=remotes / "upstream_libs.git")
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    for name, version in [("drt_alpha", "1.0"), ("drt_gamma", "1.0"), ("drt_gamma", "2.0")]:
        make_wheel(wheels, name, version)
    git_server, wheel_server = git_http_server(remotes, USER, PASSWORD), file_http_server(wheels)
    host = f"127.0.0.1:{git_server.server_address[1]}"
    links = f"http://127.0.0.1:{wheel_server.server_address[1]}/"

    repo = tmp_path / "repo"
    make_package(repo / "app", "app")
    (repo / ".repos").write_text(
        "# rosinstall format, which vcs imports too\n"
        f"- git: {{local-name: upstream_libs, uri: 'http://{host}/upstream_libs.git', "
        "version: main}  # flow style\n")
    docker = repo / "docker"
    (docker / "nested").mkdir(parents=True)
    (docker / "additional-pip-requirements.txt").write_text(
        f"--no-index\n--find-links {links}\n-r nested/more.txt\ndrt_alpha \\\n  >=1.0\n")
    (docker / "nested" / "more.txt").write_text("drt_gamma  # held below 2 by pins.txt\n"
                                                "-c pins.txt\n")
    (docker / "nested" / "pins.txt").write_text("drt_gamma<2\n")
    write_env(repo, BASE_IMAGE=ros1_base_image, IMAGE=IMAGE, TARGET="run", BUILD_NETWORK="host",
              GIT_HTTPS_SERVER=host, GIT_HTTPS_USER=USER,
              COMMAND="app_node && up_a_node && python3 -c 'import drt_alpha, drt_gamma; "
                      "print(drt_alpha.VERSION, drt_gamma.VERSION)'")
    try:
        built = docker_ros(repo, "build", env={"GIT_HTTPS_PASSWORD": PASSWORD})
        assert built.returncode == 0, built.stdout[-5000:]
        assert "clone: importing 1 repositories from src/target/.repos" in built.stdout
        ran = subprocess.run(["docker", "run", "--rm", IMAGE], capture_output=True, text=True,
                             timeout=120)
        assert ran.returncode == 0, ran.stderr
        assert ran.stdout.split() == ["app", "up_a", "1.0", "1.0"]
    finally:
        for server in (git_server, wheel_server):
            server.shutdown()
            server.server_close()
        remove_image(IMAGE)
