"""The buildx of Docker's own packages, Docker Desktop and CI runners (0.20 and later), not only
the distribution's 0.13 that the other tests use: from 0.20 on, bake refuses to read outside its
working directory what it is not granted (`ERROR: additional privileges requested`), and our
Dockerfile, layouts and secrets are in a temporary folder. scripts/setup.sh installs Debian sid's
docker-buildx beside the distribution's (tests.engines.MODERN_BUILDX)."""

from __future__ import annotations

import os
import re
import subprocess
import uuid
from pathlib import Path

import pytest

from tests.ci.cihelp import EXAMPLE_COMMAND, HEARD
from tests.conftest import SETUP_HINT
from tests.docker.buildhelp import copy_example, docker_ros, remove_image, run_until, write_env
from tests.engines import MODERN_BUILDX, modern_buildx_config

pytestmark = pytest.mark.docker


def test_a_current_buildx_builds_and_the_run_image_runs(ros1_base_image: str,
                                                       tmp_path: Path) -> None:
    """dev and run in one bake run, granted exactly our temporary folder and the build context
    (`--allow=fs.read=`, which the dry run shows); the run image runs the example."""
    if not MODERN_BUILDX.is_file():
        pytest.fail(f"no current buildx at {MODERN_BUILDX}; {SETUP_HINT}")
    env = modern_buildx_config(tmp_path / "docker-config")
    version = subprocess.run(["docker", "buildx", "version"], env={**os.environ, **env},
                             capture_output=True, text=True).stdout
    found = re.search(r" v?0\.(\d+)\.", version)
    assert found and int(found.group(1)) >= 20, version
    project = copy_example(tmp_path / "example")
    ref = f"docker-ros-test/current-buildx-{uuid.uuid4().hex[:8]}:1"
    write_env(project, BASE_IMAGE=ros1_base_image, IMAGE=ref, TARGET="dev,run",
              COMMAND=EXAMPLE_COMMAND)
    shown = docker_ros(project, "build", "--dry-run", env=env)
    assert shown.returncode == 0, shown.stdout[-3000:]
    assert (f"docker buildx bake '--allow=fs.read=<temporary>' "
            f"--allow=fs.read={project.resolve()} --progress=plain") in shown.stdout, shown.stdout
    try:
        built = docker_ros(project, "build", env=env)
        assert built.returncode == 0, built.stdout[-4000:]
        assert "additional privileges" not in built.stdout
        out = run_until(ref, HEARD, 60)
        assert HEARD in out, out[-3000:]
    finally:
        remove_image(ref)
        remove_image(f"{ref}-dev")
