"""The files the resolve stage reads, copied out of the workspace so that an edit of anything
else (a .cpp, a launch file) leaves the resolution and the dependency layers cached.
`python3 -m docker_ros.in_image.runtime.inputs DEST MARKERS`: run by the image's source stage,
which also copies the ignore markers alone to MARKERS, for the dev image's sources (the marked
stage: the build context leaves ADDITIONAL_FILES_DIR out of them, the resolve inputs do not).
Standard library only, Python 3.8+ (runs inside images)."""

import os
import shutil
import sys
from pathlib import Path
from typing import List

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.entry import image_main
from docker_ros.in_image.runtime.files import find_special_files, repository_path, walk
from docker_ros.in_image.runtime.lockfile import LOCK_FILE, is_locked
from docker_ros.in_image.runtime.packages import package_search_dirs
from docker_ros.in_image.runtime.requirements import read_requirement_file
from docker_ros.in_image.runtime.workspace import IGNORE_MARKERS, Workspace

# What the collect phases of scripts, rosdep, debs, pip, files and custom read: package
# manifests and ignore markers anywhere, and the files and folder the path settings name.
MANIFESTS = ("package.xml", *IGNORE_MARKERS)
LIST_SETTINGS = (
    "before_dependency_installation_script", "after_dependency_installation_script",
    "additional_debs_file", "additional_pip_file", "rosdep_rules_file",
    "blacklisted_packages_file",
)
STATE_FILES = ("blacklist.json",)


def resolve_inputs(ws: Workspace, settings: Settings) -> List[Path]:
    """Every file below ws.root that resolving the dependencies may read."""
    found: List[Path] = []
    for directory in package_search_dirs(ws.src):  # (where catkin_pkg's discovery looks)
        found += [directory / n for n in MANIFESTS if (directory / n).is_file()]
    for name in LIST_SETTINGS:
        found += find_special_files(ws, settings, name, step="resolve", required=False)
    for path in find_special_files(ws, settings, "additional_pip_file", step="resolve",
                                   required=False):
        # the nested -r/-c files it names (a missing one: the pip step says so)
        nested = read_requirement_file(path, step="resolve", missing_ok=True).files[1:]
        found += [p for p in nested if ws.root in p.parents]
    files_dir = repository_path(ws, settings, "additional_files_dir", step="resolve")
    if files_dir.is_dir():  # (all of it, as docker-ros's ADD: `install/`, `log/` too)
        found += [d / n for d in walk(files_dir, skip=lambda name: False)
                  for n in sorted(os.listdir(str(d))) if (d / n).is_file()]
    found += [ws.state / n for n in STATE_FILES if (ws.state / n).is_file()]
    if is_locked(settings) and (ws.target / LOCK_FILE).is_file():
        found.append(ws.target / LOCK_FILE)  # (a locked resolve stage checks against it)
    return sorted(set(found))


def copy_inputs(ws: Workspace, paths: List[Path], destination: Path) -> None:
    """Copy the files to the same relative places below destination (contents, modes); the
    repository's folder always exists (the collect phases require it)."""
    (destination / ws.target.relative_to(ws.root)).mkdir(parents=True, exist_ok=True)
    for path in paths:
        target = destination / path.relative_to(ws.root)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(str(path), str(target))


def copy_inputs_and_markers(ws: Workspace, settings: Settings, destination: Path,
                            markers: Path) -> None:
    found = resolve_inputs(ws, settings)
    copy_inputs(ws, found, destination)
    copy_inputs(ws, [path for path in found if path.name in IGNORE_MARKERS], markers)


def main(argv: List[str]) -> int:
    return image_main(argv, module="runtime.inputs", step="resolve",
                      description="Copy the files resolving reads to DESTINATION and the "
                      "ignore markers among them to MARKERS (the source stage).",
                      arguments=["DESTINATION", "MARKERS"],
                      action=lambda ws, settings, args: copy_inputs_and_markers(
                          ws, settings, Path(args[0]), Path(args[1])))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
