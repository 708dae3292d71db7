"""colcon: `colcon build` the workspace, over ROS and the base image's workspace."""

import hashlib
import json
import logging
import os
import platform
import re
import shlex
import time
from pathlib import Path
from typing import Dict, List, Mapping, Optional, Sequence, Set, Tuple

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.apt import DPKG_STATUS
from docker_ros.in_image.runtime.packages import Package, find_packages
from docker_ros.in_image.runtime.process import ERROR_LINE, run, run_tee
from docker_ros.in_image.runtime.rosenv import ros_setup_files, sourced_env
from docker_ros.in_image.runtime.workspace import StepError, Workspace, dry, phases, step_log
from docker_ros.in_image.steps.blacklist import blacklisted_packages

STEP = "colcon"
STAMP_FILE = ".docker-ros-source-hashes.json"
# In the build/ cache mount: the install space of the last successful build, and what it was
# built from (colcon arguments, packages, environment), for incremental image builds.
INSTALL_COPY = ".docker-ros-install"
INSTALL_RECORD = ".docker-ros-install.json"
# A build state from elsewhere (the registry's, bind-mounted by the Dockerfile; empty locally):
# it seeds a build/ cache that holds no state of its own.
BUILD_STATE_SEED = Path("/docker-ros/build-state")
LOG = logging.getLogger(__name__)
_FAILED = re.compile(r"^Failed\s+<<<\s+(\S+)")
# console_cohesion's block of a package's output (and console_stderr's of its stderr)
_OUTPUT_BLOCK = re.compile(r"^--- (?:output|stderr): (\S+)$")
# CMake's words for a find_package() that found nothing
_NOT_FOUND = re.compile(r"\(find_package\)|Could NOT find|Could not find a package configuration")
ERRORS_SHOWN = 2  # error lines in the one-line message; the whole output is above it
SEE_ABOVE = "; see the output above"  # the end of a failed build's message
# build types whose build folder holds copies of the sources, not compiled objects
PYTHON_BUILD_TYPES = ("ament_python", "python")


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


def stamp_changed_sources(ws: Workspace) -> Tuple[Dict[str, List[object]], Set[str]]:
    """In the image, build/ is a cache mount reused across builds, while file times come from
    COPY (the context's times) or from a fresh clone (now). Make decides by time, so: every
    file whose content changed since the last successful build gets the current time, every
    other file the time it had then (a re-imported repository must not look newer than its
    objects). Returns the record ({path: [sha256, mtime]}) to write after the build, and the
    files added, changed or removed since the last one."""
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
    removed = set(old_hashes) - set(new)
    return stamped, changed | removed


def owner(path: str, package_dirs: Mapping[str, str]) -> Optional[str]:
    """The package (name -> directory, relative to src) holding a file, or None."""
    best: Optional[str] = None
    for name, directory in package_dirs.items():
        if path.startswith(directory + "/") and (best is None
                                                  or len(directory) > len(package_dirs[best])):
            best = name
    return best


def incremental_selection(previous: Mapping[str, object], current: Mapping[str, object],
                          changed: Set[str], package_dirs: Mapping[str, str]
                          ) -> Tuple[Optional[List[str]], str]:
    """The changed packages, for `colcon build --packages-above` (they and their dependents)
    over the install space of the last build, or None and why only a full build is right."""
    if not previous:
        return None, "no build state (first build with this cache)"
    differs = [(k, why) for k, why in (
        ("platform", "the build state is for another platform"),
        ("argv", "the colcon arguments (CMAKE_ARGS, ignored packages) changed"),
        ("environment", "the dependencies changed"),
        ("packages", "the package set changed")) if previous.get(k) != current.get(k)]
    if differs:
        return None, differs[0][1]
    if previous != current:
        return None, "the build state's record is of another version"
    owners = {owner(path, package_dirs) for path in changed}
    if None in owners:
        outside = sorted(p for p in changed if owner(p, package_dirs) is None)
        return None, f"{outside[0]} changed outside every package"
    return sorted(o for o in owners if o), ""


