"""Shared by the CI integration tests: a small ROS repository under git with an origin, and
what a registry holds."""

from __future__ import annotations

import base64
import contextlib
import json
import os
import shutil
import subprocess
import urllib.request
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Tuple

import docker
import pytest
import yaml

from tests.conftest import AuthRegistry
from tests.docker.buildhelp import EXAMPLE, remove_image, run_until, write_env

REPO = Path(__file__).resolve().parents[2]
EXAMPLE_COMMAND = "roslaunch docker_ros_example talker_listener.launch"
HEARD = "I heard: hello from docker-ros"


class GitLabLoader(yaml.SafeLoader):
    """YAML with GitLab's `!reference` tag."""


GitLabLoader.add_constructor("!reference", lambda loader, node: loader.construct_sequence(node))


def load(path: Path) -> dict:
    return yaml.load(path.read_text(), Loader=GitLabLoader)


def git(cwd: Path, *args: str) -> str:
    return subprocess.run(["git", "-c", "user.name=ci", "-c", "user.email=ci@example.com",
                           *args], cwd=cwd, check=True, capture_output=True, text=True).stdout


def example_repository(root: Path, base_image: str, source: Path = EXAMPLE,
                       command: str = EXAMPLE_COMMAND) -> Path:
    """A copy of example/ (or of source) as a git repository on `main`, pushed to a bare
    `origin` whose HEAD is main (how both CIs learn the default branch)."""
    repo = root / "repo"
    shutil.copytree(source, repo)
    write_env(repo, BASE_IMAGE=base_image, COMMAND=command, TARGET="dev,run")
    origin = root / "origin.git"
    git(root, "init", "-q", "--bare", "-b", "main", str(origin))
    git(repo, "init", "-q", "-b", "main")
    git(repo, "add", "-A")
    git(repo, "commit", "-qm", "example")
    git(repo, "remote", "add", "origin", str(origin))
    git(repo, "push", "-q", "origin", "main")
    git(repo, "remote", "set-head", "origin", "main")
    return repo


def registry_get(registry: str, path: str, auth: Optional[Mapping[str, str]] = None,
                 accept: str = "") -> Any:
    """GET a registry API path (JSON), with basic authentication when auth is given."""
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    request = urllib.request.Request(f"http://{registry}/v2/{path}")
    if auth:
        pair = f"{auth['username']}:{auth['password']}".encode()
        request.add_header("Authorization", "Basic " + base64.b64encode(pair).decode())
    if accept:
        request.add_header("Accept", accept)
    with opener.open(request, timeout=10) as answer:
        return json.load(answer)


def registry_tags(registry: str, name: str,
                  auth: Optional[Mapping[str, str]] = None) -> List[str]:
    try:
        return sorted(registry_get(registry, f"{name}/tags/list", auth).get("tags") or [])
    except OSError:
        return []


def manifest_architectures(ref: str) -> List[str]:
    """Architectures of a manifest list in a loopback registry (empty: not a list)."""
    out = subprocess.run(["docker", "manifest", "inspect", "--insecure", ref],
                         capture_output=True, text=True, check=True).stdout
    data = json.loads(out)
    return sorted(m["platform"]["architecture"] for m in data.get("manifests", []))


def index_architectures(registry: str, name: str, tag: str,
                        auth: Optional[Mapping[str, str]] = None) -> List[str]:
    """Architectures of a manifest list (or OCI index) in a loopback registry that may require
    a login (empty: not a list); attestation entries (`unknown`) left out."""
    accept = ("application/vnd.docker.distribution.manifest.list.v2+json,"
              "application/vnd.oci.image.index.v1+json")
    data = registry_get(registry, f"{name}/manifests/{tag}", auth, accept)
    return sorted(m["platform"]["architecture"] for m in data.get("manifests", [])
                  if m.get("platform", {}).get("architecture") != "unknown")


def push_private_base_image(source: str, registry: AuthRegistry, repository: str) -> str:
    """source pushed to an authenticated registry as repository:bookworm (a name of the test
    module's: the run's modules share the registry), a name no local image has: a job that
    builds FROM it must log in and pull it."""
    ref = f"{registry.address}/{repository}:bookworm"
    client = docker.from_env()
    client.images.get(source).tag(ref)
    for event in client.images.push(ref, auth_config=registry.auth, stream=True, decode=True):
        assert "error" not in event, event
    forget_local(ref)
    return ref


def forget_local(ref: str) -> None:
    """Untag ref locally (the layers stay, they are the source's)."""
    with contextlib.suppress(docker.errors.NotFound):
        docker.from_env().images.remove(ref)


def assert_pulled_image_runs(ref: str, auth: Optional[Mapping[str, str]] = None) -> None:
    """Pull ref afresh from the registry and run it until the example's listener hears."""
    remove_image(ref)
    repository, tag = ref.rsplit(":", 1)
    docker.from_env().images.pull(repository, tag=tag, auth_config=dict(auth) if auth else None)
    try:
        out = run_until(ref, HEARD, 90)
        assert HEARD in out, out[-3000:]
    finally:
        remove_image(ref)


