"""The GitHub Action run for real as far as this machine allows: github_harness runs
action.yml's steps in order for a push to a feature branch and to the default branch of a copy
of example/, pushing to a local registry."""

from __future__ import annotations

import os
import subprocess

import pytest

from tests.ci.cihelp import (
    REPO,
    assert_pulled_image_runs,
    example_repository,
    git,
    registry_tags,
)
from tests.ci.github_harness import Event, run_action

pytestmark = pytest.mark.docker

IMAGE = "docker-ros-test/ci-github"
FEATURE = "Feature/GitHub_Test"


@pytest.fixture(scope="module")
def runs(ros1_base_image: str, local_registry: str,
         tmp_path_factory: pytest.TempPathFactory) -> dict:
    root = tmp_path_factory.mktemp("github")
    repo = example_repository(root, ros1_base_image)
    git(repo, "push", "-q", "origin", f"main:{FEATURE}")
    inputs = {
        "base-image": ros1_base_image,
        "target": "dev,run",
        "image-name": f"{local_registry}/{IMAGE}",
        "registry": local_registry,
        "registry-user": "",  # the local registry needs no login
        "registry-password": "",
        "enable-slim": "false",
        "enable-industrial-ci": "false",
        "enable-push-as-latest": "true",
    }
    env = {k: v for k, v in os.environ.items()
           if k not in ("TARGET", "COMMAND", "IMAGE") and not k.startswith(("GITHUB_", "CI_"))}
    results = {}
    for key, branch in (("feature", FEATURE), ("main", "main")):
        event = Event(origin=root / "origin.git", repository="Org/Example-Repo", ref_name=branch)
        results[key] = run_action(REPO, inputs, event, root / key, env)
    return {"registry": local_registry, **results}


def test_action_runs_every_step(runs: dict) -> None:
    for key in ("feature", "main"):
        run = runs[key]
        assert run.returncode == 0, run.log[-6000:]
        assert run.skipped == ["Set up QEMU"]  # amd64 on an amd64 runner
        checkout = run.replaced[0]
        assert checkout == {"uses": "actions/checkout@v4",
                            "with": {"submodules": "recursive", "lfs": "true"}}


def test_feature_branch_gets_the_ci_postfix_and_main_also_latest(runs: dict) -> None:
    assert registry_tags(runs["registry"], IMAGE) == [
        "latest", "latest-build-state-amd64", "latest-dev",
        "latest-dev_feature-github-test_ci", "latest_feature-github-test_ci",
        "latest_feature-github-test_ci-build-state-amd64",
    ]


def test_outputs_name_the_pushed_images(runs: dict) -> None:
    name = f"{runs['registry']}/{IMAGE}"
    assert runs["feature"].outputs["docker-ros"] == {
        "images": f"{name}:latest-dev_feature-github-test_ci,{name}:latest_feature-github-test_ci",
        "dev-image": f"{name}:latest-dev_feature-github-test_ci",
        "image": f"{name}:latest_feature-github-test_ci",
        "build-state-image": f"{name}:latest_feature-github-test_ci-build-state-amd64",
    }
    # IMAGE_TAG is latest already: ENABLE_PUSH_AS_LATEST adds no second push of it
    assert runs["main"].outputs["docker-ros"]["images"] == f"{name}:latest-dev,{name}:latest"


def test_token_never_reaches_the_log(runs: dict) -> None:
    """git-https-password defaults to github.token: it goes to the build as a secret only."""
    token = "ghs_harnessTokenNeverLogged0123456789"
    for key in ("feature", "main"):
        assert token not in runs[key].log
    history = subprocess.run(["docker", "history", "--no-trunc",
                              f"{runs['registry']}/{IMAGE}:latest"],
                             capture_output=True, text=True, check=True).stdout
    assert token not in history


def test_pushed_run_image_runs(runs: dict) -> None:
    ref = f"{runs['registry']}/{IMAGE}:latest_feature-github-test_ci"
    assert_pulled_image_runs(ref)
