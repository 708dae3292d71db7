"""A base image whose python3 is older than 3.8 (Ubuntu 18.04's 3.6): the build stops in its
first step with one line naming BASE_IMAGE, the version found and the minimum; nothing tagged."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path
from typing import Iterator

import pytest

from tests.docker.buildhelp import (
    docker_ros,
    failure_message,
    image_exists,
    remove_image,
    write_env,
)
from tests.rosfixtures import make_package

pytestmark = pytest.mark.docker

OLD = f"docker-ros-test/old-python:{os.getpid()}"


@pytest.fixture
def old_python_base(ros1_base_image: str, tmp_path: Path) -> Iterator[str]:
    """The ROS 1 test base with a python3 first on PATH that is 3.6.9 as far as any caller can
    tell (what `python3 --version` says; anything else fails like an old interpreter)."""
    (tmp_path / "Dockerfile").write_text(
        f"FROM {ros1_base_image}\n"
        "RUN printf '#!/bin/sh\\n[ \"$1\" = --version ] && echo \"Python 3.6.9\" && exit 0\\n"
        "echo \"SyntaxError: invalid syntax\" >&2; exit 1\\n' > /usr/local/bin/python3 && "
        "chmod 755 /usr/local/bin/python3\n")
    subprocess.run(["docker", "buildx", "build", "--load", "-q", "-t", OLD, str(tmp_path)],
                   check=True, capture_output=True)
    yield OLD
    remove_image(OLD)


def test_too_old_python3_in_base_image_is_one_clear_line(
    old_python_base: str, tmp_path: Path
) -> None:
    project = tmp_path / "ws"
    make_package(project / "pkg", "pkg")
    image = f"docker-ros-test/old-python-out:{os.getpid()}"
    write_env(project, BASE_IMAGE=old_python_base, IMAGE=image, COMMAND="true", TARGET="dev")
    result = docker_ros(project, "build")
    assert result.returncode != 0
    last = failure_message(result.stdout)
    assert "failed in step prepare: " in last, result.stdout[-3000:]
    assert (f"BASE_IMAGE '{old_python_base}' has python3 3.6.9 (/usr/local/bin/python3); "
            "docker-ros needs Python 3.8 or newer in the image") in last, last
    assert "SyntaxError" not in result.stdout
    assert not image_exists(f"{image}-dev")
