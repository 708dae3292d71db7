"""Two architectures for real (issue 21): amd64 natively and arm64 under QEMU, each from its
own base image (`<BASE_IMAGE>-arm64`, as bootstrap tags it), pushed to a local registry with
one manifest list per image, both by the Action's single job with platform amd64,arm64 and by
the GitLab template's per-architecture jobs and its Push job (gitlab-ci-local). The pulled
arm64 run image runs its talker and listener. `inv lock` resolves each platform's entries in
its own image stages (issue 23). A docker-container builder's two platforms and the GitLab
jobs' QEMU snippet are test_multiarch_builder's (a module of its own, so that the two slow
halves run side by side).

The workspace (tests/ci/multiarch.py) is one Python catkin package (a real colcon build, no C++
compile and, with its rosdep rule for std_msgs, no -dev packages to install under QEMU): the
emulated build is the slow part of this module. The GitLab jobs, the Action and `inv lock`
build FROM the same BASE_IMAGE on the same engine, so the emulated steps run once and the later
builds take them from BuildKit's cache (the apt cache mounts are named after BASE_IMAGE and the
platform; only colcon's build/ cache is per checkout and image name).

proves (each line: where; "image" = a test here):
- the dry run names each platform's base (`<BASE_IMAGE>-arm64`) and refuses a local amd64-only
  base for arm64: test_the_dry_run_shows_and_checks_each_platforms_base
- GitLab per-architecture jobs push `-<arch>` names, Push joins them into manifest lists, the
  arm64 job emulates and skips slim, the pulled arm64 run image runs under QEMU: image,
  test_gitlab_jobs_per_architecture_then_the_manifest_job
- the Action's single job builds dev and run for both architectures, logs in to push, pushes
  one manifest list per name, slims the runner's architecture only, hides the password: image,
  test_action_single_job_multiarch_example. (Its base was a private multi-arch image in the
  registry, which made every emulated step of this module run twice: the apt cache ids follow
  BASE_IMAGE. A private base pulled after the login is test_github_action's; a multi-arch base
  from a registry is test_multiarch_builder's.)
- `inv lock` with two platforms writes four entries, each platform's base digest and the
  toolchain resolved under QEMU: image, test_lock_resolves_each_platform_in_its_own_image.
  A locked arm64 build installing its platform's entry was an emulated build of its own (5
  minutes): the entry a step honours is the one of the machine it runs on (unit,
  tests/unit/test_lock.py::test_a_step_honours_the_entry_of_the_platform_it_runs_on), an
  arm64 image's machine is aarch64 (the GitLab test above), and a locked build installing
  exactly its entry is test_lock.py's (image).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import time
import uuid
from pathlib import Path
from typing import List, Mapping, Optional

import pytest

from docker_ros.host import engine
from docker_ros.in_image.runtime.lockfile import LOCK_FILE
from tests.ci.cihelp import (
    REPO,
    gitlab_ci_local,
    include_gitlab_template,
    index_architectures,
    manifest_architectures,
    registry_get,
    registry_tags,
)
from tests.ci.github_harness import Event, run_action
from tests.ci.multiarch import (
    COMMAND,
    HEARD,
    IMAGE,
    host_arch,
    pulled_architecture,
    repository,
)
from tests.conftest import AuthRegistry, stable_folder
from tests.docker.buildhelp import docker_ros, own_copy, remove_image, run_until, sh

pytestmark = pytest.mark.docker
__all__ = ["repository"]  # (a module fixture of tests/ci/multiarch.py)

# The Action's and the GitLab jobs' image names and checkouts are the same in every run (the
# registries' ports, stable_folder): so is docker-ros's colcon cache id, and the emulated
# colcon step comes from Engine 20.10's cache (see conftest.stable_folder).


def image_architectures(registry: str, name: str, tag: str,
                        auth: Optional[Mapping[str, str]] = None) -> List[str]:
    """The architectures of name:tag in the registry: a list's entries, or one image's."""
    listed = index_architectures(registry, name, tag, auth)
    if listed:
        return listed
    manifest = registry_get(registry, f"{name}/manifests/{tag}", auth,
                            "application/vnd.docker.distribution.manifest.v2+json,"
                            "application/vnd.oci.image.manifest.v1+json")
    config = registry_get(registry, f"{name}/blobs/{manifest['config']['digest']}", auth)
    return [config["architecture"]]


def test_the_dry_run_shows_and_checks_each_platforms_base(repository: Path,
                                                         ros1_base_image: str) -> None:
    """The dry run's definitions name the base image the build FROMs for each platform
    (`<BASE_IMAGE>-arm64` for arm64), and stop as the build would when a local BASE_IMAGE from
    no registry has no image for a platform."""
    shown = docker_ros(repository, "build", "--dry-run", env={"PLATFORM": "amd64,arm64"})
    assert shown.returncode == 0, shown.stdout
    assert re.findall(r'"BASE_IMAGE": "([^"]+)"', shown.stdout) == [
        ros1_base_image, ros1_base_image, f"{ros1_base_image}-arm64",
        f"{ros1_base_image}-arm64"], shown.stdout
    alone = f"docker-ros-test/amd64-only:{uuid.uuid4().hex[:12]}"
    subprocess.run(["docker", "tag", ros1_base_image, alone], check=True)
    try:
        refused = docker_ros(repository, "build", "--dry-run",
                             env={"PLATFORM": "arm64", "BASE_IMAGE": alone})
    finally:
        remove_image(alone)
    assert refused.returncode == 1
    assert refused.stdout.strip().splitlines()[-1].startswith(
        f"docker-ros build: BASE_IMAGE {alone} is a local amd64 image from no registry, and no "
        f"arm64 image is tagged {alone}-arm64"), refused.stdout


def test_gitlab_jobs_per_architecture_then_the_manifest_job(
    repository: Path, local_registry: str, docker_ros_wheel: Path
) -> None:
    """build-amd64 and build-arm64 push `-<arch>` (ENABLE_SINGLEARCH_PUSH), Push joins. Both
    jobs run on this amd64 machine (gitlab-ci-local ignores runner tags), as when no arm64
    runner is registered and the arm64 job emulates: ENABLE_SLIM at its default, amd64 is
    slimmed, arm64 is not (slimming runs the image) and the job still passes; the slim list
    holds amd64 only."""
    repo = stable_folder("multiarch-gitlab") / "repo"
    subprocess.run(["git", "clone", "-q", str(repository), str(repo)], check=True)
    include_gitlab_template(repo, {"TARGET": "run", "PLATFORM": "amd64,arm64",
                                   "ENABLE_INDUSTRIAL_CI": "false"})
    image = f"{IMAGE}-gitlab"
    began = time.monotonic()
    result = gitlab_ci_local(repo, {"GITLAB_CI": "true",
                                    "DOCKER_ROS_PIP_SPEC": str(docker_ros_wheel),
                                    "IMAGE_NAME": f"{local_registry}/{image}"})
    print(f"gitlab-ci-local, PLATFORM=amd64,arm64: {time.monotonic() - began:.0f} s")
    assert result.returncode == 0, result.stdout[-6000:]
    for job in ("build-amd64", "build-arm64", "Push"):
        assert f"PASS  {job}" in result.stdout, job
    # the arm64 job builds FROM `<BASE_IMAGE>-arm64` (a local amd64 BASE_IMAGE from no
    # registry); each job builds, slims and pushes under `-<arch>` names of its own: the jobs
    # run at once on one engine here, as on a shell runner, and once tagged each other's image
    assert "base image (arm64): docker-ros-test/ros1:bookworm-arm64" in result.stdout
    assert "slim: arm64 not slimmed on this amd64 runner" in result.stdout
    assert f"manifest: {local_registry}/{image}:latest-slim-arm64 is not in the registry" in (
        result.stdout)
    assert registry_tags(local_registry, image) == [
        # (TARGET=run: no build state, docker-ros pushed the run image only)
        "latest", "latest-amd64", "latest-arm64",
        "latest-slim", "latest-slim-amd64",
    ]
    assert manifest_architectures(f"{local_registry}/{image}:latest") == ["amd64", "arm64"]
    assert manifest_architectures(f"{local_registry}/{image}:latest-slim") == ["amd64"]
    ref = f"{local_registry}/{image}:latest"
    try:
        assert pulled_architecture(ref, "arm64") == "arm64"
        assert sh(ref, "uname -m").stdout.strip() == "aarch64"  # QEMU runs it
        out = run_until(ref, HEARD, 120)
        assert f"{HEARD} aarch64" in out, out[-3000:]
    finally:
        remove_image(ref)


def test_action_single_job_multiarch_example(
    repository: Path, ros1_base_image: str, ros1_arm64_base_image: str,
    auth_registry: AuthRegistry
) -> None:
    """docker-ros's README example "Build multi-arch images" through the Action as it is
    (dev and run, both architectures, slim left at its default: on), plus where to push: a
    registry that wants a login, and the runner's engine kept (containerd-image-store false:
    the default's engine on the containerd store is test_github_action's). The job builds
    each architecture FROM its base (the local amd64 image and its `-arm64` sibling, as the
    GitLab jobs: the emulated steps come from their cache), logs in, pushes one manifest list
    per name, slims the runner's architecture only, and passes; the password is in no log."""
    image = f"{IMAGE}-action"
    inputs = {"base-image": ros1_base_image, "command": COMMAND, "target": "dev,run",
              "platform": "amd64,arm64", "image-name": f"{auth_registry.address}/{image}",
              "registry": auth_registry.address,
              # the runner's engine as it is: the emulated steps are in its cache (the
              # default's engine on the containerd store is test_github_action's)
              "containerd-image-store": "false"}
    event = Event(origin=repository.parent / "origin.git", repository="Org/Multiarch",
                  ref_name="main", actor=auth_registry.user, token=auth_registry.password)
    env = {k: v for k, v in os.environ.items()
           if k not in ("TARGET", "COMMAND", "IMAGE") and not k.startswith(("GITHUB_", "CI_"))}
    began = time.monotonic()
    run = run_action(REPO, inputs, event, stable_folder("multiarch-action"), env)
    print(f"action, platform amd64,arm64, dev and run, with slim: "
          f"{time.monotonic() - began:.0f} s")
    assert run.returncode == 0, run.log[-6000:]
    # a foreign platform: the action sets QEMU up
    assert "docker/setup-qemu-action@v3" in [step["uses"] for step in run.replaced]
    assert auth_registry.password not in run.log
    auth = auth_registry.auth
    tags = registry_tags(auth_registry.address, image, auth)
    assert {"latest", "latest-dev", "latest-slim"} <= set(tags), tags
    for tag in ("latest", "latest-dev"):
        assert index_architectures(auth_registry.address, image, tag, auth) == [
            "amd64", "arm64"], tag
    # the slim names hold the runner's architecture only (slimming runs the image)
    assert image_architectures(auth_registry.address, image, "latest-slim", auth) == [
        host_arch()]


