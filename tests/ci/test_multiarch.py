"""Two architectures for real (issue 21): amd64 natively and arm64 under QEMU, each from its
own base image (`<BASE_IMAGE>-arm64`, as bootstrap tags it), pushed to a local registry with
one manifest list per image, both by the Action's single job with platform amd64,arm64 and by
the GitLab template's per-architecture jobs and its Push job (gitlab-ci-local). The pulled
arm64 run image runs its talker and listener. `inv lock` resolves each platform's entries in
its own image stages (issue 23).

The workspace is one Python catkin package (a real colcon build, no C++ compile and, with its
rosdep rule for std_msgs, no -dev packages to install under QEMU): the emulated build is the
slow part of this module. The
GitLab jobs, the Action and `inv lock` build FROM the same BASE_IMAGE on the same engine, so
the emulated steps run once and the later builds take them from BuildKit's cache (the apt
cache mounts are named after BASE_IMAGE and the platform; only colcon's build/ cache is per
checkout and image name).

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
  from a registry is the container builder's test below.)
- a docker-container builder builds both platforms from a multi-arch base in a registry,
  pushes them with a registry cache of every stage, the pulled arm64 image runs, and an empty
  builder (a fresh runner's) takes every step of both platforms from that cache: image,
  test_a_docker_container_builder_builds_both_platforms_and_an_empty_one_from_its_cache
- `inv lock` with two platforms writes four entries, each platform's base digest and the
  toolchain resolved under QEMU: image, test_lock_resolves_each_platform_in_its_own_image.
  A locked arm64 build installing its platform's entry was an emulated build of its own (5
  minutes): the entry a step honours is the one of the machine it runs on (unit,
  tests/unit/test_lock.py::test_a_step_honours_the_entry_of_the_platform_it_runs_on), an
  arm64 image's machine is aarch64 (the GitLab test above), and a locked build installing
  exactly its entry is test_lock.py's (image).
- the GitLab jobs' QEMU snippet registers only the job's architecture, never touching this
  machine's handlers: test_gitlab_job_of_another_architecture_registers_qemu_for_its_
  architecture_only
"""

from __future__ import annotations

import json
import os
import platform
import re
import subprocess
import time
import uuid
from pathlib import Path
from typing import Dict, Iterator, List, Mapping, Optional, Tuple

import docker
import pytest

from docker_ros.host import engine
from docker_ros.in_image.runtime.lockfile import LOCK_FILE
from tests import engines
from tests.ci.cihelp import (
    REPO,
    example_repository,
    gitlab_ci_local,
    include_gitlab_template,
    index_architectures,
    load,
    manifest_architectures,
    registry_get,
    registry_tags,
)
from tests.ci.github_harness import Event, run_action
from tests.conftest import (
    AuthRegistry,
    module_auth_registry,
    module_registry,
    serve_registry,
    stable_folder,
    stable_port,
)
from tests.docker.buildhelp import (
    cached_vertices,
    docker_ros,
    not_from_cache,
    own_copy,
    remove_image,
    run_until,
    sh,
    write_files,
)
from tests.engines import env_for

pytestmark = pytest.mark.docker

