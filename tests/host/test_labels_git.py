"""The OCI labels' git facts read from a real repository (issue 46)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from docker_ros.host.labels import GitFacts, git_facts

pytestmark = pytest.mark.host


def git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True,
                          check=True).stdout.strip()


def test_git_gives_the_commit_its_time_and_the_remote(tmp_path: Path) -> None:
    assert git_facts(tmp_path) == GitFacts()  # (not a repository)
    git(tmp_path, "init", "-q")
    assert git_facts(tmp_path) == GitFacts()  # (no commit yet)
    (tmp_path / "a").write_text("a")
    git(tmp_path, "add", "a")
    git(tmp_path, "-c", "user.name=t", "-c", "user.email=t@example.com", "commit", "-qm", "a",
        "--date=2025-11-29T00:00:00Z")
    head = git(tmp_path, "rev-parse", "HEAD")
    committed = int(git(tmp_path, "log", "-1", "--format=%ct"))
    assert git_facts(tmp_path) == GitFacts(head, committed, "")
    git(tmp_path, "remote", "add", "upstream", "git@github.com:Org/Robot.git")
    git(tmp_path, "remote", "add", "origin", "https://tok:SECRET@github.com/Org/Robot.git")
    # (the remote as git has it: labels.web_url drops the credentials)
    assert git_facts(tmp_path / ".") == GitFacts(head, committed,
                                                 "https://tok:SECRET@github.com/Org/Robot.git")
