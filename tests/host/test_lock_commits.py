"""Lock: the commits of imported checkouts, nested ones included, read from real git repos."""

import subprocess
from pathlib import Path

from docker_ros.lock import repository_commits
from docker_ros.runtime.lock import dump_repos, pin_repos


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
