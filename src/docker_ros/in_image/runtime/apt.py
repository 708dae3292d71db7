"""apt-get, non-interactive and with the build's caches.
Standard library only, Python 3.8+ (runs inside images)."""

import glob
import os
import re
from pathlib import Path
from typing import Dict, List, Mapping, Optional, Sequence

from docker_ros.in_image.runtime.process import hook_context, is_root, run, run_tee
from docker_ros.in_image.runtime.workspace import LOG, StepError, format_argv

# apt's words for a package it does not know (the name in one of the groups)
MISSING = re.compile(r"^E: (?:Unable to locate package (\S+)|Package '([^']+)' has no "
                     r"installation candidate|Version '([^']+)' for '([^']+)' was not found)")
# apt's line for a source or file it could not download: `W: Failed to fetch URL  reason`
# (`E:` when installing)
FETCH_FAILED = re.compile(r"^[WE]: Failed to fetch (\S+)\s+(.*)$")
# dpkg's record of what is installed
DPKG_STATUS = Path("/var/lib/dpkg/status")


def apt_env() -> Dict[str, str]:
    env = dict(os.environ)
    env["DEBIAN_FRONTEND"] = "noninteractive"
    return env


def apt_get(args: Sequence[str]) -> List[str]:
    """apt-get argv, non-interactive also through sudo (which resets the environment)."""
    if is_root():
        return ["apt-get", *args]
    return ["sudo", "DEBIAN_FRONTEND=noninteractive", "apt-get", *args]


def apt_lists_present(lists_dir: Path = Path("/var/lib/apt/lists")) -> bool:
    """Whether apt has package lists (images usually delete them: then `apt-get update` first)."""
    return bool(glob.glob(str(lists_dir / "*_Packages*")))


def install_options(context: str) -> List[str]:
    """apt-get install options for where it runs (hook_context). In an image, dpkg skips its
    fsync calls (--force-unsafe-io, as Docker's own Debian images build): a crash loses only
    a layer that is built again, while on overlayfs the syncs cost a large share of the
    install time. Never on the host, whose package database a crash could leave broken."""
    options = ["-y", "--no-install-recommends"]
    if context == "image":
        options += ["-o", "Dpkg::Options::=--force-unsafe-io"]
    return options


def apt_install(packages: Sequence[str], *, step: str, dry_run: bool, what: str = "",
                origins: Optional[Mapping[str, str]] = None) -> None:
    """apt-get install, updating the lists when absent or stale (origins: where a package
    comes from, for the error naming one apt does not have, e.g. its rosdep key)."""
    if not packages:
        LOG.info("%s: no apt packages to install", step)
        return
    install = apt_get(["install", *install_options(hook_context()), *packages])
    update = apt_get(["update"])
    if dry_run:
        if not apt_lists_present():
            run(update, step=step, dry_run=True)
        run(install, step=step, dry_run=True)
        return
    updated: List[str] = []
    if not apt_lists_present():
        updated = apt_update(update, step=step, what=what)
    code, lines = run_tee(install, step=step, env=apt_env())
    if code != 0 and not unreachable(updated):
        # Stale lists (host, or an apt cache mount) make apt miss packages: update once, retry
        # (not when the update just now could not download them: no network).
        LOG.info("%s: apt-get install failed, updating package lists and retrying", step)
        updated = apt_update(update, step=step, what=what)
        code, lines = run_tee(install, step=step, env=apt_env())
    if code != 0:
        raise StepError(step, f"{what + ' ' if what else ''}failed with exit code {code}: "
                        f"{format_argv(install)}{apt_reason(lines, updated, origins)}", code)


def apt_update(update: Sequence[str], *, step: str, what: str) -> List[str]:
    """apt-get update; its output lines (apt_reason reads the sources it could not reach)."""
    code, lines = run_tee(update, step=step, env=apt_env())
    if code != 0:
        raise StepError(step, f"{what + ' ' if what else ''}failed with exit code {code}: "
                        f"{format_argv(update)}{apt_reason(lines)}", code)
    return lines


def unreachable(lines: Sequence[str]) -> List[str]:
    """`URL (apt's reason)` of each source `apt-get update` could not fetch: apt warns
    (`W: Failed to fetch URL  reason`), goes on with the lists it has, and exits 0."""
    found = []
    for line in lines:
        match = FETCH_FAILED.search(line)
        if match:
            found.append(f"{match.group(1)} ({match.group(2).strip()})")
    return list(dict.fromkeys(found))


def apt_reason(lines: Sequence[str], update_lines: Sequence[str] = (),
               origins: Optional[Mapping[str, str]] = None) -> str:
    """apt's own reason, for the one-line error: the packages it cannot find, each with its
    origin (origins: package name -> where it comes from), and the sources `apt-get update`
    could not reach, which may have them; else its first `Failed to fetch` line (a download
    that failed; its last line only says to run `apt-get update`), else its last `E:` line
    ('' when it gave none)."""
    found = [m.groups() for m in map(MISSING.search, lines) if m]
    missing = [name or candidate or f"{package}={version}"
               for name, candidate, version, package in found]
    origins = origins or {}
    traced = [name for name in missing if name.split("=")[0] in origins]  # (name=version)
    missing = [f"{name} ({origins[name.split('=')[0]]})" if name in traced else name
               for name in missing]
    failed = unreachable(update_lines)
    if missing and failed:
        return (f"; apt has no package {', '.join(dict.fromkeys(missing))}, and `apt-get "
                f"update` could not reach {'; '.join(failed[:3])}: check that apt source and "
                "the network (BUILD_NETWORK, a proxy), or the package's name")
    if missing:
        # (origins come from the rosdep step: a rule of its key gave the name)
        check = "the rosdep rule" if traced else "the name"
        pinned = [package for _, _, version, package in found if version]
        if pinned:  # `name=version`: apt knows the name, not that version
            check += (f", or the version: `apt-cache policy {' '.join(dict.fromkeys(pinned))}` "
                      "lists those apt has")
        return (f"; apt has no package {', '.join(dict.fromkeys(missing))} (check {check}, "
                "and the apt sources of the base image)")
    fetch = [line[3:].strip() for line in lines
             if line.startswith("E: ") and FETCH_FAILED.search(line)]
    errors = fetch or [line[3:].strip() for line in lines if line.startswith("E: ")][-1:]
    return f"; apt: {errors[0]}" if errors else ""