def assert_sources_hold_no_secret(ref: str, secrets: List[str],
                                  auth: Optional[Mapping[str, str]] = None) -> None:
    """The dev image ref (pulled afresh) has the repository's sources but no file that holds
    one of secrets (given to grep on standard input, never on a command line), and no `.git`.
    A control text that the sources hold proves the search reads them."""
    remove_image(ref)
    repository, tag = ref.rsplit(":", 1)
    docker.from_env().images.pull(repository, tag=tag, auth_config=dict(auth) if auth else None)
    try:
        found = subprocess.run(
            ["docker", "run", "--rm", "-i", "--entrypoint", "sh", ref, "-c",
             "ls -A /docker-ros/ws/src/target; echo ---; "
             "grep -rhoF -f /dev/stdin /docker-ros/ws/src/target | sort -u"],
            input="".join(s + "\n" for s in [*secrets, SOURCES_CONTROL]), capture_output=True,
            text=True, timeout=120)
    finally:
        remove_image(ref)
    listed, _, matched = found.stdout.partition("---")
    assert "docker_ros_example" in listed.split(), found.stdout + found.stderr
    assert ".git" not in listed.split(), listed
    assert matched.split() == [SOURCES_CONTROL], (matched, found.stderr)


SOURCES_CONTROL = "<name>docker_ros_example</name>"  # in the example's package.xml


def include_gitlab_template(repo: Path, variables: Dict[str, str]) -> None:
    """Commit a .gitlab-ci.yml that includes our template, with these pipeline variables."""
    (repo / ".gitlab-ci").mkdir()
    shutil.copy(REPO / ".gitlab-ci" / "docker-ros.yml", repo / ".gitlab-ci" / "docker-ros.yml")
    (repo / ".gitlab-ci.yml").write_text(
        "include:\n  - local: .gitlab-ci/docker-ros.yml\n\n"
        # A shell runner ignores services; gitlab-ci-local would try to pull docker:dind.
        "default:\n  services: []\n\n"
        "variables:\n" + "".join(f"  {k}: '{v}'\n" for k, v in variables.items())
    )
    git(repo, "add", "-A")
    git(repo, "commit", "-qm", "ci")


def gitlab_ci_local(repo: Path, variables: Dict[str, str], *jobs: str,
                    secrets: Optional[Dict[str, str]] = None,
                    env: Optional[Dict[str, str]] = None) -> subprocess.CompletedProcess:
    """The whole pipeline (or these jobs), every job through the shell executor (the
    template's docker:dind image cannot be pulled here; a shell runner is a supported way to
    run it). secrets come from the project variables file, as from GitLab's settings: no
    command line holds them (gitlab-ci-local 4.70 reads that file only from the working
    directory, and makes a file variable of a value that names an existing path)."""
    executable = shutil.which("gitlab-ci-local")
    if executable is None:
        pytest.fail("gitlab-ci-local (npm) is not installed; run `bash scripts/setup.sh` first")
    if secrets:
        secrets_file = repo / ".gitlab-ci-local-variables.yml"
        secrets_file.write_text(yaml.safe_dump(secrets))
        with (repo / ".git" / "info" / "exclude").open("a") as exclude:
            exclude.write(f"/{secrets_file.name}\n")
    argv = [executable, "--force-shell-executor", "--no-color",
            "--ignore-predefined-vars", "GITLAB_CI", *jobs]
    for key, value in variables.items():
        argv += ["--variable", f"{key}={value}"]
    if env is None:
        env = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    return subprocess.run(argv, cwd=repo, env=env, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, timeout=1800)


def docker_recorder(root: Path) -> Tuple[Path, Path, Path]:
    """A DOCKER_CONFIG of the test's own (with the user's CLI plugins such as buildx) and a
    folder to put first on PATH whose `docker` writes each command line to a file, then runs
    the real docker: what a leaked secret on a command line would show. Returns the config
    folder, the command-line file and the PATH folder."""
    real = shutil.which("docker")
    assert real, "docker CLI not found"
    config, shim = root / "docker-config", root / "docker-shim"
    config.mkdir()
    shim.mkdir()
    plugins = Path(os.environ.get("DOCKER_CONFIG", Path.home() / ".docker")) / "cli-plugins"
    if plugins.is_dir():
        (config / "cli-plugins").symlink_to(plugins)
    argv_log = root / "docker-argv.log"
    argv_log.touch()
    (shim / "docker").write_text(f"#!/bin/sh\nprintf '%s\\n' \"$*\" >> '{argv_log}'\n"
                                 f"exec '{real}' \"$@\"\n")
    (shim / "docker").chmod(0o755)
    return config, argv_log, shim


def registry_digest(registry: str, name: str, tag: str,
                    auth: Optional[Mapping[str, str]] = None) -> str:
    """The digest a loopback registry serves name:tag under (its Docker-Content-Digest)."""
    accept = ", ".join(("application/vnd.docker.distribution.manifest.v2+json",
                        "application/vnd.docker.distribution.manifest.list.v2+json",
                        "application/vnd.oci.image.manifest.v1+json",
                        "application/vnd.oci.image.index.v1+json"))
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    request = urllib.request.Request(f"http://{registry}/v2/{name}/manifests/{tag}",
                                     method="HEAD", headers={"Accept": accept})
    if auth:
        pair = f"{auth['username']}:{auth['password']}".encode()
        request.add_header("Authorization", "Basic " + base64.b64encode(pair).decode())
    with opener.open(request, timeout=10) as answer:
        return str(answer.headers.get("Docker-Content-Digest", ""))
