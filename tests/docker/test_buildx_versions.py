"""The buildx generations users have. The suite runs on a current buildx (conftest.py): the one of
Docker's own packages, Docker Desktop and CI runners, whose bake refuses from 0.20 on to read
outside its working directory what it is not granted (`ERROR: additional privileges requested`;
our Dockerfile, layouts and secrets are in a temporary folder). Debian stable's 0.13 (`apt install
docker-buildx`) has no such check and no `--allow` flag. scripts/setup.sh installs both
(tests.engines.BUILDX_DIRS)."""

from __future__ import annotations

import os
import re
import uuid
from pathlib import Path
from typing import Dict

import pytest

from tests.ci.cihelp import EXAMPLE_COMMAND, HEARD
from tests.conftest import SETUP_HINT, buildx_version
from tests.docker.buildhelp import copy_example, docker_ros, remove_image, run_until, write_env
from tests.engines import buildx_config, buildx_plugin

pytestmark = pytest.mark.docker


def minor(version: str) -> int:
    """0.N of `docker buildx version`'s line (`github.com/docker/buildx 0.29.1+ds1 ...`)."""
    found = re.search(r" v?0\.(\d+)\.", version)
    assert found, version
    return int(found.group(1))


def build_and_run(project: Path, ref: str, env: Dict[str, str], bake: str) -> None:
    """dev and run in one bake run (the dry run shows bake's argv start: bake); the run image
    runs the example."""
    shown = docker_ros(project, "build", "--dry-run", env=env)
    assert shown.returncode == 0, shown.stdout[-3000:]
    assert f"[dry-run] build: {bake} --progress=plain" in shown.stdout, shown.stdout
    try:
        built = docker_ros(project, "build", env=env)
        assert built.returncode == 0, built.stdout[-4000:]
        out = run_until(ref, HEARD, 60)
        assert HEARD in out, out[-3000:]
    finally:
        remove_image(ref)
        remove_image(f"{ref}-dev")


def example(tmp_path: Path, ros1_base_image: str) -> tuple:
    project = copy_example(tmp_path / "example")
    ref = f"docker-ros-test/buildx-versions-{uuid.uuid4().hex[:8]}:1"
    write_env(project, BASE_IMAGE=ros1_base_image, IMAGE=ref, TARGET="dev,run",
              COMMAND=EXAMPLE_COMMAND)
    return project, ref


def test_the_suite_runs_on_a_current_buildx_whose_bake_gets_our_folders(
    ros1_base_image: str, tmp_path: Path
) -> None:
    """The suite's buildx is 0.20 or later; bake is granted exactly our temporary folder and the
    build context (`--allow=fs.read=`)."""
    version = buildx_version()
    assert buildx_plugin("current").is_file(), f"no current buildx; {SETUP_HINT}"
    assert minor(version) >= 20, f"the suite runs on {version!r}; {SETUP_HINT}"
    project, ref = example(tmp_path, ros1_base_image)
    build_and_run(project, ref, {}, "docker buildx bake '--allow=fs.read=<temporary>' "
                  f"--allow=fs.read={project.resolve()}")


def test_debians_buildx_0_13_builds_without_allow_flags(ros1_base_image: str,
                                                        tmp_path: Path) -> None:
    """Debian stable's buildx (0.13) knows no `--allow`: bake runs without it."""
    assert buildx_plugin("debian").is_file(), f"no Debian buildx; {SETUP_HINT}"
    env = buildx_config(tmp_path / "docker-config", "debian")
    version = buildx_version({**os.environ, **env})
    assert minor(version) < 20, version
    project, ref = example(tmp_path, ros1_base_image)
    build_and_run(project, ref, env, "docker buildx bake")