def stale_outputs(root: Path, packages: Sequence[Package], built: Optional[Set[str]],
                  restored: bool) -> List[Path]:
    """What to delete before building the packages colcon builds (built None: all) so that a
    file gone from the sources is gone from the install space too: a Python package's build
    folder (setuptools copies build/<pkg>/build/lib/ whole into the install space, so a
    deleted module would stay in it), and over a restored install space the built packages'
    own install folders (colcon's isolated layout; no build removes files it no longer
    installs). CMake packages keep their build folders: nothing recompiles."""
    chosen = [p for p in packages if built is None or p.name in built]
    stale = [root / "build" / p.name for p in chosen if p.build_type in PYTHON_BUILD_TYPES]
    layout = root / "install" / ".colcon_install_layout"
    if restored and layout.is_file() and layout.read_text().strip() == "isolated":
        stale += [root / "install" / p.name for p in chosen]
    return [path for path in stale if path.exists()]


def seed_build_state(cache: Path, seed: Path) -> None:
    """A build/ cache without a record of its own starts from the seed's state, if it has one."""
    if (cache / INSTALL_RECORD).is_file() or not (seed / INSTALL_RECORD).is_file():
        return
    LOG.info("%s: the build cache is empty: starting from the pulled build state", STEP)
    run(["cp", "-a", f"{seed}/.", str(cache)], step=STEP)


def dependents(selected: Sequence[str], packages: Sequence[Package]) -> Set[str]:
    """The selected packages and every package depending on them, recursively (as colcon's
    --packages-above, over all dependency kinds)."""
    found = set(selected)
    grew = True
    while grew:
        grew = False
        for package in packages:
            keys = {k for keys in package.depends.values() for k in keys}
            if package.name not in found and keys & found:
                found.add(package.name)
                grew = True
    return found


