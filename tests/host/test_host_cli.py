"""`python3 -m docker_ros.in_image.steps`: the entry the Dockerfile uses (real subprocesses)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from docker_ros.in_image.runtime.workspace import StepError
from docker_ros.in_image.steps import run_step

pytestmark = pytest.mark.host
SRC = Path(__file__).resolve().parents[2] / "src"


def steps_cli(*args, env=None):
    full = {**os.environ, "PYTHONPATH": str(SRC), **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "docker_ros.in_image.steps", *args], env=full,
        capture_output=True, text=True
    )


def test_cli_runs_a_step_with_log_lines(project):
    (project.repo / "docker").mkdir()
    (project.repo / "docker" / "additional-debs.txt").write_text("jq\n")
    proc = steps_cli("debs", "--workspace", str(project.ws.root), "--phase", "collect")
    assert proc.returncode == 0, proc.stderr
    assert "Starting >>> debs" in proc.stderr and "Finished <<< debs [" in proc.stderr
    assert (project.ws.state / "debs.json").is_file()


def test_cli_failure_is_one_line_with_the_exit_code(project):
    (project.repo / "docker").mkdir()
    (project.repo / "docker" / "custom.sh").write_text("exit 3\n")
    proc = steps_cli("custom", "--workspace", str(project.ws.root))
    assert proc.returncode == 3
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("docker-ros custom: ")
    assert "docker/custom.sh failed with exit code 3" in last
    assert "Traceback" not in proc.stderr


def test_cli_bad_setting_names_the_variable(project):
    proc = steps_cli(
        "debs",
        "--workspace",
        str(project.ws.root),
        env={"ENABLE_RECURSIVE_ADDITIONAL_DEBS": "maybe"},
    )
    assert proc.returncode == 1
    assert "docker-ros debs: invalid configuration" in proc.stderr
    assert "ENABLE_RECURSIVE_ADDITIONAL_DEBS='maybe'" in proc.stderr


def test_cli_options_reach_the_step(project, tmp_path):
    (project.repo / "docker" / "additional-files").mkdir(parents=True)
    (project.repo / "docker" / "additional-files" / "a.txt").write_text("a")
    dest = tmp_path / "dest"
    proc = steps_cli("files", "--workspace", str(project.ws.root), "--destination", str(dest))
    assert proc.returncode == 0, proc.stderr
    assert (dest / "a.txt").read_text() == "a"


def test_run_step_dispatches_and_rejects_unknown(project):
    run_step("blacklist", project.ws, project.settings())
    assert (project.ws.state / "blacklist.json").is_file()
    with pytest.raises(StepError):
        run_step("nope", project.ws, project.settings())


def test_cli_collect_without_repository_says_where_it_must_be(tmp_path):
    proc = steps_cli("rosdep", "--workspace", str(tmp_path / "ws"), "--phase", "collect")
    assert proc.returncode == 1
    assert f"docker-ros rosdep: {tmp_path / 'ws' / 'src' / 'target'} does not exist" in proc.stderr


def test_cli_runs_several_steps_in_order_and_names_the_one_that_failed(project, tmp_path):
    (project.repo / "docker" / "additional-files").mkdir(parents=True)
    (project.repo / "docker" / "additional-files" / "a.txt").write_text("a")
    (project.repo / "docker" / "additional-debs.txt").write_text("jq\n")
    dest = tmp_path / "dest"
    proc = steps_cli("debs", "files", "--workspace", str(project.ws.root), "--phase", "collect",
                     "--destination", str(dest))
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.index("Finished <<< debs") < proc.stderr.index("Starting >>> files")
    assert (project.ws.state / "debs.json").is_file()
    (project.repo / "docker" / "custom.sh").write_text("exit 4\n")
    proc = steps_cli("files", "custom", "debs", "--workspace", str(project.ws.root),
                     "--destination", str(dest))
    assert proc.returncode == 4
    assert (dest / "a.txt").read_text() == "a"  # files ran, with its own option
    assert proc.stderr.strip().splitlines()[-1].startswith("docker-ros custom: ")
    assert "Starting >>> debs" not in proc.stderr  # the failure stopped the rest


def test_each_step_of_a_call_gets_only_its_own_options():
    from docker_ros.in_image.steps.__main__ import step_options

    given = {"mark_ignored": "true", "dependency_types": "exec"}
    assert step_options("clone", given) == {}
    assert step_options("blacklist", given) == {"mark_ignored": "true"}
    assert step_options("rosdep", given) == {"dependency_types": "exec"}
