"""The whole messages of a locked build whose locked versions the sources no longer have, from the
functions that write them (check_available, check_pip_available), with the package managers'
answers given: the image builds of tests/docker/test_lock.py prove one of them reaches the user."""

import subprocess
from typing import List

import pytest

from docker_ros.in_image.runtime import lockapt, lockpip
from docker_ros.in_image.runtime.workspace import StepError


def answered(stdout: str = "", stderr: str = "", returncode: int = 0):
    def probe(argv: List[str], **kwargs: object) -> "subprocess.CompletedProcess[str]":
        return subprocess.CompletedProcess(argv, returncode, stdout, stderr)
    return probe


def test_a_locked_apt_version_the_archive_dropped_stops_naming_it_and_the_sources(monkeypatch):
    """After fresh lists too (apt's old ones may hide a version): apt is asked twice."""
    asked: List[List[str]] = []
    gone = answered(stderr="E: Version '0.0-gone1' for 'cmatrix' was not found\n", returncode=100)
    monkeypatch.setattr(lockapt, "apt_lists_present", lambda: True)
    monkeypatch.setattr(lockapt, "probe", lambda argv, **kw: asked.append(argv) or gone(argv))
    monkeypatch.setattr(lockapt, "apt_sources",
                        lambda: ["http://deb.debian.org/debian bookworm",
                                 "http://deb.debian.org/debian-security bookworm-security"])
    with pytest.raises(StepError) as stopped:
        lockapt.check_available(["cmatrix=0.0-gone1", "sl=5.02-1+b1"], step="debs")
    assert str(stopped.value) == (
        "debs: LOCKED: cmatrix=0.0-gone1 no longer available from apt's sources "
        "(http://deb.debian.org/debian bookworm; http://deb.debian.org/debian-security "
        "bookworm-security): the archive dropped the locked version; run `inv lock` to lock what "
        "it has now")
    assert [a for a in asked if "update" in a] and asked[-1][:3] == ["apt-get", "install", "-s"]
    monkeypatch.setattr(lockapt, "apt_sources", lambda: [])
    with pytest.raises(StepError, match=r"apt's sources \(none configured\): the archive"):
        lockapt.check_available(["cmatrix=0.0-gone1"], step="debs")
    # what apt has passes, and nothing locked asks apt nothing
    asked.clear()
    monkeypatch.setattr(lockapt, "probe", lambda argv, **kw: asked.append(argv) or answered()(argv))
    lockapt.check_available(["sl=5.02-1+b1"], step="debs")
    lockapt.check_available([], step="debs")
    assert len(asked) == 1


def test_a_locked_pip_version_the_index_dropped_stops_naming_it_and_the_sources(monkeypatch):
    """The requirement file's own index is named (with --no-index, not PyPI)."""
    pip_said = ("ERROR: Could not find a version that satisfies the requirement "
                "docker_ros_lock_probe (from versions: 1.0, 1.1)\n"
                "ERROR: No matching distribution found for docker_ros_lock_probe\n")
    monkeypatch.setattr(lockpip, "pip_dry_run", lambda *a, **k: answered(
        stderr=pip_said, returncode=1)(["pip"]))
    for name in ("PIP_INDEX_URL", "PIP_EXTRA_INDEX_URL", "PIP_FIND_LINKS"):
        monkeypatch.delenv(name, raising=False)
    index = "http://127.0.0.1:8000/wheels/"
    requirements = [f"--no-index --find-links {index}", "docker_ros_lock_probe"]
    constraints = ["docker-ros-lock-probe==0.9", "six==1.16.0"]
    with pytest.raises(StepError) as stopped:
        lockpip.check_pip_available(requirements, constraints, step="pip")
    assert str(stopped.value) == (
        f"pip: LOCKED: docker-ros-lock-probe==0.9 no longer available from pip's sources "
        f"({index}): run `inv lock` to lock what they have now")
    # from PyPI, where the requirements name no index
    with pytest.raises(StepError, match=r"sources \(https://pypi.org/simple \(pip's default "
                                        r"index\)\): run `inv lock`"):
        lockpip.check_pip_available(["docker_ros_lock_probe"], constraints, step="pip")
    # another failure of pip is the install's to report; nothing locked is not checked
    monkeypatch.setattr(lockpip, "pip_dry_run", lambda *a, **k: answered(
        stderr="ERROR: some other trouble\n", returncode=1)(["pip"]))
    lockpip.check_pip_available(requirements, constraints, step="pip")
    lockpip.check_pip_available(requirements, [], step="pip")
