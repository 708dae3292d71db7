"""A docker-container builder's two platforms, and the GitLab build jobs' QEMU snippet (issue
21): the slow half of the multi-arch tests that waits for the BuildKit image too, in a module of
its own so that it runs beside test_multiarch's jobs (both wait first for the emulated arm64
base). The workspace is tests/ci/multiarch.py's.

proves (each line: where; "image" = a test here):
- a docker-container builder builds both platforms from a multi-arch base in a registry,
  pushes them with a registry cache of every stage, the pulled arm64 image runs, and an empty
  builder (a fresh runner's) takes every step of both platforms from that cache: image,
  test_a_docker_container_builder_builds_both_platforms_and_an_empty_one_from_its_cache
- the GitLab jobs' QEMU snippet registers only the job's architecture, never touching this
  machine's handlers: test_gitlab_job_of_another_architecture_registers_qemu_for_its_
  architecture_only
"""

from __future__ import annotations

import re
import subprocess
import time
import uuid
from pathlib import Path
from typing import Dict, Tuple

import pytest

from tests import engines
from tests.ci.cihelp import REPO, load, manifest_architectures, registry_tags
from tests.ci.multiarch import HEARD, IMAGE, host_arch, pulled_architecture, repository
from tests.docker.buildhelp import (
    cached_vertices,
    docker_ros,
    not_from_cache,
    remove_image,
    run_until,
)
from tests.engines import env_for

pytestmark = pytest.mark.docker
__all__ = ["repository"]  # (a module fixture of tests/ci/multiarch.py)


def built_targets(log: str) -> Dict[Tuple[str, str], str]:
    """A build's log per (platform, target) (`==> docker-ros build (arm64) run -> ...`)."""
    parts = re.split(r"^==> docker-ros build \((\w+)\) ([\w-]+) -> .*$", log, flags=re.MULTILINE)
    return {(arch, target): part
            for arch, target, part in zip(parts[1::3], parts[2::3], parts[3::3])}


def last_step(vertex: str, target: str) -> bool:
    """Is the vertex (`[run 3/3] RUN ...`) the last step of the target's own stage?"""
    match = re.match(rf"\[{re.escape(target)} (\d+)/(\d+)\]", vertex)
    return bool(match) and match.group(1) == match.group(2)


def test_a_docker_container_builder_builds_both_platforms_and_an_empty_one_from_its_cache(
    repository: Path, ros1_base_image: str, ros1_arm64_base_image: str, engine26: str,
    buildkit_image: str, kept_builder: str, local_registry: str
) -> None:
    """What a GitHub workflow with docker/setup-qemu-action and docker/setup-buildx-action
    gets: a docker-container builder (its own BuildKit, QEMU through the kernel's binfmt
    handler) and BASE_IMAGE a multi-arch image in a registry. Both platforms are built there
    (the tools and imports images of each reach it as OCI layouts: a FROM of a local image
    would look for it on Docker Hub), loaded into the engine, pushed with one manifest list and
    a registry cache of every stage, and the pulled arm64 image runs its talker and listener.
    A new, empty builder (a fresh CI runner's) then takes every step of both platforms from
    that cache: the tools and imports images it gets have the digests of the first, and
    nothing runs under QEMU. (The first builder is the one kept between runs; its cache serves
    a later run of the same code: the run's registry keeps its port, hence the names. What it
    pushes is the registry cache of every stage whether it built the steps or had them
    cached.)"""
    engines.copy_once(ros1_arm64_base_image, engine26)
    env26 = env_for(engine26)
    base = f"{local_registry}/docker-ros-test/multiarch-base:bookworm"
    # (the run's registry is new in every run: no name of an earlier run is in it)
    name = f"{local_registry}/{IMAGE}-builder"
    settings = {"DOCKER_HOST": engine26, "BASE_IMAGE": base, "IMAGE": f"{name}:latest",
                "TARGET": "run", "PLATFORM": "amd64,arm64", "CACHE_TO": f"{name}:cache"}
    try:
        for arch, local in (("amd64", ros1_base_image), ("arm64", ros1_arm64_base_image)):
            for argv in (["tag", local, f"{base}-{arch}"], ["push", "-q", f"{base}-{arch}"]):
                done = subprocess.run(["docker", *argv], env=env26, capture_output=True,
                                      text=True)
                assert done.returncode == 0, done.stderr
        joined = subprocess.run(["docker", "buildx", "imagetools", "create", "--tag", base,
                                 f"{base}-amd64", f"{base}-arm64"], env=env26,
                                capture_output=True, text=True)
        assert joined.returncode == 0, joined.stderr
        began = time.monotonic()
        result = docker_ros(repository, "push", env={**settings, "BUILDER": kept_builder})
        print(f"push through a docker-container builder, PLATFORM=amd64,arm64: "
              f"{time.monotonic() - began:.0f} s")
        assert result.returncode == 0, result.stdout[-6000:]
        assert f"builder: {kept_builder} (built in its own BuildKit" in result.stdout
        assert "CACHE_TO: registry cache of every stage (mode=max)" in result.stdout
        assert manifest_architectures(f"{name}:latest") == ["amd64", "arm64"]
        assert {"latest", "cache-run-amd64", "cache-run-arm64"} <= set(
            registry_tags(local_registry, name.split("/", 1)[1]))
        ref = f"{name}:latest"
        assert pulled_architecture(ref, "arm64") == "arm64"
        out = run_until(ref, HEARD, 120)
        assert f"{HEARD} aarch64" in out, out[-3000:]

        subprocess.run(["docker", "rmi", ref], env=env26, capture_output=True)
        with engines.container_builder(engine26, buildkit_image) as empty:
            again = docker_ros(repository, "build", env={**settings, "BUILDER": empty})
        assert again.returncode == 0, again.stdout[-6000:]
        built = built_targets(again.stdout)
        assert set(built) == {("amd64", "run"), ("arm64", "run")}, again.stdout[-3000:]
        for (arch, target), log in built.items():
            assert len(cached_vertices(log)) >= 5, log[-3000:]
            # A target's last step was sometimes run again by an empty builder while every
            # step before it came from the cache (run's COMMAND check, a RUN that leaves no
            # file; measured in two full runs of 2026-11-26): it compiles nothing and takes a
            # second. Any other step must be cached.
            missed = [v for v in not_from_cache(log) if not last_step(v, target)]
            assert missed == [], (arch, target, log[-3000:])
        assert "Starting >>> " not in again.stdout
    finally:
        remove_image(f"{name}:latest")
        subprocess.run(["docker", "rmi", f"{name}:latest", f"{name}:latest-amd64",
                        f"{name}:latest-arm64", f"{base}-amd64", f"{base}-arm64"],
                       env=env26, capture_output=True)


