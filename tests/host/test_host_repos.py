"""Real repositories on the host (issue 11): blacklisted packages hidden from colcon in the
image's copy only, no rosdep key for them, the repository's own rosdep rules in a database of
the workspace (never /etc), dry runs that resolve, hooks that know where they run."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.rosfixtures import make_blacklist_repo, make_package, tree_snapshot

pytestmark = pytest.mark.host
SRC = Path(__file__).resolve().parents[2] / "src"
RULES = "my_tool:\n  debian: [jq]\n  ubuntu: [jq]\n"

STEPS = "docker_ros.in_image.steps"


def run(args: list, cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    full.update({"PYTHONPATH": str(SRC), **(env or {})})
    return subprocess.run([sys.executable, "-m", *args], cwd=cwd, env=full,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    repo = make_blacklist_repo(tmp_path / "repo", RULES)
    (repo / ".env").write_text(f"WORKSPACE={tmp_path / 'ws'}\n")
    return repo


@pytest.fixture
def no_rosdep_database(tmp_path: Path) -> dict:
    """rosdep as on a machine where `rosdep init` never ran (nothing in /etc, no cache)."""
    assert not Path("/etc/ros/rosdep").exists(), "this machine has a system rosdep database"
    empty = tmp_path / "no-sources"
    empty.mkdir()
    return {"ROSDEP_SOURCE_PATH": str(empty), "ROS_HOME": str(tmp_path / "ros-home")}


def test_blacklisted_packages_get_colcon_ignore_in_the_image_copy_only(repo: Path,
                                                                       tmp_path: Path) -> None:
    before = tree_snapshot(repo)
    assert run(["docker_ros", "blacklist"], repo).returncode == 0
    assert tree_snapshot(repo) == before  # the host task never marks the user's repository
    image_ws = tmp_path / "image-ws"  # the image's copy: src/target is a real folder
    shutil.copytree(repo, image_ws / "src" / "target")
    proc = run([STEPS, "blacklist", "--workspace", str(image_ws), "--mark-ignored"],
               repo)
    assert proc.returncode == 0, proc.stderr
    assert (image_ws / "src" / "target" / "unwanted" / "COLCON_IGNORE").is_file()
    listed = subprocess.run(["colcon", "list", "--names-only", "--base-paths", "src"],
                            cwd=image_ws, capture_output=True, text=True, check=True)
    assert listed.stdout.split() == ["app", "meta"]


def test_dry_run_without_database_resolves_with_the_repository_rules(
    repo: Path, no_rosdep_database: dict
) -> None:
    proc = run(["docker_ros", "rosdep", "--dry-run"], repo, env=no_rosdep_database)
    assert proc.returncode == 0, proc.stderr
    assert "rosdep: my_tool -> apt: jq" in proc.stderr
    assert ("rosdep: meta depends on the blacklisted package unwanted: not installed, not "
            "built") in proc.stderr
    assert "unwanted ->" not in proc.stderr  # no rosdep key for a blacklisted package
    assert not Path(no_rosdep_database["ROS_HOME"]).exists()

    # No rules of the repository's either: a real run would make rosdep's database first
    # (`rosdep init`, with sudo when not root, then `rosdep update`); the dry run says so.
    (repo / "docker" / "rosdep.yaml").unlink()
    plain = run(["docker_ros", "rosdep", "--dry-run"], repo, env=no_rosdep_database)
    assert plain.returncode == 0, plain.stderr
    init = "rosdep init" if os.geteuid() == 0 else "sudo rosdep init"
    said = plain.stdout + plain.stderr
    shown = [line for line in said.splitlines() if line.startswith("[dry-run]")]
    assert shown[1:5] == [f"[dry-run] rosdep: {init}", "[dry-run] rosdep: rosdep update",
                         "[dry-run] rosdep: resolve 1 key in the database those commands make",
                         "[dry-run] rosdep: install the resolved 'all' dependencies"], said
    assert "my_tool ->" not in said
    assert "no apt packages to install" not in said  # nothing was resolved: unknown, not none
    assert not Path(no_rosdep_database["ROS_HOME"]).exists()
    assert not any(Path(no_rosdep_database["ROSDEP_SOURCE_PATH"]).iterdir())


def test_own_rules_live_in_the_workspace_with_the_base_rules_it_reaches(
    repo: Path, tmp_path: Path, no_rosdep_database: dict
) -> None:
    base = tmp_path / "base-rules"
    base.mkdir()
    (base / "rules.yaml").write_text("base_key:\n  debian: [tree]\n  ubuntu: [tree]\n")
    sources = Path(no_rosdep_database["ROSDEP_SOURCE_PATH"])
    (sources / "10-base.list").write_text(f"yaml {(base / 'rules.yaml').as_uri()}\n")
    (sources / "20-gone.list").write_text("yaml http://127.0.0.1:9/gone.yaml\n")
    make_package(repo / "other", "other", depends=["base_key"])
    ws = tmp_path / "ws"
    (ws / "src").mkdir(parents=True)
    (ws / "src" / "target").symlink_to(repo)
    proc = run([STEPS, "rosdep", "--workspace", str(ws), "--phase", "collect"],
               repo, env={**no_rosdep_database, "ROSDISTRO_INDEX_URL": "file:///nonexistent"})
    assert proc.returncode == 0, proc.stderr
    assert "rules source not reachable, its keys stay unresolved: http://127.0.0.1:9/gone" in (
        proc.stderr)
    plan = (ws / ".docker-ros" / "rosdep.json").read_text()
    assert '"jq"' in plan and '"tree"' in plan
    assert (ws / ".docker-ros" / "rosdep" / "home" / "rosdep" / "sources.cache").is_dir()
    assert sorted(sources.iterdir()) == [sources / "10-base.list", sources / "20-gone.list"]
    assert not Path(no_rosdep_database["ROS_HOME"]).exists()
    assert not Path("/etc/ros/rosdep").exists()
    again = run([STEPS, "rosdep", "--workspace", str(ws), "--phase", "collect"],
                repo, env=no_rosdep_database)
    assert again.returncode == 0 and "rosdep update" not in again.stderr  # inputs unchanged


def test_a_ros_distro_the_unreachable_index_cannot_name_still_resolves(
    repo: Path, tmp_path: Path, no_rosdep_database: dict
) -> None:
    """ROS_DISTRO set (e.g. jazzy) on a machine or base without the rosdistro index: the
    update without the index drops --rosdistro (an empty index knows no distribution) and
    the rules files resolve."""
    ws = tmp_path / "ws"
    (ws / "src").mkdir(parents=True)
    (ws / "src" / "target").symlink_to(repo)
    env = {**no_rosdep_database, "ROSDISTRO_INDEX_URL": "file:///nonexistent",
           "ROS_DISTRO": "jazzy"}
    proc = run([STEPS, "rosdep", "--workspace", str(ws), "--phase", "collect"], repo, env=env)
    assert proc.returncode == 0, proc.stderr
    assert "trying without the rosdistro index" in proc.stderr
    assert '"jq"' in (ws / ".docker-ros" / "rosdep.json").read_text()


def test_hooks_know_where_they_run(repo: Path, tmp_path: Path) -> None:
    seen = tmp_path / "seen.txt"
    for hook in ("before_dependency_identification.sh", "before_dependency_installation.sh",
                 "custom.sh"):
        (repo / "docker" / hook).write_text(
            f'echo "{hook} $DOCKER_ROS_CONTEXT $PWD" >> {seen}\n')
    for step in ("clone", "scripts", "custom"):
        proc = run(["docker_ros", step], repo)
        assert proc.returncode == 0, proc.stderr
    ws = tmp_path / "ws"  # every hook: the workspace root (docker-ros's WORKDIR, as in images)
    assert seen.read_text().splitlines() == [
        f"before_dependency_identification.sh host {ws}",
        f"before_dependency_installation.sh host {ws}",
        f"custom.sh host {ws}",
    ]


def test_rules_file_overriding_a_base_key_is_named_once(
    repo: Path, tmp_path: Path, no_rosdep_database: dict
) -> None:
    base = tmp_path / "base-rules"
    base.mkdir()
    (base / "rules.yaml").write_text(
        "my_tool:\n  debian: [jq, jq-extra]\n  ubuntu: [jq, jq-extra]\n"
        "unused:\n  debian: [tree]\n")
    sources = Path(no_rosdep_database["ROSDEP_SOURCE_PATH"])
    (sources / "10-base.list").write_text(f"yaml {(base / 'rules.yaml').as_uri()}\n")
    ws = tmp_path / "ws"
    (ws / "src").mkdir(parents=True)
    (ws / "src" / "target").symlink_to(repo)
    env = {**no_rosdep_database, "ROSDISTRO_INDEX_URL": "file:///nonexistent",
           "ROS_OS_OVERRIDE": "debian:bookworm"}
    proc = run([STEPS, "rosdep", "--workspace", str(ws), "--phase", "collect"],
               repo, env=env)
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if "overrides" in line]
    assert len(lines) == 1, proc.stderr
    assert lines[0].endswith(
        f"rosdep: ROSDEP_RULES_FILE docker/rosdep.yaml overrides 'my_tool' of the base's rules "
        f"({(base / 'rules.yaml').as_uri()}): the base has debian: [jq, jq-extra], "
        "docker/rosdep.yaml has debian: [jq]")


BAD_RULES = "my_tool:\n  debian: [jq\nother:\n  debian: [tree]\n"
BAD_LINE = ("ROSDEP_RULES_FILE docker/rosdep.yaml:3:6: not valid YAML: expected ',' or ']', but "
            "got ':' (while parsing a flow sequence at line 2): fix the file (rosdep would skip "
            "all of its rules)")


def test_malformed_rules_file_stops_before_anything_runs(
    repo: Path, tmp_path: Path, no_rosdep_database: dict
) -> None:
    (repo / "docker" / "rosdep.yaml").write_text(BAD_RULES)
    # the image's entry (the resolve stage runs it): the step itself
    ws = tmp_path / "image-ws"
    shutil.copytree(repo, ws / "src" / "target")
    step = run([STEPS, "rosdep", "--workspace", str(ws), "--phase", "collect"],
               repo, env=no_rosdep_database)
    assert step.returncode == 1
    assert step.stderr.strip().splitlines()[-1] == f"docker-ros rosdep: {BAD_LINE}"
    assert "rosdep update" not in step.stderr
    # the host tasks, and an image build, check it before anything runs
    for args in (["rosdep"], ["build", "--base-image", "docker-ros-test-h2:none"]):
        proc = run(["docker_ros", *args], repo, env={**no_rosdep_database, "COMMAND": "true"})
        assert proc.returncode != 0
        last = proc.stderr.strip().splitlines()[-2:]
        assert last[0].endswith(f"{args[0]}: invalid configuration:"), proc.stderr
        assert last[1] == f"  {BAD_LINE}"
        assert "Starting >>>" not in proc.stderr and "docker" not in proc.stdout
