"""A repository laid out for docker-ros, built as it was: what its hooks, commands and users
relied on in docker-ros's images is there (docker-ros's dependencies-install stage installed
curl, gnupg and python-is-python3 before the hooks ran, and set DOCKER_USER and COLCON_HOME),
and the dev image's sources are without ADDITIONAL_FILES_DIR, as docker-ros's. The base image sets
PYTHONPATH, as some do: the hooks get it as in docker-ros (not the step code's folder)."""

from __future__ import annotations

import subprocess
import uuid
from pathlib import Path
from typing import Iterator, Tuple

import pytest

from tests.docker.buildhelp import docker_ros, remove_image, sh, write_env
from tests.rosfixtures import make_package

pytestmark = pytest.mark.docker
RUN_ID = uuid.uuid4().hex[:8]
IMAGE = f"docker-ros-test/parity-{RUN_ID}:1"
DEV_IMAGE = f"docker-ros-test/parity-{RUN_ID}:1-dev"

# a before-dependency-installation hook as docker-ros users write them: it fetches with curl
# and checks an apt key with gpg (here without network: --version); custom.sh calls `python`.
# Each tolerates a missing tool and writes what it got into the image (a cached build prints
# no hook output): the tests name what is missing.
BEFORE_INSTALL = ("{ curl --version | head -n 1; gpg --version | head -n 1; } "
                  "> /docker-ros-parity-tools 2>&1 || true\n")
CUSTOM = ('python -c "import sys; print(\'python\', sys.version_info[0])" '
          '>> /docker-ros-parity-tools 2>&1 || true\n'
          'echo "$DOCKER_USER $COLCON_HOME" > /docker-ros-parity-env\n'
          'echo "${PYTHONPATH-unset}" > /docker-ros-parity-pythonpath\n')
# ROS 1 base + ENV PYTHONPATH (a layer of metadata only: kept for the next run's build cache)
BASE = "docker-ros-test/parity-base:pythonpath"
BASE_PYTHONPATH = "/opt/base-python"
Built = Tuple[str, Path]  # the build's log, the repository


@pytest.fixture(scope="module")
def built(ros1_base_image: str,
          tmp_path_factory: pytest.TempPathFactory) -> Iterator[Built]:
    subprocess.run(["docker", "build", "-t", BASE, "-"], check=True, capture_output=True,
                   input=f"FROM {ros1_base_image}\nENV PYTHONPATH={BASE_PYTHONPATH}\n",
                   text=True, timeout=300)
    repo = tmp_path_factory.mktemp("parity") / "repo"
    make_package(repo / "app", "app")
    docker = repo / "docker"
    docker.mkdir()
    (docker / "before_dependency_installation.sh").write_text(BEFORE_INSTALL)
    (docker / "custom.sh").write_text(CUSTOM)
    (docker / "additional-files" / "maps").mkdir(parents=True)
    (docker / "additional-files" / "maps" / "map.yaml").write_text("image: map.pgm\n")
    # folders named as colcon's or git's (left out of the dependency inputs elsewhere)
    (docker / "additional-files" / "install" / "log").mkdir(parents=True)
    (docker / "additional-files" / "install" / "log" / "keep.txt").write_text("kept\n")
    write_env(repo, BASE_IMAGE=BASE, IMAGE=IMAGE, TARGET="dev,run",
              COMMAND="python -c 'import sys; print(\"python\", sys.version_info[0])'")
    try:
        result = docker_ros(repo, "build")
        assert result.returncode == 0, result.stdout[-5000:]
        yield result.stdout, repo
    finally:
        for image in (IMAGE, DEV_IMAGE, f"{IMAGE}-after-custom"):
            remove_image(image)


def test_hooks_and_command_have_curl_gpg_and_python_as_in_docker_ros(built: Built) -> None:
    for image in (IMAGE, DEV_IMAGE):
        tools = sh(image, "cat /docker-ros-parity-tools").stdout.splitlines()
        assert [line.split()[0] for line in tools] == ["curl", "gpg", "python"], tools
        assert tools[1].startswith("gpg (GnuPG)") and tools[2] == "python 3", tools
    ran = subprocess.run(["docker", "run", "--rm", IMAGE], capture_output=True, text=True,
                         timeout=120)
    assert ran.returncode == 0, ran.stderr
    assert ran.stdout.strip() == "python 3"


def test_docker_user_and_colcon_home_as_in_docker_ros(built: Built) -> None:
    expected = "dockeruser /docker-ros/ws/.colcon"
    for image in (IMAGE, DEV_IMAGE):
        assert sh(image, "cat /docker-ros-parity-env").stdout.strip() == expected
        assert sh(image, 'echo "$DOCKER_USER $COLCON_HOME"').stdout.strip() == expected
    # the mapped user (docker-ros's default name) has the same colcon home as root
    mapped = sh(DEV_IMAGE, 'echo "$(id -un) $COLCON_HOME"', "-e", "DOCKER_UID=4321")
    assert mapped.stdout.strip() == "dockeruser /docker-ros/ws/.colcon", mapped.stderr


def test_dev_image_sources_without_additional_files_as_in_docker_ros(built: Built) -> None:
    """docker-ros removed ADDITIONAL_FILES_DIR from the dev image's sources: its files (often
    large: models, maps) are at /docker-ros/additional-files, not a second time in src/."""
    listed = sh(DEV_IMAGE, "cat /docker-ros/additional-files/maps/map.yaml && "
                "ls /docker-ros/ws/src/target/docker && ls /docker-ros/ws/src/target/app")
    assert listed.returncode == 0, listed.stderr
    assert listed.stdout.split() == ["image:", "map.pgm", "before_dependency_installation.sh",
                                     "custom.sh", "CMakeLists.txt", "main.cpp", "package.xml"]
    assert sh(IMAGE, "cat /docker-ros/additional-files/maps/map.yaml").stdout == "image: map.pgm\n"
    # all of the folder, as docker-ros's ADD: `install/log/` too
    assert sh(IMAGE, "cat /docker-ros/additional-files/install/log/keep.txt").stdout == "kept\n"


def test_hooks_get_the_base_images_pythonpath_as_in_docker_ros(built: Built) -> None:
    """docker-ros's hooks ran with the base image's environment; the step code's folder
    (/docker-ros/lib) in PYTHONPATH replaced the base's PYTHONPATH for them."""
    for image in (IMAGE, DEV_IMAGE):
        assert sh(image, "cat /docker-ros-parity-pythonpath").stdout == BASE_PYTHONPATH + "\n"


def test_a_hook_run_in_a_container_gets_the_base_images_pythonpath(
    built: Built
) -> None:
    """`custom --in-container` (a container of the stage's state, not a RUN): the container's
    PYTHONPATH put the step code's folder before the base image's, not in place of it."""
    ran = docker_ros(built[1], "custom", "--in-container")
    assert ran.returncode == 0, ran.stdout[-3000:]
    state = sh(f"{IMAGE}-after-custom", "cat /docker-ros-parity-pythonpath")
    assert state.stdout == BASE_PYTHONPATH + "\n", state.stdout + state.stderr
