"""The GitLab CI template run for real: gitlab-ci-local executes its jobs with the shell executor
on a copy of example/ (a git repository with an origin) whose .gitlab-ci.yml is docker-ros's
README example with overrides of docker-ros's job and stage names, pushing to a local registry
that requires a login, FROM a private base image in it."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import time
import uuid
from pathlib import Path
from typing import Callable, Dict

import pytest

from tests.ci.cihelp import (
    EXAMPLE_COMMAND,
    REPO,
    assert_pulled_image_runs,
    assert_sources_hold_no_secret,
    docker_recorder,
    example_repository,
    forget_local,
    git,
    gitlab_ci_local,
    index_architectures,
    push_private_base_image,
    registry_digest,
    registry_tags,
)
from tests.conftest import AuthRegistry, stable_folder

pytestmark = pytest.mark.docker

IMAGE = "docker-ros-test/ci-gitlab"
FEATURE = "Feature/GitLab--Test"
# docker-ros's README example ("Build development and deployment images") with the `include:`
# changed as the migration notes say (local: the template of this checkout), then overrides of
# docker-ros's jobs and stages as users write them.
GITLAB_CI = """\
include:
  - local: .gitlab-ci/docker-ros.yml

variables:
  BASE_IMAGE: {base_image}
  COMMAND: {command}
  TARGET: dev,run

# A shell runner ignores services; gitlab-ci-local would try to pull docker:dind.
default:
  services: []

build-amd64:
  tags: [privileged, amd64, own-runner]
Test dev-amd64:
  variables:
    BEFORE_INIT: echo industrial_ci-only
Slim run-amd64:
  tags: [own-runner]
Push latest:
  tags: [own-runner]
image-check:
  stage: Slim Images
  needs: [build-amd64]
  before_script: []
  script: [echo checked by a job in a docker-ros stage]
