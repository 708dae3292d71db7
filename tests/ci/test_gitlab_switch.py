"""docker-ros-style `.gitlab-ci.yml` files of our own writing, valid with docker-ros v1.9.0's
template, switched by changing the `include:` line only (issue 46), checked with gitlab-ci-local
without building an image: a manual gate on Push, `needs:` on jobs whose work moved, and a
downstream job that uses docker-ros's `_IMAGE_*` names."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Dict, List

import pytest

from tests.ci.cihelp import git, gitlab_ci_local, include_gitlab_template

# docker-ros's pattern for a hand-pushed image: its own Push rules, then `when: manual`
MANUAL_PUSH = """
Push:
  rules:
    - !reference [.push, rules]
    - when: manual
"""
# valid with docker-ros's defaults (ENABLE_SLIM true: Slim run-amd64 ran; industrial_ci on)
NEEDS_MOVED = """
image-check:
  stage: Push Multi-Arch Images
  needs: ["Slim run-amd64", "Test dev-amd64"]
  before_script: []
  after_script: []
  script: [echo checked]
"""
# a job after the pushes that uses docker-ros's names of the images
DOWNSTREAM = """
stages: [Build Images, Test ROS Industrial CI, Slim Images, Push Multi-Arch Images, Deploy]

deploy:
  stage: Deploy
  needs: [Push CI]
  before_script: []
  after_script: []
  script:
    - echo "run image is <${_IMAGE_RUN_CI}>, amd64 <${_IMAGE_RUN_CI_AMD64}>, dev <${_DEV_IMAGE}>"
"""
VARIABLES = {"BASE_IMAGE": "rwthika/ros2:jazzy", "COMMAND": "ros2 run demo_nodes_cpp talker",
             "TARGET": "dev,run", "ENABLE_INDUSTRIAL_CI": "true",
             "IMAGE_NAME": "registry.example/group/robot"}


def pipeline(tmp_path: Path, jobs: str, branch: str = "main") -> Path:
    """A repository on branch whose .gitlab-ci.yml includes our template (as the migration
    notes say), with docker-ros's variables and these jobs of the user's."""
    repo = tmp_path / "repo"
    repo.mkdir()
    git(repo, "init", "-q", "-b", "main")
    include_gitlab_template(repo, VARIABLES)
    with (repo / ".gitlab-ci.yml").open("a") as ci:
        ci.write(jobs)
    git(repo, "add", "-A")
    git(repo, "commit", "-qm", "jobs")
    if branch != "main":
        git(repo, "checkout", "-qb", branch)
    return repo


def listed(repo: Path, *flags: str) -> Dict[str, List[str]]:
    """gitlab-ci-local --list: job name -> [stage, when, allow_failure, needs]."""
    result = gitlab_ci_local(repo, {}, "--list", *flags)
    assert result.returncode == 0, result.stdout
    rows = [re.split(r"\s{2,}", line.strip()) for line in result.stdout.splitlines()]
    header = next(i for i, row in enumerate(rows) if row[:2] == ["name", "description"])
    return {row[0]: row[1:] for row in rows[header + 1:] if row and row[0]}


def test_a_push_gated_by_hand_stays_manual(tmp_path: Path) -> None:
    jobs = listed(pipeline(tmp_path, MANUAL_PUSH))
    assert jobs["Push"][:2] == ["Push Multi-Arch Images", "manual"], jobs
    assert jobs["build-amd64"][1] == "on_success"


def test_needs_on_jobs_whose_work_moved_creates_the_pipeline(tmp_path: Path) -> None:
    repo = pipeline(tmp_path, NEEDS_MOVED)
    jobs = listed(repo)
    for job in ("Slim run-amd64", "Test dev-amd64", "image-check"):
        assert jobs[job][1] == "on_success", jobs
    checked = gitlab_ci_local(repo, {}, "--validate-dependency-chain")
    assert checked.returncode == 0 and "All job dependencies are valid" in checked.stdout, (
        checked.stdout)
    # their jobs run, need no docker service and say where the work ran
    done = gitlab_ci_local(repo, {}, "Slim run-amd64")
    assert done.returncode == 0, done.stdout
    assert ('job "Slim run-amd64" has no work of its own here; it ran in build-amd64 '
            "(ENABLE_SLIM)") in done.stdout


@pytest.mark.parametrize("flags", [[]], ids=["feature-branch"])
def test_a_downstream_job_gets_the_image_names(tmp_path: Path, docker_ros_wheel: Path,
                                               flags: List[str]) -> None:
    """Push CI (a feature branch) writes the dotenv report; the user's job after it reads the
    names. The jobs run as dry runs (invoke's run.dry, INVOKE_RUN_DRY): nothing is pushed."""
    repo = pipeline(tmp_path, DOWNSTREAM, branch="feature/x")
    env = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    result = gitlab_ci_local(repo, {"GITLAB_CI": "true", "INVOKE_RUN_DRY": "1",
                                    "DOCKER_ROS_PIP_SPEC": str(docker_ros_wheel)},
                             "Push CI", "deploy", env=env)
    assert result.returncode == 0, result.stdout[-6000:]
    image = "registry.example/group/robot"
    assert (f"run image is <{image}:latest_feature-x_ci>, amd64 <{image}:latest_feature-x_ci-amd64>"
            f", dev <{image}:latest-dev>") in result.stdout, result.stdout[-3000:]
