"""The modern engine generation (issue 21): Engine 26 on the containerd image store, the daemon
scripts/setup.sh starts beside the shared Engine 20.10. Its GitLab CI pipeline builds, tests,
slims and pushes the example with a registry cache of every stage (CACHE_TO, mode=max); the same
pipeline on an empty Engine 26 takes every stage of dev and run from that cache, and after a
one-file edit compiles that file only, then caches every stage again; Engine 26
reached through a docker context (BUILDER) is a build server whose images land in a registry
and run on the shared engine."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import uuid
from pathlib import Path
from typing import Dict, Iterator, List, Optional

import pytest

from docker_ros.host import engine
from tests import engines
from tests.ci.cihelp import (
    REPO,
    assert_pulled_image_runs,
    assert_sources_hold_no_secret,
    example_repository,
    git,
    registry_get,
    registry_tags,
)
from tests.ci.test_gitlab_template import gitlab_ci_local
from tests.docker.buildhelp import cached_vertices, docker_ros, not_from_cache, write_env
from tests.docker.test_fast_rebuilds import compiled_objects
from tests.engines import ENGINE26_HOST, private_engine

pytestmark = pytest.mark.docker

IMAGE = "docker-ros-test/engine26"
REGISTRY_CACHE = "CACHE_TO: registry cache of every stage (mode=max)"


def pipeline(repo: Path, registry: str, host: str, wheel: Path,
             secrets: Optional[Dict[str, str]] = None, **variables: str
             ) -> subprocess.CompletedProcess:
    """The GitLab template's pipeline on main with every job's docker on the engine at host
    (secrets: from gitlab-ci-local's variables file, as from GitLab's settings)."""
    return gitlab_ci_local(repo, {
        "GITLAB_CI": "true", "IMAGE_NAME": f"{registry}/{IMAGE}",
        "DOCKER_ROS_PIP_SPEC": str(wheel), "DOCKER_HOST": host, "BUILD_NETWORK": "host",
        **variables}, secrets=secrets)


def build_log(repo: Path) -> str:
    return (repo / ".gitlab-ci-local" / "output" / "build-amd64.log").read_text()


@pytest.fixture(scope="module")
def first_pipeline(engine26: str, ros1_base_image: str, local_registry: str,
                   docker_ros_wheel: Path, tmp_path_factory: pytest.TempPathFactory
                   ) -> Iterator[Dict[str, object]]:
    """The example's main-branch pipeline on Engine 26: build, test, slim, push, manifest.
    Engine 26 keeps no image of it afterwards (the other modules' images named after the
    run's registry are theirs)."""
    repo = example_repository(tmp_path_factory.mktemp("engine26"), ros1_base_image)
    (repo / ".gitlab-ci").mkdir()
    shutil.copy(REPO / ".gitlab-ci" / "docker-ros.yml", repo / ".gitlab-ci" / "docker-ros.yml")
    (repo / ".gitlab-ci.yml").write_text(
        "include:\n  - local: .gitlab-ci/docker-ros.yml\n\ndefault:\n  services: []\n\n"
        "variables:\n  TARGET: dev,run\n")
    git(repo, "add", "-A")
    git(repo, "commit", "-qm", "ci")
    secret = f"docker-ros-test-secret-{uuid.uuid4().hex}"
    result = pipeline(repo, local_registry, engine26, docker_ros_wheel, ENABLE_SLIM="true",
                      secrets={"GIT_HTTPS_PASSWORD": secret}, ENABLE_INDUSTRIAL_CI="true")
    yield {"repo": repo, "registry": local_registry, "result": result,
           "build": build_log(repo), "secret": secret, "host": engine26,
           "wheel": docker_ros_wheel, "base": ros1_base_image}
    env = {**os.environ, "DOCKER_HOST": engine26}
    listed = subprocess.run(["docker", "images", "--format", "{{.Repository}}:{{.Tag}}"],
                            env=env, capture_output=True, text=True)
    mine = [ref for ref in listed.stdout.split()
            if ref.startswith(f"{local_registry}/{IMAGE}:")]
    if mine:
        subprocess.run(["docker", "rmi", "-f", *mine], env=env, capture_output=True)


def test_ci_template_builds_tests_slims_and_pushes_on_engine26(first_pipeline: dict) -> None:
    result = first_pipeline["result"]
    assert result.returncode == 0, result.stdout[-6000:]
    assert "PASS  build-amd64" in result.stdout and "PASS  Push" in result.stdout
    log = first_pipeline["build"]
    for task in ("build", "test", "slim", "push"):
        assert f"docker-ros ci: docker-ros {task}" in log, task
    assert "docker-ros test (amd64): " in log
    assert "containerd image store" in log and REGISTRY_CACHE in log
    assert "exporting cache to registry" in log
    tags = registry_tags(first_pipeline["registry"], IMAGE)
    assert {"latest", "latest-dev", "latest-slim", "latest-build-state-amd64",
            "latest-cache-dev-amd64", "latest-cache-run-amd64"} <= set(tags), tags


def test_the_secret_stays_out_of_engine26_images_and_the_log(first_pipeline: dict) -> None:
    """GIT_HTTPS_PASSWORD (from gitlab-ci-local's variables file, in the checkout): in no log,
    history or image configuration, and no file of the dev image's sources holds it."""
    assert first_pipeline["result"].returncode == 0
    secret = first_pipeline["secret"]
    assert secret not in first_pipeline["build"]
    env = {**os.environ, "DOCKER_HOST": first_pipeline["host"]}
    # (the build job's local images carry its architecture: ENABLE_SINGLEARCH_PUSH)
    for tag in ("latest-amd64", "latest-dev-amd64", "latest-slim-amd64"):
        ref = f"{first_pipeline['registry']}/{IMAGE}:{tag}"
        for argv in (["docker", "history", "--no-trunc", ref], ["docker", "image", "inspect", ref]):
            shown = subprocess.run(argv, env=env, capture_output=True, text=True)
            assert shown.returncode == 0, shown.stderr
            assert secret not in shown.stdout, argv
    assert_sources_hold_no_secret(f"{first_pipeline['registry']}/{IMAGE}:latest-dev", [secret])


def test_images_pushed_from_engine26_run_on_the_shared_engine(first_pipeline: dict) -> None:
    assert first_pipeline["result"].returncode == 0
    assert_pulled_image_runs(f"{first_pipeline['registry']}/{IMAGE}:latest")
    assert_pulled_image_runs(f"{first_pipeline['registry']}/{IMAGE}:latest-slim")


def sections(log: str) -> Dict[str, str]:
    """The `docker-ros build` task's log per target (`==> docker-ros build (amd64) dev -> ...`)."""
    build = log.split("docker-ros ci: docker-ros build", 1)[1].split("docker-ros ci: ", 1)[0]
    parts = re.split(r"^==> docker-ros build \(\w+\) ([\w-]+) -> .*$", build,
                     flags=re.MULTILINE)
    return dict(zip(parts[1::2], parts[2::2]))


STATE_TAG = "latest-build-state-amd64"
MANIFESTS = ", ".join(["application/vnd.oci.image.index.v1+json",
                       "application/vnd.oci.image.manifest.v1+json",
                       "application/vnd.docker.distribution.manifest.v2+json"])


def pushed_state(registry: str) -> object:
    """The build state's manifest as the registry holds it now."""
    return registry_get(registry, f"{IMAGE}/manifests/{STATE_TAG}", accept=MANIFESTS)


def assert_every_step_cached(log: str) -> None:
    """Every stage step of dev and run from the registry cache, the colcon step never started,
    and the pulled build state kept as this job's (not built again)."""
    assert REGISTRY_CACHE in log
    assert "build state: built from these same inputs: seeding as that build was" in log
    built = sections(log)
    assert {"dev", "run"} <= set(built) and "build-state" not in built, log[-3000:]
    for target in ("dev", "run"):  # (steps there are, and none ran)
        assert len(cached_vertices(built[target])) >= 5, built[target][-3000:]
        assert not_from_cache(built[target]) == [], built[target][-3000:]
    assert "Starting >>> colcon" not in built["run"]


def test_after_a_one_file_edit_engine26_compiles_it_then_caches_every_stage(
    first_pipeline: dict, empty_engine26: str, tmp_path: Path
) -> None:
    """Two fresh runners (empty Engine 26s), on a clone of the repository (the module's own
    stays as the first pipeline built it):
    1. one .cpp edited: the job builds over the pulled build state and compiles that file only;
    2. nothing changed since: every stage of dev and run comes from the registry cache, the
       colcon RUN too. The pulled build state was built from these same inputs: the build is
       seeded as that build was (the state before the edit, by digest), so the RUN's cache key
       is the edit job's, and the state pushed again is the same image.
    (A no-change job after the first pipeline, seeded empty, is the same proof with the plainer
    seed: test_buildstate.py has that seed's decision, test_ci_build_state.py its build.)"""
    assert first_pipeline["result"].returncode == 0
    registry: str = first_pipeline["registry"]
    repo = tmp_path / "repo"
    git(tmp_path, "clone", "-q", str(first_pipeline["repo"]), str(repo))
    # (the first pipeline's checkout as it was: its variables file, which git ignores)
    shutil.copy(first_pipeline["repo"] / ".gitlab-ci-local-variables.yml", repo)
    shutil.copy(first_pipeline["repo"] / ".git" / "info" / "exclude",
                repo / ".git" / "info" / "exclude")
    source = repo / "docker_ros_example" / "src" / "talker.cpp"
    source.write_text(source.read_text() + "// edited by the Engine 26 test\n")
    git(repo, "commit", "-qam", "edit talker.cpp")
    result = pipeline(repo, registry, empty_engine26, first_pipeline["wheel"],
                      ENABLE_SLIM="false", ENABLE_INDUSTRIAL_CI="false")
    assert result.returncode == 0, result.stdout[-6000:]
    log = build_log(repo)
    assert "build state: its inputs differ from this build's: building over it" in log
    run = sections(log)["run"]
    assert "starting from the pulled build state" in run
    assert "colcon: 1 of " in run and "docker_ros_example changed" in run
    assert [len(o) for o in compiled_objects(run).values()] == [1], compiled_objects(run)

    before = pushed_state(registry)
    with private_engine([first_pipeline["base"]], modern=True) as host:
        again = pipeline(repo, registry, host, first_pipeline["wheel"],
                         ENABLE_SLIM="false", ENABLE_INDUSTRIAL_CI="false")
    assert again.returncode == 0, again.stdout[-6000:]
    log = build_log(repo)
    assert f"seeding as that build was ({registry}/{IMAGE}@sha256:" in log
    assert_every_step_cached(log)
    assert pushed_state(registry) == before


@pytest.fixture
def engine26_context(engine26: str) -> Iterator[str]:
    """A docker context whose endpoint is Engine 26 (a build server); removed afterwards."""
    name = f"docker-ros-test-e26-{uuid.uuid4().hex[:8]}"
    subprocess.run(["docker", "context", "create", name, "--docker", f"host={engine26}"],
                   check=True, capture_output=True)
    yield name
    subprocess.run(["docker", "context", "rm", "-f", name], capture_output=True)


def test_context_host_reads_the_clis_context_store(engine26_context: str) -> None:
    """The SDK client's engine follows the CLI's docker context (DOCKER_CONTEXT here)."""
    environ = {k: v for k, v in os.environ.items() if k != "DOCKER_HOST"}
    assert engine.context_host(engine26_context, environ) == ENGINE26_HOST
    assert engine.cli_host({**environ, "DOCKER_CONTEXT": engine26_context}) == ENGINE26_HOST
    assert engine.cli_host({**environ, "DOCKER_HOST": "unix:///x.sock",
                            "DOCKER_CONTEXT": engine26_context}) == "unix:///x.sock"


def test_build_server_through_a_docker_context_pushes_to_the_registry(
    engine26_context: str, sbom_scanner: str, ros1_base_image: str, local_registry: str,
    tmp_path: Path
) -> None:
    """BUILDER names a docker context: the images are built by Engine 26 (nothing of them in
    the shared engine), pushed from there with its registry cache and, with
    BUILDX_ATTESTATIONS=true (docker-ros's --provenance and --sbom), an attestation manifest
    holding their SLSA provenance and SPDX SBOM (the containerd image store keeps them), and
    run on the shared engine after a pull. `slim` finds the run image there (no rebuild) and
    slims it there."""
    project = tmp_path / "example"
    shutil.copytree(REPO / "example", project)
    name = f"docker-ros-test/remote-{uuid.uuid4().hex[:8]}"
    ref = f"{local_registry}/{name}:1"
    write_env(project, BASE_IMAGE=ros1_base_image, IMAGE=ref, TARGET="dev,run",
              COMMAND="roslaunch docker_ros_example talker_listener.launch",
              BUILDER=engine26_context, CACHE_TO=f"{ref}-cache", BUILD_NETWORK="host",
              BUILDX_ATTESTATIONS="true")
    try:
        result = docker_ros(project, "push")
        slimmed = docker_ros(project, "slim")
    finally:  # the build server keeps nothing of this test
        subprocess.run(["docker", "rmi", "-f", ref, f"{ref}-dev", f"{ref}-slim"],
                       capture_output=True, env={**os.environ, "DOCKER_HOST": ENGINE26_HOST})
    assert result.returncode == 0, result.stdout[-6000:]
    assert slimmed.returncode == 0, slimmed.stdout[-6000:]
    assert "neither local nor pullable" not in slimmed.stdout, slimmed.stdout[:3000]
    assert "==> docker-ros build" not in slimmed.stdout
    assert f"==> docker-ros slim {ref} -> {ref}-slim" in slimmed.stdout
    assert (f"builder: {engine26_context} (docker driver of the engine at {ENGINE26_HOST}: "
            "--load keeps the images in that engine, not the local one") in result.stdout
    assert REGISTRY_CACHE in result.stdout
    shared = subprocess.run(["docker", "image", "inspect", ref], capture_output=True)
    assert shared.returncode != 0, "the image was built in the shared engine"
    repository, tag = ref.split("/", 1)[1].rsplit(":", 1)
    assert {tag, f"{tag}-dev", f"{tag}-cache-run-amd64"} <= set(
        registry_tags(local_registry, repository))
    assert attestation_predicates(local_registry, name, "1") == [
        "https://slsa.dev/provenance/v0.2", "https://spdx.dev/Document"]
    assert_pulled_image_runs(ref)


def attestation_predicates(registry: str, name: str, tag: str) -> List[str]:
    """The predicate types of the attestation manifest of name:tag's index in the registry."""
    index = registry_get(registry, f"{name}/manifests/{tag}",
                         accept="application/vnd.oci.image.index.v1+json")
    attestation, = (m for m in index["manifests"]
                    if m.get("annotations", {}).get("vnd.docker.reference.type")
                    == "attestation-manifest")
    manifest = registry_get(registry, f"{name}/manifests/{attestation['digest']}",
                            accept="application/vnd.oci.image.manifest.v1+json")
    return sorted(layer["annotations"]["in-toto.io/predicate-type"]
                  for layer in manifest["layers"])


def test_until_on_a_context_builder_prints_commands_that_reach_its_engine(
    engine26_context: str, ros1_base_image: str, tmp_path: Path
) -> None:
    """BUILDER names a docker context of Engine 26: `--until` runs its step and keeps the
    image there, and the `docker run` it prints to go on names that engine (it said `docker
    run`: the shared engine, which has no such image)."""
    project = tmp_path / "example"
    shutil.copytree(REPO / "example", project)
    ref = f"docker-ros-test/until-context-{uuid.uuid4().hex[:8]}:1"
    write_env(project, BASE_IMAGE=ros1_base_image, IMAGE=ref, BUILDER=engine26_context,
              BUILD_NETWORK="host")
    until = f"{ref}-until-clone"
    try:
        result = docker_ros(project, "build", "--until", "clone")
        assert result.returncode == 0, result.stdout[-6000:]
        enter, = (line for line in result.stdout.splitlines() if "enter it:" in line)
        assert f"docker --context {engine26_context} run --rm -it {until} bash" in enter
        line, = (line for line in result.stdout.splitlines() if "next step:" in line)
        argv = shlex.split(line.split("next step:", 1)[1])
        assert argv[:4] == ["docker", "--context", engine26_context, "run"]
        ran = subprocess.run(argv, capture_output=True, text=True, timeout=600)
        assert ran.returncode == 0, ran.stdout + ran.stderr
        assert "Finished <<< blacklist" in ran.stdout + ran.stderr
        shared = subprocess.run(["docker", "image", "inspect", until], capture_output=True)
        assert shared.returncode != 0, "the image is in the shared engine"
    finally:  # the build server keeps nothing of this test
        subprocess.run(["docker", "rmi", "-f", until], capture_output=True,
                       env={**os.environ, "DOCKER_HOST": ENGINE26_HOST})


def test_a_build_without_network_on_engine26_names_build_network_host(
    engine26: str, ros2_base_image: str, tmp_path: Path
) -> None:
    """Engine 26 of setup.sh has no outbound NAT: a build step that reaches for the network
    without BUILD_NETWORK=host (here a hook fetching a file) stops the build with a last line
    naming what failed and the setting. The base is the ROS 2 one (it has the toolchain:
    nothing else needs the network before the hook) without apt sources: apt-get update then
    has nothing to look up (each look-up waits out the resolver here, 20 s, and apt only
    warns), so the hook's own look-up is what fails."""
    engines.copy_once(ros2_base_image, engine26)
    env = engines.env_for(engine26)
    base = f"docker-ros-test/ros2-no-apt-sources:{uuid.uuid4().hex[:12]}"
    (tmp_path / "base").mkdir()
    (tmp_path / "base" / "Dockerfile").write_text(
        f"FROM {ros2_base_image}\nRUN rm -rf /etc/apt/sources.list /etc/apt/sources.list.d\n")
    subprocess.run(["docker", "build", "-q", "-t", base, str(tmp_path / "base")], env=env,
                   check=True, capture_output=True)
    project = tmp_path / "offline"
    (project / "docker").mkdir(parents=True)
    (project / "docker" / "before_dependency_installation.sh").write_text(
        "python3 -c \"import urllib.request; "
        "urllib.request.urlopen('http://deb.debian.org/debian/', timeout=10)\"\n")
    write_env(project, BASE_IMAGE=base, IMAGE="docker-ros-test/engine26-offline:1",
              TARGET="dev")
    try:
        result = docker_ros(project, "build", env={"DOCKER_HOST": engine26})
    finally:
        subprocess.run(["docker", "rmi", base], env=env, capture_output=True)
    assert result.returncode != 0, result.stdout[-3000:]
    # (the message's first line; the failing tool's own lines may follow it, indented)
    last = [line for line in result.stdout.splitlines()
            if line.startswith("docker-ros build: ")][-1]
    assert last.startswith("docker-ros build: building target 'dev' (amd64) failed in step "
                           "scripts: "), last
    assert ("; the step could not reach the network (Temporary failure in name resolution): on "
            "an engine without outbound NAT") in last, last
    assert "; it stopped at line 1: `python3 -c " in last, last  # the hook's line
    assert last.endswith("set BUILD_NETWORK=host"), last


# docker/buildkit-syft-scanner, the SBOM generator BuildKit runs by default, is on Docker Hub,
# which this machine cannot reach: a stand-in of the same name (BuildKit's scanner protocol:
# read BUILDKIT_SCAN_SOURCE, write in-toto statements to BUILDKIT_SCAN_DESTINATION).
SCANNER = "docker/buildkit-syft-scanner:stable-1"
SCAN = """#!/bin/sh
set -e
files=$(find "$BUILDKIT_SCAN_SOURCE" -type f | wc -l)
printf '{"_type": "https://in-toto.io/Statement/v0.1", "predicateType": "https://spdx.dev/Document",\
 "subject": [], "predicate": {"spdxVersion": "SPDX-2.3", "name": "stand-in: %s files"}}' "$files" \
 > "$BUILDKIT_SCAN_DESTINATION/sbom.spdx.json"
"""


@pytest.fixture
def sbom_scanner(engine26: str, ros1_base_image: str, tmp_path: Path) -> Iterator[str]:
    """The stand-in scanner under the default scanner's name on Engine 26, removed afterwards
    (unless that name was there before: then it is left as it was)."""
    env = engines.env_for(engine26)
    if engines.has_image(engine26, SCANNER):
        yield SCANNER
        return
    (tmp_path / "scanner").mkdir()
    (tmp_path / "scanner" / "scan").write_text(SCAN)
    (tmp_path / "scanner" / "scan").chmod(0o755)
    (tmp_path / "scanner" / "Dockerfile").write_text(
        f'FROM {ros1_base_image}\nCOPY scan /scan\nENTRYPOINT ["/scan"]\n')
    subprocess.run(["docker", "build", "-q", "-t", SCANNER, str(tmp_path / "scanner")], env=env,
                   check=True, capture_output=True)
    try:
        yield SCANNER
    finally:
        subprocess.run(["docker", "rmi", SCANNER], env=env, capture_output=True)


def test_attestations_are_refused_on_the_classic_store(
    ros1_base_image: str, local_registry: str, tmp_path: Path
) -> None:
    """BUILDX_ATTESTATIONS=true on the shared Engine 20.10 (classic store, which keeps no
    attestations) is refused before building, saying what to do: it once built and pushed the
    images without either, silently. (Engine 26 pushing them: the build server test above.)"""
    project = tmp_path / "example"
    shutil.copytree(REPO / "example", project)
    name = f"docker-ros-test/attested-{uuid.uuid4().hex[:8]}"
    write_env(project, BASE_IMAGE=ros1_base_image, IMAGE=f"{local_registry}/{name}:1",
              TARGET="run", COMMAND="roslaunch docker_ros_example talker_listener.launch",
              BUILDX_ATTESTATIONS="true", ENABLE_SLIM="false", BUILD_NETWORK="host")
    refused = docker_ros(project, "push")
    assert refused.returncode != 0
    assert refused.stdout.strip().splitlines()[-1] == (
        f"docker-ros push: BUILDX_ATTESTATIONS=true: the images are loaded into the engine at "
        f"{engine.cli_host(os.environ)} and pushed from there, and its classic image store "
        "keeps no attestations (SBOM, provenance): turn on its containerd image store "
        '(daemon.json: "features": {"containerd-snapshotter": true}) or set '
        "BUILDX_ATTESTATIONS=false"), refused.stdout[-3000:]
    assert "==> docker-ros build" not in refused.stdout