def environment_digest(ws: Workspace) -> str:
    """What the build runs on: the installed apt packages and the resolution (pip, hooks...)."""
    digest = hashlib.sha256()
    for path in [DPKG_STATUS, *sorted(ws.state.glob("**/*"))]:
        if path.is_file():
            digest.update(str(path).encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def failed_packages(lines: Sequence[str]) -> List[str]:
    """Packages colcon reports as `Failed   <<< pkg [...]`."""
    out = []
    for line in lines:
        match = _FAILED.match(line.strip())
        if match and match.group(1) not in out:
            out.append(match.group(1))
    return out


def error_lines(lines: Sequence[str], packages: Sequence[str]) -> List[str]:
    """The error lines of the compiler, linker or CMake in the output colcon printed for the
    packages (console_cohesion's `--- output: pkg` blocks), each once, in order. A CMake error
    comes with the first paragraph of its explanation (`By not providing "Findfoo.cmake"...`)."""
    found: List[str] = []
    current: Optional[str] = None
    for index, line in enumerate(lines):
        header = _OUTPUT_BLOCK.match(line)
        if header or line == "---":
            current = header.group(1) if header and header.group(1) in packages else None
            continue
        if current is None or not ERROR_LINE.search(line):
            continue
        text = line.strip()
        if text.startswith("CMake Error"):
            paragraph = []
            for following in lines[index + 1:]:
                if not following.startswith("  ") or not following.strip():
                    break
                paragraph.append(following.strip())
            text = " ".join([text, *paragraph])
        if text not in found:
            found.append(text)
    return found


def shown_errors(errors: Sequence[str], ws: Workspace, limit: int = ERRORS_SHOWN) -> str:
    """The first error lines for the one-line message: paths in the workspace shortened (the
    repository's relative to it, as the user knows them), each at most 300 characters."""
    shown = []
    for text in errors[:limit]:
        for prefix in (f"{ws.target}/", f"{ws.root}/"):
            text = text.replace(prefix, "")
        shown.append(text if len(text) <= 300 else text[:297] + "...")
    more = len(errors) - len(shown)
    return " | ".join(shown) + (f" (and {more} more error line{'s' * (more > 1)})" if more else "")


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: object,
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
        if not options.get("stamp_changed"):
            build(ws, argv, env)
            return
        cache = ws.root / "build"
        seed_build_state(cache, BUILD_STATE_SEED)
        stamps, changed = stamp_changed_sources(ws)
        packages = find_packages(ws, settings, step=STEP)
        package_dirs = {p.name: p.path.relative_to(ws.src).as_posix() for p in packages}
        current = {"argv": argv, "environment": environment_digest(ws), "packages": package_dirs,
                   "platform": platform.machine()}
        record = cache / INSTALL_RECORD
        previous = json.loads(record.read_text()) if record.is_file() else {}
        selected, why = incremental_selection(previous, current, changed, package_dirs)
        if selected is not None and not (cache / INSTALL_COPY).is_dir():
            selected, why = None, "the build state has no install space"
        if selected is not None:
            restore_install(ws, cache / INSTALL_COPY)
            rebuilt = dependents(selected, packages) - set(ignore)
            if rebuilt:
                LOG.info("%s: %s changed: building them and their dependents only", STEP,
                         ", ".join(selected))
                remove(stale_outputs(ws.root, packages, rebuilt, restored=True))
                build(ws, [*argv, "--packages-above", *selected], env)
            else:
                LOG.info("%s: no package changed, the install space is the last build's", STEP)
        else:
            LOG.info("%s: full build: %s", STEP, why)
            rebuilt = None
            remove(stale_outputs(ws.root, [p for p in packages if p.name not in ignore], None,
                                 restored=False))
            build(ws, argv, env)
        # Only after success: a failed build must find the same files changed next time.
        keep_install(ws, cache / INSTALL_COPY, rebuilt)
        record.write_text(json.dumps(current, sort_keys=True))
        (cache / STAMP_FILE).write_text(json.dumps(stamps, sort_keys=True))


def build(ws: Workspace, argv: Sequence[str], env: Optional[Mapping[str, str]] = None) -> None:
    returncode, lines = run_tee(argv, step=STEP, cwd=ws.root, env=env)
    if returncode != 0:
        raise StepError(STEP, failure_message(ws, lines, returncode), returncode)


def failure_message(ws: Workspace, lines: Sequence[str], returncode: int) -> str:
    """What failed, for the one-line error: the packages colcon names and the first error
    lines of their output (in an image build, the rest is far above, between BuildKit's)."""
    failed = failed_packages(lines)
    what = (("package " + ", ".join(failed) + " failed to build") if failed
            else "colcon build failed")
    errors = error_lines(lines, failed)
    cause = f": {shown_errors(errors, ws)}" if errors else ""
    if any(_NOT_FOUND.search(error) for error in errors[:ERRORS_SHOWN]):
        cause += ("; a dependency CMake cannot find is installed when the package.xml declares "
                  "it (<depend>, <build_depend>: rosdep installs it) or ADDITIONAL_DEBS_FILE "
                  "lists it")
    return f"{what} (exit code {returncode}){cause}{SEE_ABOVE}"


def remove(paths: Sequence[Path]) -> None:
    if paths:
        run(["rm", "-rf", *(str(p) for p in paths)], step=STEP)


def restore_install(ws: Workspace, copy: Path) -> None:
    """The last build's install space, as the start of an incremental build."""
    install = ws.root / "install"
    if install.exists():
        run(["rm", "-rf", str(install)], step=STEP)
    run(["cp", "-a", str(copy), str(install)], step=STEP)


def keep_install(ws: Workspace, copy: Path, rebuilt: Optional[Set[str]]) -> None:
    """Keep the install space in the cache: all of it (rebuilt None), or the rebuilt packages'
    folders and colcon's top-level files."""
    install = ws.root / "install"
    if rebuilt is None or not copy.is_dir():
        run(["rm", "-rf", str(copy)], step=STEP)
        run(["cp", "-a", str(install), str(copy)], step=STEP)
        return
    entries = [e for e in sorted(install.iterdir()) if not e.is_dir() or e.name in rebuilt]
    run(["rm", "-rf", *(str(copy / e.name) for e in entries)], step=STEP)
    run(["cp", "-a", *(str(e) for e in entries), str(copy)], step=STEP)
