"""Finding packages' special files, list files and copying trees in the workspace.
Standard library only, Python 3.8+ (runs inside images)."""

import fnmatch
import functools
import hashlib
import os
import shutil
from pathlib import Path
from typing import Callable, Iterator, List, Optional, Sequence, Tuple

from docker_ros.core.settings import FIELDS, Settings, explicitly_set
from docker_ros.in_image.runtime.workspace import (
    LOG,
    SKIP_DIRS,
    StepError,
    Workspace,
    dry,
    read_user_text,
)


def is_elf(path: Path) -> bool:
    """Whether path is an ELF file (an executable, a shared library, an object)."""
    with path.open("rb") as handle:
        return handle.read(4) == b"\x7fELF"


def walk(
    root: Path, *, prune: Optional[Callable[[Path, List[str]], bool]] = None,
    skip: Callable[[str], bool] = SKIP_DIRS.__contains__,
) -> Iterator[Path]:
    """Every directory below root (root first), skipping VCS/build dirs (or the folder names
    `skip` says); follows symlinks once.

    `prune(directory, entries)` returning True stops the descent below that directory
    (the directory itself is still yielded)."""
    seen = set()
    for dirpath, dirnames, filenames in os.walk(str(root), followlinks=True):
        real = os.path.realpath(dirpath)
        if real in seen:
            dirnames[:] = []
            continue
        seen.add(real)
        dirnames[:] = sorted(d for d in dirnames if not skip(d))
        if prune is not None and prune(Path(dirpath), dirnames + filenames):
            dirnames[:] = []
        yield Path(dirpath)


def path_problem(repository: Path, relative: str) -> Optional[str]:
    """Why `relative` does not name a place inside the repository (absolute, `..` out of it,
    or through a symlink leading out of it), or None when it does."""
    if Path(relative).is_absolute():
        return "is an absolute path"
    if os.path.normpath(relative).split(os.sep)[0] == "..":
        return "leaves the repository through '..'"
    root = os.path.realpath(str(repository))
    real = os.path.realpath(os.path.join(root, relative))
    if real != root and not real.startswith(root + os.sep):
        return f"leads to {real} through a symlink"
    return None


def repository_path(ws: Workspace, settings: Settings, name: str, *, step: str) -> Path:
    """The repository's file or folder that path setting `name` names; a StepError when the
    setting points outside the repository (the image would get the build machine's files)."""
    relative = str(getattr(settings, name))
    problem = path_problem(ws.target, relative)
    if problem:
        raise StepError(step, f"{name.upper()}={relative!r} {problem}: give a path inside the "
                        "repository")
    return ws.target / relative


# The path settings docker-ros looked for after removing the blacklisted packages: their files
# there are not used (the .repos files and the blacklist files themselves came before).
AFTER_BLACKLIST = ("before_dependency_installation_script", "after_dependency_installation_script",
                   "additional_debs_file", "additional_pip_file")


def blacklisted_folders(ws: Workspace) -> List[Path]:
    """The folders of the blacklisted packages (the blacklist step's blacklist.json; none before
    it ran)."""
    data = ws.read_state("blacklist.json")
    packages = data.get("packages") or {} if isinstance(data, dict) else {}
    return [ws.root / path for paths in packages.values() for path in paths]


def find_special_files(
    ws: Workspace,
    settings: Settings,
    name: str,
    *,
    pattern: Optional[str] = None,
    step: str = "docker-ros",
    required: bool = True,
) -> List[Path]:
    """docker-ros's file discovery for path setting `name`: the configured file in the
    repository, and when its recursive setting is on, every file of the same name (or matching
    `pattern`) anywhere in the workspace. A file the user set explicitly must exist."""
    ws.require_sources(step)
    relative_path = str(getattr(settings, name))
    switch = FIELDS[name].metadata["recursive"]
    recursive = bool(switch and getattr(settings, switch))
    found: List[Path] = []
    top = repository_path(ws, settings, name, step=step)
    if top.is_file():
        found.append(top)
    if recursive:
        file_name = Path(relative_path).name
        left_out = blacklisted_folders(ws) if name in AFTER_BLACKLIST else []
        for directory in walk(ws.src):
            if any(folder == directory or folder in directory.parents for folder in left_out):
                continue
            for entry in sorted(directory.iterdir()):
                matches = (fnmatch.fnmatch(entry.name, pattern) if pattern
                           else entry.name == file_name)
                if matches and entry.is_file() and entry not in found:
                    found.append(entry)
    if not found and required and explicitly_set(settings, name):
        where = f" (nor any {pattern or file_name!r} in {ws.src})" if recursive else ""
        raise StepError(step, f"{name.upper()} '{relative_path}' not found in the repository"
                        f"{where}, but set explicitly: fix the path or unset it")
    return found


def read_list_file(path: Path, step: str) -> List[str]:
    """Lines of a list file (package names: the blacklist, apt packages) without comments,
    blank lines and surrounding spaces. A comment starts at any '#', as docker-ros's awk
    (`gsub(/#.*/, "")`) had it: `bad_pkg# old` is bad_pkg (pip files have their own rules)."""
    items = []
    for line in read_user_text(path, functools.partial(StepError, step)).splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            items.append(line)
    return items


def collect_list_entries(
    ws: Workspace, step: str, settings: Settings, name: str
) -> Tuple[List[str], List[Path]]:
    """Entries of every list file of path setting `name` (in discovery order), and the files."""
    files = find_special_files(ws, settings, name, step=step)
    if not files:
        LOG.info("%s: no %s found, nothing to do", step, getattr(settings, name))
    entries: List[str] = []
    for path in files:
        items = read_list_file(path, step)
        LOG.info("%s: %d entries in %s", step, len(items), path)
        entries.extend(items)
    return entries, files


def unique(items: Sequence[str]) -> List[str]:
    """Items without repetitions, first occurrence kept (order matters for pip options)."""
    out: List[str] = []
    seen = set()
    for item in items:
        if item not in seen:
            seen.add(item)
            out.append(item)
    return out


def file_sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def copy_tree(src: Path, dst: Path, *, step: str, dry_run: bool) -> None:
    """Copy a directory's contents into dst (merging, symlinks kept as symlinks)."""
    if dry_run:
        dry(step, f"copy {src}/ -> {dst}/")
        return
    LOG.info("%s: copy %s/ -> %s/", step, src, dst)
    _copy_into(Path(src), Path(dst))


def _copy_into(src: Path, dst: Path) -> None:
    # shutil.copytree(dirs_exist_ok=True) fails on existing symlinks: re-runs must not.
    dst.mkdir(parents=True, exist_ok=True)
    for entry in sorted(src.iterdir()):
        target = dst / entry.name
        if entry.is_dir() and not entry.is_symlink():
            if target.is_symlink() or (target.exists() and not target.is_dir()):
                target.unlink()
            _copy_into(entry, target)
            continue
        if target.is_symlink() or target.is_file():
            target.unlink()
        elif target.is_dir():
            shutil.rmtree(str(target))
        if entry.is_symlink():
            os.symlink(os.readlink(str(entry)), str(target))
        else:
            shutil.copy2(str(entry), str(target))
    shutil.copystat(str(src), str(dst))


def remove_tree(path: Path, *, step: str, dry_run: bool) -> None:
    if dry_run:
        dry(step, f"remove {path}")
        return
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.exists():
        shutil.rmtree(str(path))
