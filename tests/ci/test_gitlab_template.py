"""The GitLab CI template run for real: gitlab-ci-local executes its jobs with the shell executor
on a copy of example/ (a git repository with an origin), pushing to a local registry."""

from __future__ import annotations

import pytest

from tests.ci.cihelp import (
    REPO,
    assert_pulled_image_runs,
    example_repository,
    git,
    gitlab_ci_local,
    include_gitlab_template,
    manifest_architectures,
    registry_tags,
)

pytestmark = pytest.mark.docker

IMAGE = "docker-ros-test/ci-gitlab"
FEATURE = "Feature/GitLab_Test"


@pytest.fixture(scope="module")
def pipelines(ros1_base_image: str, local_registry: str,
              tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The template included by a repository; one pipeline on a feature branch, one on main."""
    repo = example_repository(tmp_path_factory.mktemp("gitlab"), ros1_base_image)
    include_gitlab_template(repo, {"TARGET": "dev,run", "ENABLE_SLIM": "false",
                                   "ENABLE_INDUSTRIAL_CI": "false"})
    variables = {
        "GITLAB_CI": "true",  # gitlab-ci-local says false; GitLab says true
        "IMAGE_NAME": f"{local_registry}/{IMAGE}",
        "DOCKER_ROS_PIP_SPEC": str(REPO),
    }
    results = {}
    git(repo, "checkout", "-q", "-b", FEATURE)
    results["feature"] = gitlab_ci_local(repo, variables)
    git(repo, "checkout", "-q", "main")
    # On main, as docker-ros's defaults: tests and the slim image (pipeline variables beat the
    # file's, as in GitLab).
    results["main"] = gitlab_ci_local(repo, {**variables, "ENABLE_SLIM": "true",
                                             "ENABLE_INDUSTRIAL_CI": "true"})
    return {"registry": local_registry, **results}


def test_pipelines_pass(pipelines: dict) -> None:
    for branch in ("feature", "main"):
        result = pipelines[branch]
        assert result.returncode == 0, result.stdout[-6000:]
        assert "PASS  build-amd64" in result.stdout and "PASS  manifest" in result.stdout
        assert "build-arm64" not in result.stdout  # PLATFORM=amd64: no arm64 job


def test_feature_branch_and_main_push_docker_ros_tags(pipelines: dict) -> None:
    assert registry_tags(pipelines["registry"], IMAGE) == [
        "latest", "latest-amd64", "latest-build-state-amd64", "latest-dev", "latest-dev-amd64",
        "latest-dev_feature-gitlab-test_ci", "latest-dev_feature-gitlab-test_ci-amd64",
        "latest-slim", "latest-slim-amd64",
        "latest_feature-gitlab-test_ci", "latest_feature-gitlab-test_ci-amd64",
        "latest_feature-gitlab-test_ci-build-state-amd64",
    ]
    assert manifest_architectures(f"{pipelines['registry']}/{IMAGE}:latest") == ["amd64"]


def test_secrets_and_setup_stay_out_of_the_log(pipelines: dict) -> None:
    log = pipelines["main"].stdout
    for task in ("build", "test", "slim", "push"):
        assert f"docker-ros ci: docker-ros {task}" in log, task
    assert "docker-ros test (amd64): " in log
    assert "--password" not in log.replace("--password-stdin", "")


def test_pushed_run_image_runs(pipelines: dict) -> None:
    ref = f"{pipelines['registry']}/{IMAGE}:latest_feature-gitlab-test_ci"
    assert_pulled_image_runs(ref)


def test_pushed_slim_image_runs(pipelines: dict) -> None:
    assert_pulled_image_runs(f"{pipelines['registry']}/{IMAGE}:latest-slim")
