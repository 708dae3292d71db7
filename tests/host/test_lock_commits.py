"""Lock: the commits of imported checkouts, nested ones included, read from real git repos."""

import subprocess
from pathlib import Path

import pytest

from docker_ros.core.loading import host_platform
from docker_ros.in_image.runtime.lock import repository_commits
from docker_ros.in_image.runtime.lockfile import dump_repos, pin_repos
from docker_ros.in_image.runtime.workspace import Workspace

pytestmark = pytest.mark.host


def git(*args: str, cwd: Path) -> str:
    return subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True,
                          text=True).stdout.strip()


def make_upstream(path: Path) -> str:
    path.mkdir(parents=True)
    git("init", "-q", "-b", "main", cwd=path)
    (path / "a.txt").write_text("1\n")
    git("add", "a.txt", cwd=path)
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "one", cwd=path)
    return git("rev-parse", "HEAD", cwd=path)


def test_commits_of_nested_checkouts_and_pinned_import(tmp_path: Path):
    first = make_upstream(tmp_path / "remote" / "foo")
    make_upstream(tmp_path / "remote" / "bar")
    root = tmp_path / "src" / "upstream"
    root.mkdir(parents=True)
    git("clone", "-q", (tmp_path / "remote" / "foo").as_uri(), "foo", cwd=root)
    git("clone", "-q", (tmp_path / "remote" / "bar").as_uri(), "foo/nested/bar", cwd=root)
    commits = repository_commits(root)
    assert sorted(commits) == ["upstream/foo", "upstream/foo/nested/bar"]
    assert commits["upstream/foo"] == {"url": (tmp_path / "remote" / "foo").as_uri(),
                                       "commit": first}
    # A new upstream commit: vcs import of the pinned .repos still checks out the locked one.
    remote = tmp_path / "remote" / "foo"
    (remote / "a.txt").write_text("2\n")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qam", "two", cwd=remote)
    repos = {"foo": {"type": "git", "url": remote.as_uri(), "version": "main"}}
    pinned = pin_repos(repos, commits, "upstream")
    repos_file = tmp_path / "pinned.repos"
    repos_file.write_text(dump_repos(pinned))
    dest = tmp_path / "fresh"
    dest.mkdir()
    subprocess.run(["vcs", "import", "--input", str(repos_file), str(dest)], check=True,
                   capture_output=True)
    assert git("rev-parse", "HEAD", cwd=dest / "foo") == first
    assert (dest / "foo" / "a.txt").read_text() == "1\n"


def test_locked_clone_step_imports_the_locked_commit_and_unlocked_the_new(tmp_path: Path):
    from docker_ros.core.loading import host_platform, load_settings
    from docker_ros.in_image.runtime.lockfile import LOCK_FILE, dump_lock
    from docker_ros.in_image.runtime.workspace import StepError, Workspace
    from docker_ros.in_image.steps import clone

    remote = tmp_path / "remote" / "foo"
    first = make_upstream(remote)
    (remote / "a.txt").write_text("2\n")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qam", "two", cwd=remote)
    newest = git("rev-parse", "HEAD", cwd=remote)

    def clone_into(name: str, locked: bool, url: str = remote.as_uri()) -> Path:
        ws = Workspace(tmp_path / name)
        ws.target.mkdir(parents=True)
        (ws.target / ".repos").write_text(
            f"repositories:\n  foo:\n    type: git\n    url: {url}\n    version: main\n")
        entry = {"repos": {"upstream/foo": {"url": remote.as_uri(), "commit": first}}}
        (ws.target / LOCK_FILE).write_text(dump_lock(
            {"format": 1, "targets": {f"host/{host_platform()}": entry}}))
        settings = load_settings(environ={"LOCKED": str(locked).lower()}, project_dir=ws.target)
        clone.main(ws, settings)
        return ws.upstream / "foo"

    assert git("rev-parse", "HEAD", cwd=clone_into("locked", True)) == first
    assert git("rev-parse", "HEAD", cwd=clone_into("unlocked", False)) == newest
    with pytest.raises(StepError, match="upstream/foo .* differs from docker-ros.lock"):
        clone_into("moved", True, url=(tmp_path / "remote" / "other").as_uri())


def test_apt_closure_lists_the_package_and_what_apt_pulls_in():
    from docker_ros.in_image.runtime.lockapt import apt_closure

    closure = apt_closure(["cmatrix"])
    assert "cmatrix" in closure and all(version for version in closure.values())
    policy = subprocess.run(["apt-cache", "policy", "cmatrix"], capture_output=True, text=True,
                            env={"LC_ALL": "C", "PATH": "/usr/bin:/bin"}).stdout
    assert f"Candidate: {closure['cmatrix']}" in policy


def test_lock_host_writes_checks_and_then_holds_the_locked_build(project, tmp_path: Path):
    import json

    from docker_ros.host.lock import lock
    from docker_ros.in_image.runtime.lockfile import LOCK_FILE, LockError
    from docker_ros.in_image.runtime.workspace import StepError
    from docker_ros.in_image.steps import clone, debs
    from tests.rosfixtures import make_git_repo, write_repos

    url = make_git_repo(tmp_path / "remotes" / "lib_a", {"README": "a\n"})
    write_repos(project.repo / ".repos", {"lib_a": {"url": url, "version": "main"}})
    (project.repo / "debs.txt").write_text("cmatrix\n")
    env = {"build_context": str(project.repo), "additional_debs_file": "debs.txt"}
    settings = project.settings(**env)

    # --check without a lock says so at once (it cloned and ran rosdep, or built the lock
    # stages, to compare with nothing); the image lock would need an engine: none is asked
    for host in (True, False):
        with pytest.raises(LockError, match=r"docker-ros.lock does not exist: `inv lock` "):
            lock(settings, check=True, host=host, out=None)

    assert lock(settings, check=False, host=True, out=None)  # a first lock: everything is new
    entry = next(iter(json.loads((project.repo / LOCK_FILE).read_text())["targets"].values()))
    first = entry["repos"]["upstream/lib_a"]["commit"]
    assert "cmatrix" in entry["apt"] and entry["inputs"]["debs"] == ["cmatrix"]
    assert lock(settings, check=True, host=True, out=None) == []

    remote = tmp_path / "remotes" / "lib_a"
    (remote / "README").write_text("a2\n")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qam", "two", cwd=remote)
    git("push", "-q", url, "HEAD:main", cwd=remote)
    (project.repo / "debs.txt").write_text("cmatrix\nsl\n")
    changes = lock(settings, check=True, host=True, out=None)
    key = f"host/{host_platform()}"
    assert f"{key}: debs: added sl" in changes
    assert any(c.startswith(f"{key}: repos upstream/lib_a ") and first in c for c in changes)
    assert any(c.startswith(f"{key}: apt sl None -> ") for c in changes)

    locked = project.settings(locked="true", **env)
    with pytest.raises(StepError, match="debs: added sl.*run `inv lock`"):
        debs.main(project.ws, locked, dry_run=True)
    fresh = Workspace(tmp_path / "fresh")
    fresh.src.mkdir(parents=True)
    fresh.target.symlink_to(project.repo, target_is_directory=True)
    clone.main(fresh, locked)
    assert git("rev-parse", "HEAD", cwd=fresh.upstream / "lib_a") == first