"""


def dotenv_reports(repo: Path, since: float) -> Dict[str, str]:
    """The variables of the dotenv reports a pipeline's jobs left (gitlab-ci-local's artifacts;
    an earlier pipeline's are older than since), merged as a later job that needs them all
    reads them (the names are the same in each; the digests each job's own pushes)."""
    found: Dict[str, str] = {}
    artifacts = repo / ".gitlab-ci-local" / "artifacts"
    for report in sorted(artifacts.glob("*/.gitlab-ci-reports/dotenv/docker-ros-images.env")):
        if report.stat().st_mtime >= since:
            found.update(line.split("=", 1) for line in report.read_text().splitlines())
    return found


@pytest.fixture(scope="module")
def pipelines(ros1_base_image: str, auth_registry: AuthRegistry,
              docker_ros_wheel: Path) -> dict:
    """One pipeline on a feature branch, one on main; jobs log in to a registry that requires
    it, build FROM a private image there, and run docker with a recorded command line."""
    root = stable_folder("gitlab-template")  # (the build cache id: see conftest.stable_folder)
    base = push_private_base_image(ros1_base_image, auth_registry, f"{IMAGE}-base")
    repo = example_repository(root, base)
    (repo / ".gitlab-ci").mkdir()
    shutil.copy(REPO / ".gitlab-ci" / "docker-ros.yml", repo / ".gitlab-ci" / "docker-ros.yml")
    (repo / ".gitlab-ci.yml").write_text(GITLAB_CI.format(base_image=base,
                                                          command=EXAMPLE_COMMAND))
    git(repo, "add", "-A")
    git(repo, "commit", "-qm", "ci")
    variables = {
        "GITLAB_CI": "true",  # gitlab-ci-local says false; GitLab says true
        "IMAGE_NAME": f"{auth_registry.address}/{IMAGE}",
        "REGISTRY": auth_registry.address,
        "REGISTRY_USER": auth_registry.user,
        "DOCKER_ROS_PIP_SPEC": str(docker_ros_wheel),
        "ENABLE_SLIM": "false",
        "ENABLE_INDUSTRIAL_CI": "false",
    }
    runner_tmp = root / "runner-tmp"
    runner_tmp.mkdir()
    docker_config, argv_log, shim = docker_recorder(root)
    env = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    env.update({"PATH": f"{shim}{os.pathsep}{env['PATH']}", "DOCKER_CONFIG": str(docker_config),
                "TMPDIR": str(runner_tmp)})
    results, reports = {}, {}
    git(repo, "checkout", "-q", "-b", FEATURE)
    # GIT_HTTPS_PASSWORD: GitLab's job token by default, which gitlab-ci-local does not set
    secrets = {"REGISTRY_PASSWORD": auth_registry.password,
               "GIT_HTTPS_PASSWORD": f"glpat-{uuid.uuid4().hex}"}
    began = time.time()
    results["feature"] = gitlab_ci_local(repo, variables, secrets=secrets, env=env)
    reports["feature"] = dotenv_reports(repo, began)
    git(repo, "checkout", "-q", "main")
    forget_local(base)  # the main pipeline pulls it again
    # On main, as docker-ros's defaults: tests and the slim image.
    began = time.time()
    results["main"] = gitlab_ci_local(repo, {**variables, "ENABLE_SLIM": "true",
                                             "ENABLE_INDUSTRIAL_CI": "true"},
                                     secrets=secrets, env=env)
    reports["main"] = dotenv_reports(repo, began)
    return {"registry": auth_registry, "repo": repo, "env": env, "variables": variables,
            "secrets": secrets, "reports": reports,
            "docker_config": docker_config, "argv_log": argv_log, "runner_tmp": runner_tmp,
            **results}


def test_pipelines_pass(pipelines: dict) -> None:
    for branch in ("feature", "main"):
        result = pipelines[branch]
        assert result.returncode == 0, result.stdout[-6000:]
        # docker-ros's rules: Push CI off the default branch, Push on it
        push = "Push CI" if branch == "feature" else "Push"
        for job in ("build-amd64", push, "image-check"):
            assert f"PASS  {job}" in result.stdout, job
        assert "build-arm64" not in result.stdout  # PLATFORM=amd64: no arm64 job
        assert "docker-ros setup: docker-ros " in result.stdout
    # ENABLE_SLIM on main: docker-ros's Slim job runs (a job may need it), build-amd64 slimmed
    assert ('job "Slim run-amd64" has no work of its own here; it ran in build-amd64 '
            "(ENABLE_SLIM)") in pipelines["main"].stdout
    assert "Slim run-amd64" not in pipelines["feature"].stdout  # ENABLE_SLIM=false there


def test_the_job_pushes_the_images_it_built_and_tested(pipelines: dict) -> None:
    """build-amd64's push builds and slims nothing again: on this engine (the classic store,
    inline cache) a rebuild had new image ids, and slim ran a second time."""
    log = pipelines["main"].stdout
    push = log.split("docker-ros ci: docker-ros push", 1)[1]
    assert "dev, run, build-state: up to date, built from these same inputs" in push, push[:3000]
    assert "is up to date (made from" in push
    assert log.count("==> docker-ros slim ") == 1


def test_feature_branch_and_main_push_docker_ros_tags(pipelines: dict) -> None:
    auth = pipelines["registry"]
    assert registry_tags(auth.address, IMAGE, auth.auth) == [
        "latest", "latest-amd64", "latest-build-state-amd64", "latest-dev", "latest-dev-amd64",
        "latest-dev_feature-gitlab--test_ci", "latest-dev_feature-gitlab--test_ci-amd64",
        "latest-slim", "latest-slim-amd64",
        "latest_feature-gitlab--test_ci", "latest_feature-gitlab--test_ci-amd64",
        "latest_feature-gitlab--test_ci-build-state-amd64",
    ]
    assert index_architectures(auth.address, IMAGE, "latest", auth.auth) == ["amd64"]


def test_the_pushing_jobs_dotenv_reports_give_the_digests(pipelines: dict) -> None:
    """The jobs that push give each pushed name's registry digest in their dotenv report:
    build-amd64 those of its `-amd64` images and its build state, Push those of the manifest
    lists, each the digest the registry serves the name under."""
    auth = pipelines["registry"]
    name = f"{auth.address}/{IMAGE}"

    def served(tag: str) -> str:
        digest = registry_digest(auth.address, IMAGE, tag, auth.auth)
        assert re.fullmatch(r"sha256:[0-9a-f]{64}", digest), (tag, digest)
        return digest

    main = pipelines["reports"]["main"]
    assert main["_IMAGE_RUN_CI"] == f"{name}:latest"
    for kind, tag in (("RUN", "latest"), ("DEV", "latest-dev"), ("SLIM", "latest-slim")):
        assert main[f"_IMAGE_{kind}_CI_AMD64_DIGEST"] == served(f"{tag}-amd64"), kind
        assert main[f"_IMAGE_{kind}_CI_DIGEST"] == main[f"_{kind}_IMAGE_DIGEST"] == served(tag)
    assert main["_IMAGE_BUILD_STATE_CI_AMD64"] == f"{name}:latest-build-state-amd64"
    assert main["_IMAGE_BUILD_STATE_CI_AMD64_DIGEST"] == served("latest-build-state-amd64")
    assert "_IMAGE_RUN_CI_ARM64_DIGEST" not in main  # (no arm64 job)
    feature = pipelines["reports"]["feature"]
    assert feature["_IMAGE_RUN_CI_DIGEST"] == served("latest_feature-gitlab--test_ci")
    assert feature["_IMAGE_DEV_CI_AMD64_DIGEST"] == served(
        "latest-dev_feature-gitlab--test_ci-amd64")
    assert feature["_IMAGE_BUILD_STATE_CI_AMD64_DIGEST"] == served(
        "latest_feature-gitlab--test_ci-build-state-amd64")
    assert "_RUN_IMAGE_DIGEST" not in feature  # (`latest` is main's: not pushed here)


def test_secrets_and_setup_stay_out_of_the_log(pipelines: dict) -> None:
    """Each job logs in first, password on standard input; the password and the git token
    are in no log and no docker command line; no credential is left behind."""
    auth = pipelines["registry"]
    token = pipelines["secrets"]["GIT_HTTPS_PASSWORD"]
    log = pipelines["main"].stdout
    for task in ("build", "test", "slim", "push"):
        assert f"docker-ros ci: docker-ros {task}" in log, task
    assert "docker-ros test (amd64): " in log
    for branch in ("feature", "main"):
        out = pipelines[branch].stdout
        assert auth.password not in out and token not in out
        assert f"docker-ros ci: logged in to {auth.address} as {auth.user}" in out
        assert f"docker-ros manifest: logged in to {auth.address} as {auth.user}" in out
        # once per job: the tasks `ci` runs use its login
        assert out.count(f"logged in to {auth.address}") == 2, out[-6000:]
    argvs = pipelines["argv_log"].read_text()
    assert f"login --username {auth.user} --password-stdin {auth.address}" in argvs
    assert "buildx build" in argvs or "buildx bake" in argvs
    assert auth.password not in argvs and token not in argvs
    # the DOCKER_CONFIG of the runner holds no login; the jobs' folders are gone
    config = pipelines["docker_config"] / "config.json"
    assert auth.address not in (config.read_text() if config.exists() else "")
    assert list(pipelines["runner_tmp"].iterdir()) == []


def test_test_results_are_the_build_job_s_artifact(pipelines: dict) -> None:
    """The tests write outside the checkout (the build context stays as it is); after_script
    copies their results into it, where `artifacts:` (and `reports: junit`) collect them."""
    main, feature = pipelines["main"].stdout, pipelines["feature"].stdout
    assert "docker-ros: test results in the job's artifact docker-ros-test-results/" in main
    assert "docker-ros: no test results (ENABLE_INDUSTRIAL_CI is not true)" in feature
    collected = pipelines["repo"] / ".gitlab-ci-local" / "artifacts" / "build-amd64"
    assert (collected / "docker-ros-test-results" / "outcome.json").is_file(), \
        sorted(str(p) for p in collected.rglob("*"))[:20]


def test_pushed_run_image_runs(pipelines: dict) -> None:
    ref = f"{pipelines['registry'].address}/{IMAGE}:latest_feature-gitlab--test_ci"
    assert_pulled_image_runs(ref, pipelines["registry"].auth)


def test_pushed_dev_image_holds_no_credential(pipelines: dict) -> None:
    """gitlab-ci-local's variables file (REGISTRY_PASSWORD, GIT_HTTPS_PASSWORD) and git's
    folder of the checkout stay out of the dev image's sources."""
    auth = pipelines["registry"]
    secrets = list(pipelines["secrets"].values())
    variables = (pipelines["repo"] / ".gitlab-ci-local-variables.yml").read_text()
    assert all(secret in variables for secret in secrets)
    assert_sources_hold_no_secret(f"{auth.address}/{IMAGE}:latest-dev", secrets, auth.auth)


def test_pushed_slim_image_runs(pipelines: dict) -> None:
    assert_pulled_image_runs(f"{pipelines['registry'].address}/{IMAGE}:latest-slim",
                             pipelines["registry"].auth)


def jobs_of(pipelines: dict, edit: Callable[[str], str], *jobs: str
            ) -> subprocess.CompletedProcess:
    """The jobs, run by gitlab-ci-local with the pipelines' .gitlab-ci.yml as edit makes it
    (restored afterwards)."""
    ci = pipelines["repo"] / ".gitlab-ci.yml"
    original = ci.read_text()
    try:
        ci.write_text(edit(original))
        return gitlab_ci_local(pipelines["repo"], pipelines["variables"], *jobs,
                               secrets=pipelines["secrets"], env=pipelines["env"])
    finally:
        ci.write_text(original)


def test_a_moved_job_made_to_run_says_where_its_work_is(pipelines: dict) -> None:
    """An override that gives docker-ros's `Slim run-amd64` rules of its own: that job passes
    with one line naming the job that slims now (no docker service, no checkout)."""
    result = jobs_of(pipelines, lambda ci: ci.replace(
        "Slim run-amd64:\n", "Slim run-amd64:\n  rules:\n    - when: always\n"), "Slim run-amd64")
    assert result.returncode == 0, result.stdout[-3000:]
    assert ('docker-ros: job "Slim run-amd64" has no work of its own here; it ran in build-amd64 '
            "(ENABLE_SLIM)" in result.stdout), result.stdout[-3000:]


def test_own_jobs_on_docker_ros_hidden_jobs_fail_saying_why(pipelines: dict) -> None:
    """A job of the user's that extends docker-ros's .test (which ran industrial_ci on its
    DOCKER_IMAGE) never ran without a word; one that extends .push with IMG_RUN (pushed there
    in docker-ros) pushed docker-ros's names only. Both fail now, saying what to do."""
    own = ("My tests:\n  extends: .test\n  variables:\n    DOCKER_IMAGE: my/image:1\n"
           "My push:\n  extends: .push\n  needs: []\n  rules:\n    - when: always\n"
           "  variables:\n    IMG_RUN: my/image:stable\n")
    result = jobs_of(pipelines, lambda ci: ci + own, "My tests", "My push")
    assert result.returncode != 0
    assert ('docker-ros: job "My tests" extends a docker-ros job whose script no longer exists: '
            'its work runs in build-<arch> (ENABLE_INDUSTRIAL_CI); move your settings of "My '
            'tests" there, or remove the job' in result.stdout), result.stdout[-3000:]
    assert ('docker-ros: job "My push" sets IMG_RUN, which docker-ros\'s .push pushed to; here '
            '`docker-ros manifest` pushes docker-ros\'s names and reads no IMG_*' in
            result.stdout), result.stdout[-3000:]
    assert "manifest: docker buildx imagetools create" not in result.stdout  # (it stopped first)
