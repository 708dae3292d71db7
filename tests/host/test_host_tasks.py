"""The user's commands on the host: `inv`/`docker-ros` tasks, as real subprocesses."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from docker_ros.core.loading import host_platform
from tests.rosfixtures import make_package, tree_snapshot

pytestmark = pytest.mark.host
REPO = Path(__file__).resolve().parents[2]


def cli(project: Path, *args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    full.update(env or {})
    return subprocess.run([sys.executable, "-m", "docker_ros", *args], cwd=project, env=full,
                          capture_output=True, text=True, timeout=600)


def inv(project: Path, *args: str) -> subprocess.CompletedProcess:
    invoke = shutil.which("inv", path=os.path.dirname(sys.executable)) or "inv"
    return subprocess.run([invoke, *args], cwd=project, capture_output=True, text=True)


@pytest.fixture
def project(tmp_path: Path) -> Path:
    repo = tmp_path / "my_repo"
    make_package(repo / "pkg_a", "pkg_a")
    make_package(repo / "pkg_b", "pkg_b", depends=["pkg_a"])
    (repo / "tasks.py").write_text((REPO / "tasks.py").read_text())
    (repo / ".env").write_text(f"WORKSPACE={tmp_path / 'ws'}\nCOMMAND=pkg_b_node && echo done\n")
    return repo


def task_names(listing: str) -> list:
    return sorted(line.split()[0] for line in listing.splitlines() if line.startswith("  "))


def test_inv_and_docker_ros_list_the_same_tasks(project: Path) -> None:
    via_inv, via_cli = inv(project, "--list"), cli(project, "--list")
    assert via_inv.returncode == 0 and via_cli.returncode == 0, via_inv.stderr + via_cli.stderr
    names = task_names(via_inv.stdout)
    for expected in ("clone", "blacklist", "scripts", "rosdep", "debs", "pip", "files",
                     "custom", "colcon", "command", "build", "dev", "run", "config", "dev-shell",
                     "slim"):
        assert expected in names
    assert names == task_names(via_cli.stdout.split("Subcommands:")[-1])


def test_run_host_runs_all_ten_steps_then_command_and_is_idempotent(project: Path) -> None:
    before = tree_snapshot(project)
    first = cli(project, "run", "--host")
    assert first.returncode == 0, first.stderr[-3000:]
    for step in ("clone", "blacklist", "scripts", "rosdep", "debs", "pip", "files", "custom",
                 "colcon", "command"):
        assert f"Starting >>> {step}" in first.stderr
    assert first.stdout.split()[-2:] == ["pkg_b", "done"]
    again = cli(project, "run", "--host")
    assert again.returncode == 0, again.stderr[-3000:]
    assert again.stdout.split()[-2:] == ["pkg_b", "done"]
    assert tree_snapshot(project) == before, "the user's repository was modified"


def test_step_dry_run_changes_nothing(project: Path, tmp_path: Path) -> None:
    before = tree_snapshot(project)
    result = cli(project, "run", "--host", "--dry-run")
    assert result.returncode == 0, result.stderr
    assert "[dry-run] colcon: colcon build" in result.stdout
    assert "[dry-run] command:" in result.stdout
    assert not (tmp_path / "ws").exists()
    assert tree_snapshot(project) == before


def test_invokes_dry_flag_is_our_dry_run_or_refused(project: Path, tmp_path: Path) -> None:
    before = tree_snapshot(project)
    result = cli(project, "-R", "clone")
    assert result.returncode == 0, result.stderr
    assert "[dry-run]" in result.stdout
    assert not (tmp_path / "ws").exists(), "-R ran the step for real"
    assert tree_snapshot(project) == before
    refused = cli(project, "--dry", "config")
    assert refused.returncode != 0
    assert "docker-ros config: has no dry run" in refused.stderr


def test_config_shows_sources_and_masks_secrets(project: Path) -> None:
    (project / "invoke.yaml").write_text("docker_ros:\n  image_tag: from-yaml\n")
    result = inv(project, "config", "--set", "CMAKE_ARGS=-DX=1")
    assert result.returncode == 0, result.stderr
    rows = {line.split()[0]: line.split() for line in result.stdout.splitlines()[1:]}
    assert rows["IMAGE_TAG"][1:] == ["from-yaml", "invoke.yaml"]
    assert rows["CMAKE_ARGS"][1:] == ["-DX=1", "flag"]
    assert rows["COMMAND"][-1] == ".env"
    masked = cli(project, "config", env={"GIT_HTTPS_PASSWORD": "hunter2"})
    assert "hunter2" not in masked.stdout and "****" in masked.stdout


def test_bad_input_is_one_clear_line_and_non_zero(project: Path) -> None:
    result = cli(project, "config", env={"ENABLE_SLIM": "maybe"})
    assert result.returncode != 0
    assert "ENABLE_SLIM='maybe'" in result.stderr and "Traceback" not in result.stderr
    (project / ".env").unlink()
    missing = cli(project, "build", "--target", "dev,run")
    assert missing.returncode != 0
    assert "BASE_IMAGE" in missing.stderr and "COMMAND" in missing.stderr


def test_test_needs_no_command_and_takes_it_as_a_flag(project: Path) -> None:
    """`test` builds the dev stage only: BASE_IMAGE is enough; --command is accepted (the
    dev stage of a build with that COMMAND is reused)."""
    (project / ".env").write_text("BASE_IMAGE=docker-ros-test/ros1:bookworm\n")
    for extra in ((), ("--command", "roslaunch x y")):
        result = cli(project, "test", "--dry-run", *extra)
        assert result.returncode == 0, result.stderr
        assert "[dry-run] test:" in result.stdout


def test_push_dry_run_logs_in_first_password_on_standard_input(project: Path) -> None:
    env = {"REGISTRY": "reg.invalid:5000", "REGISTRY_USER": "me", "REGISTRY_PASSWORD": "hunter2",
           "BASE_IMAGE": "docker-ros-test/ros1:bookworm"}
    # REGISTRY is where to log in; the name says where to push (docker-ros's rule too)
    refused = cli(project, "push", "--dry-run", env=env)
    assert refused.returncode == 1 and "(IMAGE=reg.invalid:5000/my_repo:tag)" in refused.stderr
    env["IMAGE"] = "reg.invalid:5000/my_repo:latest"
    result = cli(project, "push", "--dry-run", env=env)
    assert result.returncode == 0, result.stderr
    first = result.stdout.splitlines()[0]
    assert first.startswith("[dry-run] docker-ros push: docker login --username me "
                            "--password-stdin reg.invalid:5000"), result.stdout
    assert "hunter2" not in result.stdout + result.stderr


def test_build_dry_run_shows_secret_arguments_without_their_values(project: Path) -> None:
    env = {"GIT_HTTPS_PASSWORD": "hunter2", "GIT_HTTPS_SERVER": "git.example.com",
           "GIT_HTTPS_USER": "me", "BASE_IMAGE": "docker-ros-test/ros1:bookworm"}
    result = cli(project, "build", "--dry-run", env=env)
    assert result.returncode == 0, result.stderr
    assert "docker buildx bake" in result.stdout
    secret = '"id=GIT_HTTPS_PASSWORD,env=DOCKER_ROS_SECRET_GIT_HTTPS_PASSWORD"'
    assert secret in result.stdout
    assert "hunter2" not in result.stdout + result.stderr


def test_singlearch_push_names_every_local_image_by_its_architecture(project: Path) -> None:
    """ENABLE_SINGLEARCH_PUSH (GitLab's per-architecture jobs): the build tags `-<arch>` names,
    as docker-ros's CI, and the dev shell runs the image under that name."""
    arch = host_platform()
    env = {"BASE_IMAGE": "docker-ros-test/ros1:bookworm", "IMAGE": "reg.invalid/team/app:v1",
           "ENABLE_SINGLEARCH_PUSH": "true", "TARGET": "dev,run"}
    built = cli(project, "build", "--dry-run", env=env)
    assert built.returncode == 0, built.stderr
    for name in (f"reg.invalid/team/app:v1-dev-{arch}", f"reg.invalid/team/app:v1-{arch}"):
        assert f'"{name}"' in built.stdout, built.stdout[-3000:]
    assert '"reg.invalid/team/app:v1"' not in built.stdout
    shell = cli(project, "dev-shell", "--dry-run", env=env)
    assert shell.returncode == 0, shell.stderr
    assert f" reg.invalid/team/app:v1-dev-{arch} bash" in shell.stdout, shell.stdout


def test_the_dev_shells_dry_run_names_no_file_that_is_gone(project: Path) -> None:
    """With a blacklist the shell gets a colcon defaults file in a temporary folder, removed
    when the dry run ends: its path in the printed `docker run` named nothing."""
    (project / "docker").mkdir(exist_ok=True)
    (project / "docker" / "blacklisted-packages.txt").write_text("other_pkg\n")
    shell = cli(project, "dev-shell", "--dry-run",
                env={"BASE_IMAGE": "docker-ros-test/ros1:bookworm", "DISPLAY": ""})
    assert shell.returncode == 0, shell.stderr
    assert ("-v '<temporary>/colcon-defaults.yaml:/tmp/.docker-ros.colcon-defaults.yaml:ro'"
            in shell.stdout), shell.stdout


def test_slim_asked_for_a_dev_only_build_says_there_is_none(project: Path) -> None:
    """ENABLE_SLIM applies to the run image: asked for with TARGET dev, the build says it
    makes no slim image; left at its default, it says nothing."""
    env = {"BASE_IMAGE": "docker-ros-test/ros1:bookworm", "TARGET": "dev"}
    asked = cli(project, "build", "--enable-slim", "--dry-run", env=env)
    assert asked.returncode == 0, asked.stderr
    assert asked.stdout.startswith(
        "build: ENABLE_SLIM slims the run image, which TARGET dev does not build: no slim "
        "image (add run to TARGET for one)\n"), asked.stdout[:500]
    quiet = cli(project, "build", "--dry-run", env=env)
    assert quiet.returncode == 0 and "ENABLE_SLIM" not in quiet.stdout, quiet.stdout[:500]
