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


def build_and_run(project: Path, ref: str, env: Dict[str, str], *shown: str) -> None:
    """dev and run built (the dry run shows one buildx argv per pattern of `shown`, each
    matching it from its start); the run image runs the example."""
    dry = docker_ros(project, "build", "--dry-run", env=env)
    assert dry.returncode == 0, dry.stdout[-3000:]
    builds = [line for line in dry.stdout.splitlines() if line.startswith("[dry-run] build: ")]
    assert len(builds) == len(shown), dry.stdout
    for line, start in zip(builds, shown):
        assert re.match(start, line[len("[dry-run] build: "):]), (line, start)
    try:
        built = docker_ros(project, "build", env=env)
        assert built.returncode == 0, built.stdout[-4000:]
        out = run_until(ref, HEARD, 60)
        assert HEARD in out, out[-3000:]
    finally:
        remove_image(ref)
        remove_image(f"{ref}-dev")


def example(tmp_path: Path, ros1_base_image: str, **settings: str) -> tuple:
    project = copy_example(tmp_path / "example")
    ref = f"docker-ros-test/buildx-versions-{uuid.uuid4().hex[:8]}:1"
    write_env(project, BASE_IMAGE=ros1_base_image, IMAGE=ref, TARGET="dev,run",
              COMMAND=EXAMPLE_COMMAND, **settings)
    return project, ref


def test_the_suite_runs_on_a_current_buildx_whose_bake_gets_what_it_needs(
    ros1_base_image: str, tmp_path: Path
) -> None:
    """The suite's buildx is 0.20 or later; bake is granted exactly our temporary folder and the
    build context (`--allow=fs.read=`), and with BUILD_NETWORK=host the host's network."""
    version = buildx_version()
    assert buildx_plugin("current").is_file(), f"no current buildx; {SETUP_HINT}"
    assert minor(version) >= 20, f"the suite runs on {version!r}; {SETUP_HINT}"
    project, ref = example(tmp_path, ros1_base_image, BUILD_NETWORK="host")
    build_and_run(project, ref, {}, re.escape(
        "docker buildx bake '--allow=fs.read=<temporary>' "
        f"--allow=fs.read={project.resolve()} --allow=network.host --progress=plain "))


@pytest.mark.parametrize("network", ["", "host"])
def test_debians_buildx_0_13_builds_without_allow_flags(ros1_base_image: str, tmp_path: Path,
                                                        network: str) -> None:
    """Debian stable's buildx (0.13) knows no `--allow`: bake runs without it. Its bake knows
    no network mode either: with BUILD_NETWORK, dev and run are two builds, dev first."""
    assert buildx_plugin("debian").is_file(), f"no Debian buildx; {SETUP_HINT}"
    env = buildx_config(tmp_path / "docker-config", "debian")
    version = buildx_version({**os.environ, **env})
    assert minor(version) < 20, version
    project, ref = example(tmp_path, ros1_base_image, BUILD_NETWORK=network)
    if network:
        build_and_run(project, ref, env, *(
            rf"docker buildx build --progress=plain --file \S+ --target {target} .* "
            "--network host " for target in ("dev", "run")))
    else:
        build_and_run(project, ref, env, re.escape("docker buildx bake --progress=plain "))
