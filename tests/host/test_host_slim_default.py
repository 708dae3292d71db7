"""Where slimming applies (issue 19): a local `build` slims only when asked; CI, `push` and `ci`
keep docker-ros's default; `config` says which applies and why. Dry runs print the plan the
real commands follow (`[dry-run] slim: ...` exactly when the run image would be slimmed)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Dict, Optional

import pytest

from tests.rosfixtures import make_package

pytestmark = pytest.mark.host

CI_VARIABLES = ("GITHUB_ACTIONS", "GITLAB_CI", "ENABLE_SLIM", "TARGET", "COMMAND", "IMAGE")
SLIMS = "[dry-run] slim: trace"


def cli(project: Path, *args: str, env: Optional[Dict[str, str]] = None, inv: bool = False
        ) -> subprocess.CompletedProcess:
    """`docker-ros ARGS` (or `inv ARGS`) in project, outside any CI."""
    clean = {k: v for k, v in os.environ.items() if k not in CI_VARIABLES}
    program = ([shutil.which("inv", path=os.path.dirname(sys.executable)) or "inv"] if inv
               else [sys.executable, "-m", "docker_ros"])
    return subprocess.run([*program, *args], cwd=project, env={**clean, **(env or {})},
                          capture_output=True, text=True, timeout=120)


@pytest.fixture
def project(tmp_path: Path) -> Path:
    (tmp_path / ".env").write_text("BASE_IMAGE=docker-ros-test/none:1\nCOMMAND=true\n")
    make_package(tmp_path / "pkg", "pkg")
    return tmp_path


def slims(result: subprocess.CompletedProcess) -> bool:
    assert result.returncode == 0, result.stdout + result.stderr
    return SLIMS in result.stdout


def test_a_local_build_slims_only_when_asked(project: Path) -> None:
    assert not slims(cli(project, "build", "--dry-run"))
    assert slims(cli(project, "build", "--dry-run", "--enable-slim"))
    assert not slims(cli(project, "build", "--dry-run", "--enable-slim=false"))
    assert slims(cli(project, "build", "--dry-run", "--target", "slim"))
    assert slims(cli(project, "build", "--dry-run", env={"ENABLE_SLIM": "true"}))
    # invoke.yaml is read by `inv` (beside the project's tasks.py)
    (project / "tasks.py").write_text("from docker_ros.tasks import ns  # noqa: F401\n")
    (project / "invoke.yaml").write_text("docker_ros:\n  enable_slim: true\n")
    assert slims(cli(project, "build", "--dry-run", inv=True))


def test_ci_and_push_keep_docker_ros_default(project: Path) -> None:
    assert slims(cli(project, "build", "--dry-run", env={"GITHUB_ACTIONS": "true"}))
    assert slims(cli(project, "build", "--dry-run", env={"GITLAB_CI": "true"}))
    # (a name push can push: one without registry or namespace is refused, test_host_bad_input)
    image = "me/slim-default:latest"
    pushed = cli(project, "push", "--dry-run", env={"IMAGE": image})
    assert slims(pushed)
    names = re.findall(r"\[dry-run\] push: docker push (\S+)", pushed.stdout)
    assert sorted(names) == [image, f"{image}-slim"], pushed.stdout
    ci = cli(project, "ci", "--dry-run", env={"IMAGE": image})
    assert ci.returncode == 0, ci.stderr
    assert "docker-ros ci: docker-ros slim --dry-run" in ci.stdout
    # each task's own dry run: the job's image names as push would push them
    assert re.findall(r"\[dry-run\] push: docker push (\S+)", ci.stdout) == names, ci.stdout
    assert not slims(cli(project, "push", "--dry-run", env={"ENABLE_SLIM": "false",
                                                           "IMAGE": image}))


def test_config_says_which_applies_and_why(project: Path) -> None:
    def row(*args: str, env: Optional[Dict[str, str]] = None) -> str:
        shown = cli(project, "config", *args, env=env)
        assert shown.returncode == 0, shown.stderr
        return next(line for line in shown.stdout.splitlines() if line.startswith("ENABLE_SLIM"))

    local = row().split(None, 2)
    assert local[1] == "false" and local[2].startswith("derived: a local build slims only when "
                                                       "asked (ENABLE_SLIM=true, TARGET slim")
    assert row("--set", "TARGET=dev,slim").split(None, 2)[1:] == ["true",
                                                                 "derived from TARGET (flag)"]
    github = row(env={"GITHUB_ACTIONS": "true"}).split(None, 2)
    assert github[1:] == ["true", "derived from the CI pipeline (github): docker-ros's default"]
    assert row(env={"ENABLE_SLIM": "true"}).split()[1:] == ["true", "environment"]


def test_ci_passes_its_flags_on_as_given_and_its_plan_wins(project: Path) -> None:
    """`ci --image-tag v1` on a branch pipeline pushes v1 with the branch's postfix (the tasks
    got the postfixed tag as a flag and dropped it); a flag of the user's never undoes the plan's
    own --set: ENABLE_INDUSTRIAL_CI=true tests once, in the test task, not in the build too."""
    branch = {"GITLAB_CI": "true", "CI_COMMIT_BRANCH": "feature", "CI_DEFAULT_BRANCH": "main",
              "CI_REGISTRY_IMAGE": "reg.example/group/project"}
    ci = cli(project, "ci", "--image-tag", "v1", "--dry-run", env=branch)
    assert ci.returncode == 0, ci.stdout + ci.stderr
    # (run only: no build state, test_a_run_only_ci_job_pushes_no_build_state_...)
    assert re.findall(r"\[dry-run\] push: docker push (\S+)", ci.stdout) == [
        "reg.example/group/project:v1_feature_ci",
        "reg.example/group/project:v1-slim_feature_ci"], ci.stdout
    assert "docker-ros ci: docker-ros build --set IMAGE_TAG=v1 --set ENABLE_SLIM=false" in (
        ci.stdout)
    tested = cli(project, "ci", "--set", "ENABLE_INDUSTRIAL_CI=true", "--dry-run",
                 env={"IMAGE": "me/ci-flags:latest"})
    assert tested.returncode == 0, tested.stdout + tested.stderr
    assert tested.stdout.count("[dry-run] test: would copy the results") == 1, tested.stdout
    assert ("docker-ros ci: docker-ros build --set ENABLE_INDUSTRIAL_CI=true --set "
            "ENABLE_SLIM=false --set ENABLE_INDUSTRIAL_CI=false --dry-run") in tested.stdout


def test_a_run_only_ci_job_pushes_no_build_state_and_no_cache_of_every_stage(
        project: Path) -> None:
    """docker-ros's run-only pipeline pushed the run image only: the build state (the colcon
    build folder) and a registry cache of every stage (the source stages too) go nowhere by
    default, and to BUILD_STATE_REPOSITORY when it names a repository (issue 46)."""
    gitlab = {"GITLAB_CI": "true", "CI_COMMIT_BRANCH": "feature", "CI_DEFAULT_BRANCH": "main",
              "IMAGE_NAME": "registry.example/g/robot", "TARGET": "run"}
    run_only = cli(project, "ci", "--dry-run", env=gitlab)
    assert run_only.returncode == 0, run_only.stdout + run_only.stderr
    pushed = re.findall(r"\[dry-run\] push: docker push (\S+)", run_only.stdout)
    assert pushed == ["registry.example/g/robot:latest_feature_ci",
                      "registry.example/g/robot:latest-slim_feature_ci"], run_only.stdout
    # the run image carries its own inline cache, nothing else is exported
    assert set(re.findall(r"--cache-to (\S+)", run_only.stdout)) == {"type=inline"}
    assert not re.search(r":\S*-cache-", run_only.stdout) and "build-state" not in run_only.stdout
    named = cli(project, "ci", "--dry-run",
                env={**gitlab, "BUILD_STATE_REPOSITORY": "registry.example/g/private"})
    assert named.returncode == 0, named.stdout + named.stderr
    pushed = re.findall(r"\[dry-run\] push: docker push (\S+)", named.stdout)
    assert "registry.example/g/private:latest_feature_ci-build-state-amd64" in pushed
    assert "--cache-from registry.example/g/private:latest_feature_ci-cache-run-amd64" in (
        named.stdout)
    shown = cli(project, "config",
                env={**gitlab, "BUILD_STATE_REPOSITORY": "registry.example/g/private"})
    assert "registry.example/g/private:latest_feature_ci-cache" in shown.stdout, shown.stdout
