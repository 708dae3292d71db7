"""What a before-dependency-identification hook changed in an image's system, kept for the
stages that resolve and install.

docker-ros runs that hook, rosdep and every install in one stage, so a hook may add rosdep
sources, apt sources and keys, pip configuration or environment files, and the installs see
them. Our image runs the hook in the source stage, and resolves and installs in stages built
from the base: the files the hook created or changed outside the workspace are copied to
CHANGES_DIR, which the Dockerfile's hooked-system stage lays over the base.
Standard library only, Python 3.8+ (runs inside images).
"""

import logging
import os
import shutil
import time
from pathlib import Path
from typing import Iterator, List, Sequence

LOG = logging.getLogger(__name__)
CHANGES_DIR = Path("/docker-ros/system-changes")
ROSDEP_SOURCES = Path("/etc/ros/rosdep/sources.list.d")
# Not the system: the workspace and tools, caches, logs, and the kernel's file systems.
SKIPPED = ("/docker-ros", "/proc", "/sys", "/dev", "/run", "/tmp", "/var/tmp", "/var/cache",
           "/var/lib/apt/lists", "/var/log", "/root/.cache", "/root/.ros/log")


def skipped(path: str, skip: Sequence[str] = SKIPPED) -> bool:
    return any(path == s or path.startswith(s + "/") for s in skip)


def changed_since(since: float, root: str = "/", skip: Sequence[str] = SKIPPED
                  ) -> Iterator[str]:
    """Files and symlinks below root (one file system) whose status changed at or after since.
    The status change time (ctime) also catches files copied with their old mtime."""
    device = os.lstat(root).st_dev
    for dirpath, dirnames, filenames in os.walk(root):
        kept = []
        for name in dirnames:
            path = os.path.join(dirpath, name)
            try:
                info = os.lstat(path)
            except OSError:
                continue
            if skipped(path, skip) or info.st_dev != device:
                continue
            if os.path.islink(path):
                filenames.append(name)  # a symlink to a folder: copied as a link
            else:
                kept.append(name)
        dirnames[:] = kept
        for name in filenames:
            path = os.path.join(dirpath, name)
            try:
                if os.lstat(path).st_ctime >= since:
                    yield path
            except OSError:
                continue


def referenced_rules(sources: Path = ROSDEP_SOURCES) -> List[str]:
    """Local rules files (`yaml file:///...`) the rosdep sources lists name: the resolve stage
    needs them even when the hook did not write them (a file of the repository, say)."""
    found: List[str] = []
    if not sources.is_dir():
        return found
    for listing in sorted(sources.glob("*.list")):
        for line in listing.read_text(errors="replace").splitlines():
            words = line.split()
            if len(words) >= 2 and words[1].startswith("file://"):
                found.append(words[1][len("file://"):])
    return found


def copy_into(path: str, destination: Path) -> None:
    """Copy path (file or symlink) to destination/path, with its mode and times."""
    target = destination / path.lstrip("/")
    target.parent.mkdir(parents=True, exist_ok=True)
    if os.path.islink(path):
        if os.path.lexists(str(target)):
            target.unlink()
        os.symlink(os.readlink(path), str(target))
    else:
        shutil.copy2(path, str(target))


def capture(since: float, destination: Path = CHANGES_DIR) -> List[str]:
    """Copy what changed since `since` (and the local rules files rosdep's sources name) to
    destination; return the paths copied. destination exists afterwards, also when empty."""
    destination.mkdir(parents=True, exist_ok=True)
    paths = sorted(set(changed_since(since)) | {p for p in referenced_rules()
                                                if os.path.isfile(p) and not skipped(p)})
    for path in paths:
        copy_into(path, destination)
    return paths


def mark() -> float:
    """The time to compare ctimes with, a little early: the kernel stamps files with a coarse
    clock (a tick, a few milliseconds)."""
    return time.time() - 0.1


def report(step: str, paths: Sequence[str]) -> None:
    if not paths:
        LOG.info("%s: the hook changed nothing outside the workspace", step)
        return
    folders = sorted({str(Path(p).parent) for p in paths})
    shown = ", ".join(folders[:8]) + (f" and {len(folders) - 8} more" if len(folders) > 8 else "")
    LOG.info("%s: the hook changed %d system file(s) (%s): the resolve and install stages "
             "start from them", step, len(paths), shown)
