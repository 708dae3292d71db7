"""The command line reads well: per-task options, help that fits 80 columns, steps numbered."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Set

import pytest

from docker_ros.cli.tasks import EXAMPLE, ns
from docker_ros.in_image.steps import STEPS
from tests.rosfixtures import make_package

pytestmark = pytest.mark.host


def cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "COLUMNS": "80"}
    return subprocess.run([sys.executable, "-m", "docker_ros", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


def source_words(task_name: str) -> Set[str]:
    """Every word of a task's docstring and option help, and its pieces at hyphens (where
    invoke's wrapper may break a line, as typesetting does)."""
    task = ns[task_name]
    texts = [task.__doc__ or "", *task.help.values()]
    words: Set[str] = set()
    for word in " ".join(texts).split():
        words.add(word)
        pieces = word.split("-")
        for i in range(len(pieces)):
            for j in range(i + 1, len(pieces) + 1):
                words.add("-".join(pieces[i:j]) + ("-" if j < len(pieces) else ""))
    return words


@pytest.mark.parametrize("task", sorted(ns.task_names))
def test_task_help_fits_80_columns_and_splits_no_word(task: str, tmp_path: Path) -> None:
    out = cli(task, "--help", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    # invoke's own "Usage: docker-ros [--core-opts] <task> ..." header is left aside.
    lines = [line for line in out.stdout.splitlines() if not line.startswith("Usage:")]
    assert all(len(line) <= 80 for line in lines), [line for line in lines if len(line) > 80]
    allowed = source_words(task)
    help_part = "\n".join(lines[lines.index("Options:") + 1:])
    for line in help_part.splitlines():
        text = re.sub(r"^\s*(-\w( \w+)?, )?--[\w-]+(=\w+)?(\[=\w+\])?\s*", "", line)
        for word in text.split():
            assert word in allowed, f"{task} --help: {word!r} is a broken word in {line!r}"
    assert len(out.stdout.splitlines()) < 80, f"{task} --help is {len(lines)} lines"


def test_list_numbers_the_steps_in_pipeline_order(tmp_path: Path) -> None:
    out = cli("--list", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    numbered = dict(re.findall(rf"^  (\w+)\s+\[step (\d+)/{len(STEPS)}\]", out.stdout,
                               flags=re.M))
    assert [name for name, _ in sorted(numbered.items(), key=lambda kv: int(kv[1]))] == list(STEPS)


def test_set_reaches_any_setting_and_refuses_secrets(tmp_path: Path) -> None:
    make_package(tmp_path / "pkg", "pkg")
    shown = cli("config", "--set", "ENABLE_SLIM=false", "--set", "cmake-args=-DX=1", cwd=tmp_path)
    assert shown.returncode == 0, shown.stderr
    rows = {line.split()[0]: line.split()[1:] for line in shown.stdout.splitlines()[1:]}
    assert rows["ENABLE_SLIM"] == ["false", "flag"] and rows["CMAKE_ARGS"] == ["-DX=1", "flag"]
    secret = cli("config", "--set", "REGISTRY_PASSWORD=hunter2", cwd=tmp_path)
    assert secret.returncode != 0 and "never given on a command line" in secret.stderr
    typo = cli("config", "--set", "ENABLE_SLM=true", cwd=tmp_path)
    assert typo.returncode != 0 and "did you mean ENABLE_SLIM?" in typo.stderr
    flag_wins = cli("build", "--dry-run", "--image-tag", "a", "--set", "IMAGE_TAG=b",
                    "--set", "BASE_IMAGE=x", "--set", "COMMAND=true", cwd=tmp_path)
    assert flag_wins.returncode == 0, flag_wins.stderr
    assert ':a"' in flag_wins.stdout and ':b"' not in flag_wins.stdout


def test_the_console_script_reads_the_projects_invoke_yaml(tmp_path: Path) -> None:
    """`docker-ros` (a Program with its tasks bundled) reads invoke.yaml where it runs, as
    `inv` does next to tasks.py."""
    make_package(tmp_path / "pkg", "pkg")
    (tmp_path / "invoke.yaml").write_text("docker_ros:\n  base_image: from-invoke-yaml/x:1\n")
    result = cli("config", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    row = next(line for line in result.stdout.splitlines() if line.startswith("BASE_IMAGE "))
    assert row.split()[1:] == ["from-invoke-yaml/x:1", "invoke.yaml"], row


def test_example_task_finds_the_repository_s_example_folder() -> None:
    """`inv example`, the README's first command, finds the bundled example (it looked in
    src/example after the command line moved into docker_ros/cli)."""
    assert Path(__file__).resolve().parents[2] / "example" == EXAMPLE
    assert "BASE_IMAGE=docker-ros/ros1:bookworm" in (EXAMPLE / ".env").read_text()