IMAGE = "docker-ros-test/multiarch"
COMMAND = "roslaunch tiny_chat chat.launch"
HEARD = "tiny_chat heard: hello from"
FILES = {
    "tiny_chat/package.xml": """\
        <?xml version="1.0"?>
        <package format="3">
          <name>tiny_chat</name>
          <version>0.1.0</version>
          <description>multi-arch test: a Python talker and listener (ROS 1)</description>
          <maintainer email="tests@docker-ros.invalid">tests</maintainer>
          <license>MIT</license>
          <buildtool_depend>catkin</buildtool_depend>
          <exec_depend>rospy</exec_depend>
          <exec_depend>std_msgs</exec_depend>
          <exec_depend>roslaunch</exec_depend>
        </package>
        """,
    "tiny_chat/CMakeLists.txt": """\
        cmake_minimum_required(VERSION 3.10)
        project(tiny_chat)
        find_package(catkin REQUIRED)
        catkin_package()
        catkin_install_python(PROGRAMS scripts/talker.py scripts/listener.py
          DESTINATION ${CATKIN_PACKAGE_BIN_DESTINATION})
        install(DIRECTORY launch DESTINATION ${CATKIN_PACKAGE_SHARE_DESTINATION})
        """,
    "tiny_chat/scripts/talker.py": """\
        #!/usr/bin/env python3
        import platform
        import rospy
        from std_msgs.msg import String
        rospy.init_node("talker")
        pub = rospy.Publisher("chat", String, queue_size=10)
        rate = rospy.Rate(5)
        while not rospy.is_shutdown():
            pub.publish("hello from " + platform.machine())
            rate.sleep()
        """,
    "tiny_chat/scripts/listener.py": """\
        #!/usr/bin/env python3
        import rospy
        from std_msgs.msg import String
        rospy.init_node("listener")
        rospy.Subscriber("chat", String, lambda m: print("tiny_chat heard: " + m.data, flush=True))
        rospy.spin()
        """,
    # A Python node needs std_msgs' Python module, which the base has; Debian's rosdep rule
    # also installs its C++ headers and the roscpp -dev chain they pull in: under QEMU, three
    # minutes of every emulated build. The repository's own rule (ROSDEP_RULES_FILE's default
    # place) is what a user of Python nodes writes for a small run image.
    "docker/rosdep.yaml": """\
        std_msgs:
          debian: [python3-std-msgs]
        """,
    "tiny_chat/launch/chat.launch": """\
        <launch>
          <node pkg="tiny_chat" type="talker.py" name="talker" output="screen"/>
          <node pkg="tiny_chat" type="listener.py" name="listener" output="screen"/>
        </launch>
        """,
}


# The Action's and the GitLab jobs' image names and checkouts are the same in every run (the
# registries' ports, stable_folder): so is docker-ros's colcon cache id, and the emulated
# colcon step comes from Engine 20.10's cache (see conftest.stable_folder).
own_registry = module_registry("docker-ros-test-multiarch")
own_auth_registry = module_auth_registry("docker-ros-test-multiarch-auth")


def tiny_workspace(root: Path) -> Path:
    for path in write_files(root, FILES):
        if path.suffix == ".py":
            path.chmod(0o755)
    return root


@pytest.fixture(scope="module")
def repository(ros1_base_image: str, ros1_arm64_base_image: str,
               tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny workspace as a git repository; BASE_IMAGE names the amd64 base, whose arm64
    image bootstrap tagged `<BASE_IMAGE>-arm64`."""
    assert ros1_arm64_base_image == f"{ros1_base_image}-arm64"
    root = tmp_path_factory.mktemp("multiarch")
    source = tiny_workspace(root / "source")
    return example_repository(root, ros1_base_image, source=source, command=COMMAND)


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


def host_arch() -> str:
    return {"x86_64": "amd64", "aarch64": "arm64"}[platform.machine()]


def pulled_architecture(ref: str, platform: str) -> str:
    """Pull ref's image of platform afresh from the registry; its architecture."""
    remove_image(ref)
    subprocess.run(["docker", "pull", "-q", "--platform", f"linux/{platform}", ref],
                   check=True, capture_output=True)
    return subprocess.run(["docker", "image", "inspect", "-f", "{{.Architecture}}", ref],
                          check=True, capture_output=True, text=True).stdout.strip()


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
    repository: Path, own_registry: str, docker_ros_wheel: Path
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
                                    "IMAGE_NAME": f"{own_registry}/{image}"})
    print(f"gitlab-ci-local, PLATFORM=amd64,arm64: {time.monotonic() - began:.0f} s")
    assert result.returncode == 0, result.stdout[-6000:]
    for job in ("build-amd64", "build-arm64", "Push"):
        assert f"PASS  {job}" in result.stdout, job
    # the arm64 job builds FROM `<BASE_IMAGE>-arm64` (a local amd64 BASE_IMAGE from no
    # registry); each job builds, slims and pushes under `-<arch>` names of its own: the jobs
    # run at once on one engine here, as on a shell runner, and once tagged each other's image
    assert "base image (arm64): docker-ros-test/ros1:bookworm-arm64" in result.stdout
    assert "slim: arm64 not slimmed on this amd64 runner" in result.stdout
    assert f"manifest: {own_registry}/{image}:latest-slim-arm64 is not in the registry" in (
        result.stdout)
    assert registry_tags(own_registry, image) == [
        # (TARGET=run: no build state, docker-ros pushed the run image only)
        "latest", "latest-amd64", "latest-arm64",
        "latest-slim", "latest-slim-amd64",
    ]
    assert manifest_architectures(f"{own_registry}/{image}:latest") == ["amd64", "arm64"]
    assert manifest_architectures(f"{own_registry}/{image}:latest-slim") == ["amd64"]
    ref = f"{own_registry}/{image}:latest"
    try:
        assert pulled_architecture(ref, "arm64") == "arm64"
        assert sh(ref, "uname -m").stdout.strip() == "aarch64"  # QEMU runs it
        out = run_until(ref, HEARD, 120)
        assert f"{HEARD} aarch64" in out, out[-3000:]
    finally:
        remove_image(ref)


