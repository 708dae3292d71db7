"""colcon: `colcon build` the workspace, over ROS and the base image's workspace."""

import hashlib
import json
import logging
import os
import re
import shlex
import time
from pathlib import Path
from typing import Dict, List, Sequence

from docker_ros.runtime.process import run, run_tee
from docker_ros.runtime.rosenv import ros_setup_files, sourced_env
from docker_ros.runtime.workspace import StepError, Workspace, dry, phases, step_log
from docker_ros.settings import Settings
from docker_ros.steps.blacklist import blacklisted_packages

STEP = "colcon"
STAMP_FILE = ".docker-ros-source-hashes.json"
LOG = logging.getLogger(__name__)
_FAILED = re.compile(r"^Failed\s+<<<\s+(\S+)")


def cmake_arguments(cmake_args: str) -> List[str]:
    """CMAKE_ARGS split like a shell would (quotes keep spaces), no shell involved. colcon
    strips a leading space, which keeps `--foo` from being taken for a colcon option."""
    return [
        " " + a if a.startswith("--") or a.startswith("-h") else a for a in shlex.split(cmake_args)
    ]


def build_argv(cmake_args: str, ignore: Sequence[str]) -> List[str]:
    # console_cohesion+: each package's full build output (compiler errors included) in the log.
    argv = ["colcon", "build", "--base-paths", "src", "--event-handlers", "console_cohesion+"]
    if ignore:
        argv += ["--packages-ignore", *ignore]
    arguments = cmake_arguments(cmake_args)
    if arguments:
        argv += ["--cmake-args", *arguments]
    return argv


def source_hashes(src: Path) -> Dict[str, str]:
    """sha256 of every file below src (not .git), by relative path."""
    hashes = {}
    for dirpath, dirnames, filenames in os.walk(str(src)):
        dirnames[:] = [d for d in dirnames if d != ".git"]
        for name in filenames:
            path = Path(dirpath, name)
            if path.is_file():
                digest = hashlib.sha256(path.read_bytes()).hexdigest()
                hashes[path.relative_to(src).as_posix()] = digest
    return hashes


def changed_files(old: Dict[str, str], new: Dict[str, str]) -> List[str]:
    return sorted(path for path, digest in new.items() if old.get(path) != digest)


def stamp_changed_sources(ws: Workspace) -> Dict[str, List[object]]:
    """In the image, build/ is a cache mount reused across builds, while file times come from
    COPY (the context's times) or from a fresh clone (now). Make decides by time, so: every
    file whose content changed since the last successful build gets the current time, every
    other file the time it had then (a re-imported repository must not look newer than its
    objects). Returns the record ({path: [sha256, mtime]}) to write after the build."""
    record = ws.root / "build" / STAMP_FILE
    old = json.loads(record.read_text()) if record.is_file() else {}
    old_hashes = {p: (v[0] if isinstance(v, list) else v) for p, v in old.items()}
    new = source_hashes(ws.src)
    now = time.time()
    changed = set(changed_files(old_hashes, new))
    stamped: Dict[str, List[object]] = {}
    for rel, digest in new.items():
        before = old.get(rel)
        if rel in changed or not isinstance(before, list):
            mtime = now if rel in changed else (ws.src / rel).stat().st_mtime
        else:
            mtime = float(before[1])
        os.utime(str(ws.src / rel), (mtime, mtime))
        stamped[rel] = [digest, mtime]
    LOG.info("%s: %d of %d source files changed since the last build", STEP, len(changed), len(new))
    return stamped


def failed_packages(lines: Sequence[str]) -> List[str]:
    """Packages colcon reports as `Failed   <<< pkg [...]`."""
    out = []
    for line in lines:
        match = _FAILED.match(line.strip())
        if match and match.group(1) not in out:
            out.append(match.group(1))
    return out


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: str,
) -> None:
    """Single phase: build with CMAKE_ARGS, blacklisted packages ignored."""
    phases(STEP, phase)
    with step_log(STEP):
        ws.require_sources(STEP)
        ignore = blacklisted_packages(ws, settings)
        argv = build_argv(settings.cmake_args, ignore)
        setup = ros_setup_files(settings)
        if dry_run:
            for path in setup:
                dry(STEP, f"source {path}")
            run(argv, step=STEP, dry_run=True, cwd=ws.root)
            return
        env = sourced_env(setup, step=STEP)
        stamps = stamp_changed_sources(ws) if options.get("stamp_changed") else None
        returncode, lines = run_tee(argv, step=STEP, cwd=ws.root, env=env)
        if returncode != 0:
            failed = failed_packages(lines)
            what = (
                ("package " + ", ".join(failed) + " failed to build")
                if failed
                else ("colcon build failed")
            )
            raise StepError(
                STEP, f"{what} (exit code {returncode}); see the output above", returncode
            )
        if stamps is not None:
            # Only after success: a failed build must find the same files changed next time.
            (ws.root / "build" / STAMP_FILE).write_text(json.dumps(stamps, sort_keys=True))
