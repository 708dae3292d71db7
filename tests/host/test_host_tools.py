"""The installed command finds its own tools: docker-ros and vcstool installed in a virtualenv
that is not activated (its bin/ not on PATH), as `/path/to/venv/bin/docker-ros clone` runs."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from docker_ros.in_image.runtime.process import executable_argv, tool_path
from tests import suitelock
from tests.rosfixtures import make_git_repo, write_repos

pytestmark = pytest.mark.host
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A venv (with this interpreter's packages for docker-ros's dependencies) holding its own
    docker-ros and vcstool: the `docker-ros` and `vcs` commands exist only in its bin/."""
    path = tmp_path_factory.mktemp("tools") / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(path)],
                   check=True)
    pip = [str(path / "bin" / "python"), "-m", "pip", "install", "-q", "--no-deps",
           "--ignore-installed"]
    with suitelock.once(suitelock.SOURCE_TREE_BUILD):
        subprocess.run([*pip, "vcstool>=0.3", str(ROOT)], check=True, capture_output=True)
    assert (path / "bin" / "vcs").is_file() and (path / "bin" / "docker-ros").is_file()
    return path


def test_clone_from_a_venv_that_is_not_activated(venv: Path, tmp_path: Path) -> None:
    url = make_git_repo(tmp_path / "remotes" / "lib_a", {"README": "a\n"})
    repo = tmp_path / "repo"
    write_repos(repo / ".repos", {"lib_a": {"url": url, "version": "main"}})
    (repo / ".env").write_text(f"WORKSPACE={tmp_path / 'ws'}\n")
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "VIRTUAL_ENV", "TARGET", "COMMAND", "IMAGE")}
    env["PATH"] = "/usr/sbin:/usr/bin:/sbin:/bin"  # git, but no vcs
    assert subprocess.run(["sh", "-c", "command -v vcs"], env=env).returncode != 0

    proc = subprocess.run([str(venv / "bin" / "docker-ros"), "clone"], cwd=repo, env=env,
                          capture_output=True, text=True, timeout=300)

    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "ws" / "src" / "upstream" / "lib_a" / "README").read_text() == "a\n"
    assert "command not found" not in proc.stderr


def test_tool_path_prefers_the_interpreters_folder(venv: Path, monkeypatch) -> None:
    monkeypatch.delenv("DOCKER_ROS", raising=False)
    python = str(venv / "bin" / "python")
    assert tool_path("vcs", python) == str(venv / "bin" / "vcs")
    assert tool_path("rosdep", python) == "rosdep"  # not in that venv: PATH decides
    assert tool_path("git", python) == "git"  # only the host-mode tools
    assert executable_argv(["git", "status"]) == ["git", "status"]
    monkeypatch.setenv("DOCKER_ROS", "1")  # in images: PATH, as the image's tools are
    assert tool_path("vcs", python) == "vcs"
