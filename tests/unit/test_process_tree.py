"""The processes below a command (runtime.process.descendants), which an interrupted step stops
with it: tests/host/test_host_clone_https.py checks that vcs's git clones do not outlive it."""

from docker_ros.in_image.runtime.process import descendants


def test_descendants_are_found_at_any_depth_whatever_the_command_names(tmp_path):
    """descendants reads /proc/<pid>/stat: the parent is the second field after the command
    name, which may hold spaces and parentheses; an entry that ended meanwhile is passed over."""
    def stat(pid: int, comm: str, parent: int) -> None:
        (tmp_path / str(pid)).mkdir()
        (tmp_path / str(pid) / "stat").write_text(f"{pid} ({comm}) S {parent} {pid} 0 0\n")

    stat(10, "inv", 1)
    stat(11, "vcs", 10)
    stat(12, "git (clone) x", 11)
    stat(13, "git-remote-http", 12)
    stat(20, "other", 1)
    (tmp_path / "14").mkdir()  # ended meanwhile: no stat
    assert sorted(descendants(10, tmp_path)) == [11, 12, 13]
    assert descendants(13, tmp_path) == []