BINFMT = Path("/proc/sys/fs/binfmt_misc")
# The runner's handler as the snippet finds it -> the stand-in's calls it must make.
HANDLERS = {
    "none": (None, ["--install arm64"]),
    "disabled": ("disabled\ninterpreter /usr/bin/qemu-aarch64\nflags: F\n",
                 ["--uninstall qemu-aarch64", "--install arm64"]),
    "not fixed": ("enabled\ninterpreter /usr/bin/qemu-aarch64\nflags: P\n",
                  ["--uninstall qemu-aarch64", "--install arm64"]),
    "registered": ("enabled\ninterpreter /usr/bin/qemu-aarch64-static\nflags: PF\n", []),
}


def machine_handlers() -> dict:
    """This machine's binfmt handlers and status (`register` is write-only)."""
    return {path.name: path.read_bytes() for path in sorted(BINFMT.iterdir())
            if path.name != "register"}


def test_gitlab_job_of_another_architecture_registers_qemu_for_its_architecture_only(
        engine26: str, ros1_base_image: str, tmp_path: Path) -> None:
    """The GitLab build jobs' QEMU snippet, run for real, for each state of the runner's
    qemu-aarch64 handler: none, disabled, not fixed (no F) -> DOCKER_ROS_QEMU_IMAGE is run
    privileged with `--install arm64` (after `--uninstall qemu-aarch64` where one is there), as
    docker/setup-qemu-action runs tonistiigi/binfmt, never a reset of every handler; registered
    and fixed -> nothing is run; an amd64 job on this amd64 runner -> nothing. The snippet reads
    the handlers where BINFMT_MISC says (a folder of this test's), and the image stands in for
    tonistiigi/binfmt (Docker Hub) by printing its arguments: this machine's binfmt handlers,
    which other work on it may be using, are never touched (checked byte for byte). That the
    real image then registers the handler is tonistiigi/binfmt's to prove. The job's engine is
    Engine 26, as GitLab's docker:27 service (Engine 20.10 cannot start a privileged container
    here: it lacks CAP_SYS_RESOURCE)."""
    assert host_arch() == "amd64", "the snippet is checked from an amd64 runner"
    before = machine_handlers()
    context = tmp_path / "binfmt"
    context.mkdir()
    (context / "Dockerfile").write_text(
        f'FROM {ros1_base_image}\nENTRYPOINT ["echo", "binfmt stand-in:"]\n')
    snippet = load(REPO / ".gitlab-ci" / "docker-ros.yml")[".docker-ros-qemu"]["script"][0]
    image = f"docker-ros-test/binfmt-stand-in:{uuid.uuid4().hex[:12]}"
    env26 = env_for(engine26)
    subprocess.run(["docker", "build", "-q", "-t", image, str(context)], env=env26,
                   check=True, capture_output=True)
    try:
        for state, (status, calls) in HANDLERS.items():
            fake = tmp_path / state.replace(" ", "-")
            fake.mkdir()
            if status is not None:
                (fake / "qemu-aarch64").write_text(status)
            ran = subprocess.run(["bash", "-ec", snippet], capture_output=True, text=True,
                                 env={**env26, "_PLATFORM": "arm64", "BINFMT_MISC": str(fake),
                                      "DOCKER_ROS_QEMU_IMAGE": image})
            assert ran.returncode == 0, (state, ran.stderr)
            made = re.findall(r"^binfmt stand-in: (.*)$", ran.stdout, re.MULTILINE)
            assert made == calls, (state, ran.stdout)
            said = ("QEMU (qemu-aarch64) is registered" if not calls
                    else f"registering QEMU for arm64 ({image})")
            assert f"docker-ros: arm64 job on a amd64 runner: {said}" in ran.stdout, ran.stdout
        native = subprocess.run(["bash", "-ec", snippet], capture_output=True, text=True,
                                env={**env26, "_PLATFORM": "amd64",
                                     "BINFMT_MISC": str(tmp_path / "none"),
                                     "DOCKER_ROS_QEMU_IMAGE": image})
        assert native.returncode == 0 and native.stdout == "", native.stdout + native.stderr
    finally:
        subprocess.run(["docker", "image", "rm", image], env=env26, capture_output=True)
    assert machine_handlers() == before