def test_lock_resolves_each_platform_in_its_own_image(
    repository: Path, ros1_base_image: str, tmp_path: Path
) -> None:
    """`inv lock` with PLATFORM=amd64,arm64: four entries, each platform's from its own base
    image (arm64 resolved under QEMU, in lock stages that start from the steps the builds
    above left in the cache), the toolchain in dev's prepare."""
    image = f"{IMAGE}-lock-{uuid.uuid4().hex[:8]}:1"
    repo = own_copy(repository, tmp_path / "repo", image)
    arm64_base = f"{ros1_base_image}-arm64"
    began = time.monotonic()
    locked = docker_ros(repo, "lock", env={"PLATFORM": "amd64,arm64"})
    print(f"inv lock, PLATFORM=amd64,arm64: {time.monotonic() - began:.0f} s")
    assert locked.returncode == 0, locked.stdout[-6000:]
    targets = json.loads((repo / LOCK_FILE).read_text())["targets"]
    assert sorted(targets) == ["dev/amd64", "dev/arm64", "run/amd64", "run/arm64"]
    for target in ("dev", "run"):
        amd64, arm64 = targets[f"{target}/amd64"], targets[f"{target}/arm64"]
        assert amd64["base_image"]["digest"] == engine.inspect_image(ros1_base_image)["Id"]
        assert arm64["base_image"]["digest"] == engine.inspect_image(arm64_base)["Id"]
        assert amd64["inputs"] == arm64["inputs"]  # one repository: the same resolution
    assert "g++" in targets["dev/arm64"]["prepare"]  # the toolchain, resolved under QEMU
    assert "g++" not in targets["run/arm64"]["prepare"]


