"""Shared by the CI integration tests: a small ROS repository under git with an origin, and
what a registry holds."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import urllib.request
from pathlib import Path
from typing import Dict, List

import pytest

from tests.docker.buildhelp import EXAMPLE, remove_image, run_until, write_env

REPO = Path(__file__).resolve().parents[2]
EXAMPLE_COMMAND = "roslaunch docker_ros_example talker_listener.launch"
HEARD = "I heard: hello from docker-ros"


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


def registry_tags(registry: str, name: str) -> List[str]:
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    try:
        with opener.open(f"http://{registry}/v2/{name}/tags/list", timeout=10) as answer:
            return sorted(json.load(answer).get("tags") or [])
    except OSError:
        return []


def manifest_architectures(ref: str) -> List[str]:
    """Architectures of a manifest list in a loopback registry (empty: not a list)."""
    out = subprocess.run(["docker", "manifest", "inspect", "--insecure", ref],
                         capture_output=True, text=True, check=True).stdout
    data = json.loads(out)
    return sorted(m["platform"]["architecture"] for m in data.get("manifests", []))


def assert_pulled_image_runs(ref: str) -> None:
    """Pull ref afresh from the registry and run it until the example's listener hears."""
    remove_image(ref)
    subprocess.run(["docker", "pull", "-q", ref], check=True, capture_output=True)
    try:
        out = run_until(ref, HEARD, 90)
        assert HEARD in out, out[-3000:]
    finally:
        remove_image(ref)


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


def gitlab_ci_local(repo: Path, variables: Dict[str, str]) -> subprocess.CompletedProcess:
    """The whole pipeline, every job through the shell executor (the template's docker:dind
    image cannot be pulled here; a shell runner is a supported way to run it)."""
    executable = shutil.which("gitlab-ci-local")
    if executable is None:
        pytest.fail("gitlab-ci-local (npm) is not installed; run `bash scripts/setup.sh` first")
    argv = [executable, "--force-shell-executor", "--no-color",
            "--ignore-predefined-vars", "GITLAB_CI"]
    for key, value in variables.items():
        argv += ["--variable", f"{key}={value}"]
    env = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    return subprocess.run(argv, cwd=repo, env=env, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, timeout=1800)