def test_action_single_job_multiarch_example(
    repository: Path, ros1_base_image: str, ros1_arm64_base_image: str,
    own_auth_registry: AuthRegistry
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
              "platform": "amd64,arm64", "image-name": f"{own_auth_registry.address}/{image}",
              "registry": own_auth_registry.address,
              # the runner's engine as it is: the emulated steps are in its cache (the
              # default's engine on the containerd store is test_github_action's)
              "containerd-image-store": "false"}
    event = Event(origin=repository.parent / "origin.git", repository="Org/Multiarch",
                  ref_name="main", actor=own_auth_registry.user, token=own_auth_registry.password)
    env = {k: v for k, v in os.environ.items()
           if k not in ("TARGET", "COMMAND", "IMAGE") and not k.startswith(("GITHUB_", "CI_"))}
    began = time.monotonic()
    run = run_action(REPO, inputs, event, stable_folder("multiarch-action"), env)
    print(f"action, platform amd64,arm64, dev and run, with slim: "
          f"{time.monotonic() - began:.0f} s")
    assert run.returncode == 0, run.log[-6000:]
    # a foreign platform: the action sets QEMU up
    assert "docker/setup-qemu-action@v3" in [step["uses"] for step in run.replaced]
    assert own_auth_registry.password not in run.log
    auth = own_auth_registry.auth
    tags = registry_tags(own_auth_registry.address, image, auth)
    assert {"latest", "latest-dev", "latest-slim"} <= set(tags), tags
    for tag in ("latest", "latest-dev"):
        assert index_architectures(own_auth_registry.address, image, tag, auth) == [
            "amd64", "arm64"], tag
    # the slim names hold the runner's architecture only (slimming runs the image)
    assert image_architectures(own_auth_registry.address, image, "latest-slim", auth) == [
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


def built_targets(log: str) -> Dict[Tuple[str, str], str]:
    """A build's log per (platform, target) (`==> docker-ros build (arm64) run -> ...`)."""
    parts = re.split(r"^==> docker-ros build \((\w+)\) ([\w-]+) -> .*$", log, flags=re.MULTILINE)
    return {(arch, target): part
            for arch, target, part in zip(parts[1::3], parts[2::3], parts[3::3])}


def last_step(vertex: str, target: str) -> bool:
    """Is the vertex (`[run 3/3] RUN ...`) the last step of the target's own stage?"""
    match = re.match(rf"\[{re.escape(target)} (\d+)/(\d+)\]", vertex)
    return bool(match) and match.group(1) == match.group(2)


@pytest.fixture(scope="module")
def builder_registry(docker_client: docker.DockerClient,
                     tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A registry of this module on the same port in every run where that port is free: the
    base image's name holds it, and so do the kept builder's cache keys (BASE_IMAGE is an ARG
    of the steps)."""
    with serve_registry(docker_client, tmp_path_factory.mktemp("builder-registry"),
                        port=stable_port("docker-ros-test-container-builder")) as address:
        yield address


def test_a_docker_container_builder_builds_both_platforms_and_an_empty_one_from_its_cache(
    repository: Path, ros1_base_image: str, ros1_arm64_base_image: str, engine26: str,
    buildkit_image: str, kept_builder: str, builder_registry: str
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
    a later run of the same code: its registry keeps its port, hence the names. What it pushes
    is the registry cache of every stage whether it built the steps or had them cached.)"""
    engines.copy_once(ros1_arm64_base_image, engine26)
    env26 = env_for(engine26)
    base = f"{builder_registry}/docker-ros-test/multiarch-base:bookworm"
    # (this module's registry is new in every run: no name of an earlier run is in it)
    name = f"{builder_registry}/{IMAGE}-builder"
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
            registry_tags(builder_registry, name.split("/", 1)[1]))
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
