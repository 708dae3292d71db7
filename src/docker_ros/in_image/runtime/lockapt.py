"""apt under docker-ros.lock: the closure apt would install, the versions prepare installed,
the preferences holding them, and whether apt's sources still have them."""

import os
import re
from pathlib import Path
from typing import Any, Dict, List, Mapping, Sequence

from docker_ros.core.loading import host_platform
from docker_ros.in_image.runtime.apt import (
    DPKG_STATUS,
    apt_env,
    apt_get,
    apt_install,
    apt_lists_present,
)
from docker_ros.in_image.runtime.lockfile import (
    dump_lock,
    load_lock,
    locked_target,
    require_locked,
    target_key,
)
from docker_ros.in_image.runtime.process import probe
from docker_ros.in_image.runtime.workspace import StepError

# `apt-get install -s`: "Inst name [old] (version suite [arch])"
APT_INST = re.compile(r"^Inst (\S+) (?:\[[^\]]*\] )?\((\S+) ([^\[)]*)")


def apt_name(spec: str) -> str:
    """The package name of an apt spec (`pkg`, `pkg=1.2`, `pkg/bookworm`, `pkg:arm64`)."""
    return re.split(r"[=/]", spec, maxsplit=1)[0]


def parse_apt_simulation(lines: Sequence[str]) -> Dict[str, str]:
    """name -> version of every package `apt-get install -s` would install (dependencies too)."""
    found: Dict[str, str] = {}
    for line in lines:
        match = APT_INST.match(line)
        if match:
            found[match.group(1)] = match.group(2)
    return found


def apt_pins(packages: Sequence[str], locked: Mapping[str, str]) -> List[str]:
    """`name=version` for the packages and everything the lock recorded apt pulling in with
    them, so that dependencies are held at their locked versions as well."""
    require_locked("apt", [apt_name(p) for p in packages], locked)
    return [f"{name}={version}" for name, version in sorted(locked.items())]


# where a locked build's prepare holds apt to the lock's versions (runtime/prepare.py; removed
# again before the layer ends)
LOCK_PREFERENCES = Path("/etc/apt/preferences.d/docker-ros-lock")


def installed_records(text: str) -> Dict[str, Dict[str, str]]:
    """name -> fields (Version, Depends, Provides...) of every installed package in a dpkg
    status file."""
    installed: Dict[str, Dict[str, str]] = {}
    for paragraph in text.split("\n\n"):
        fields = {key: value.strip() for key, _, value in
                  (line.partition(":") for line in paragraph.splitlines()
                   if ":" in line and not line[:1].isspace())}
        if fields.get("Status", "").endswith(" installed") and "Package" in fields:
            installed[fields["Package"]] = fields
    return installed


def parse_dpkg_status(text: str) -> Dict[str, str]:
    """name -> version of every installed package in a dpkg status file."""
    return {name: fields.get("Version", "") for name, fields in installed_records(text).items()}


def relation_names(field: str) -> List[List[str]]:
    """A Depends-style field's package names: one list of alternatives per relation (version
    constraints and architecture qualifiers left out)."""
    return [[re.split(r"[\s(:]", alternative.strip(), maxsplit=1)[0]
             for alternative in relation.split("|")]
            for relation in field.split(",") if relation.strip()]


def installed_closure(packages: Sequence[str], text: str) -> Dict[str, str]:
    """name -> installed version of the packages and of what they depend on (Depends and
    Pre-Depends, recursively) in a dpkg status file: of alternatives and virtual packages,
    the installed one that satisfies them. Names not installed are left out."""
    records = installed_records(text)
    providers: Dict[str, str] = {}
    for name, fields in sorted(records.items()):
        for (provided, *_) in relation_names(fields.get("Provides", "")):
            providers.setdefault(provided, name)
    found: Dict[str, str] = {}
    queue = [apt_name(package) for package in packages]
    while queue:
        name = queue.pop()
        name = name if name in records else providers.get(name, "")
        if not name or name in found:
            continue
        fields = records[name]
        found[name] = fields.get("Version", "")
        for field in ("Pre-Depends", "Depends"):
            for alternatives in relation_names(fields.get(field, "")):
                chosen = [a for a in alternatives if a in records or a in providers]
                queue.extend(chosen[:1])
    return dict(sorted(found.items()))


def read_dpkg_status(path: Path = DPKG_STATUS) -> Dict[str, str]:
    """The installed packages of a dpkg status file; none when there is no file (no dpkg)."""
    return parse_dpkg_status(path.read_text(errors="replace")) if path.is_file() else {}


def installed_over(before: Mapping[str, str], after: Mapping[str, str]) -> Dict[str, str]:
    """name -> version of each package installed, or at another version, since `before`."""
    return {name: version for name, version in sorted(after.items())
            if before.get(name) != version}


def lean_entry(entry: Mapping[str, Any], lean: Sequence[str], status_text: str
               ) -> Dict[str, Any]:
    """A locked run entry for ENABLE_LEAN_RUN_IMAGE (made in the lean-resolve stage, the locked
    dev image's state, status_text its dpkg status): rosdep's exec apt set is the lean one,
    and apt installs it and the debs with all they depend on at the versions the dev image
    holds, which are the lock's."""
    inputs = {**(entry.get("inputs") or {}), "rosdep_apt_exec": sorted(lean)}
    wanted = [*lean, *(inputs.get("debs") or [])]
    return {**entry, "inputs": inputs, "apt": installed_closure(wanted, status_text)}


def lock_lean(path: Path, lean: Sequence[str]) -> None:
    """Rewrite the run entry of this platform in the resolution's copy of the lock (path) for
    the lean run image (lean_entry)."""
    lock = load_lock(path)
    entry = locked_target(lock, "run", host_platform())
    lock["targets"][target_key("run", host_platform())] = lean_entry(
        entry, lean, DPKG_STATUS.read_text())
    path.write_text(dump_lock(lock))


PREFERENCES_HEADER = "# docker-ros.lock, what prepare installs at its locked version\n"


def apt_preferences(pins: Mapping[str, str]) -> str:
    """An apt preferences file that holds each package at its locked version, whatever pulls
    it in (priority 1001: also when the sources offer a newer one, or it is installed newer).
    Never empty (a first comment line): an empty file is no lock (a mount's leftover stub)."""
    return PREFERENCES_HEADER + "".join(
        f"Package: {name}\nPin: version {version}\nPin-Priority: 1001\n\n"
        for name, version in sorted(pins.items()))


def parse_apt_preferences(text: str) -> Dict[str, str]:
    """name -> version of the version pins of an apt preferences file (apt_preferences)."""
    pins: Dict[str, str] = {}
    for paragraph in text.split("\n\n"):
        fields = dict(line.split(": ", 1) for line in paragraph.splitlines() if ": " in line)
        if "Package" in fields and fields.get("Pin", "").startswith("version "):
            pins[fields["Package"]] = fields["Pin"][len("version "):]
    return pins


def unlocked_installs(pins: Mapping[str, str], before: Mapping[str, str],
                      after: Mapping[str, str]) -> List[str]:
    """What an install held to the lock (`pins`) did otherwise: each package it installed that
    the lock lacks, each locked package not installed at its locked version."""
    problems = [f"{name} {version} (not in docker-ros.lock)"
                for name, version in installed_over(before, after).items() if name not in pins]
    problems += [f"{name}={version} ({'installed ' + after[name] if name in after else 'missing'})"
                 for name, version in sorted(pins.items()) if after.get(name) != version]
    return problems


def apt_closure(packages: Sequence[str], *, step: str = "lock", update: bool = False
                ) -> Dict[str, str]:
    """name -> version of the packages and every package apt would install with them, where
    this runs (`--reinstall`: named packages already installed are listed too); `update`:
    fresh package lists first (an image's lists come from a cache mount that may be old)."""
    if not packages:
        return {}
    if update:
        probe(apt_get(["update"]), step=step, env=apt_env())
    argv = ["apt-get", "install", "-s", "--reinstall", "--no-install-recommends", *packages]
    proc = probe(argv, step=step, env={**os.environ, "LC_ALL": "C"})
    if proc.returncode != 0:
        raise StepError(step, f"apt cannot resolve {' '.join(packages)}: "
                        f"{proc.stderr.strip().splitlines()[-1:] or proc.returncode}")
    return parse_apt_simulation(proc.stdout.splitlines())


# apt's words for a locked version it cannot find
APT_MISSING_VERSION = re.compile(r"Version '([^']+)' for '([^']+)' was not found")


def apt_sources(root: Path = Path("/etc/apt")) -> List[str]:
    """The URIs and suites apt installs from (one-line and deb822 sources)."""
    found: List[str] = []
    for path in [root / "sources.list", *sorted((root / "sources.list.d").glob("*"))]:
        if not path.is_file():
            continue
        text = path.read_text(errors="replace")
        found += [" ".join(line.split()[1:3]) for line in text.splitlines()
                  if line.startswith("deb ")]
        uris = re.findall(r"^URIs:\s*(.+)$", text, flags=re.MULTILINE)
        suites = re.findall(r"^Suites:\s*(.+)$", text, flags=re.MULTILINE)
        found += [f"{u.strip()} {s.strip()}" for u, s in zip(uris, suites)]
    return found


def missing_versions(apt_output: str) -> List[str]:
    """`name=version` of each locked version apt says it cannot find."""
    return [f"{name}={version}" for version, name in APT_MISSING_VERSION.findall(apt_output)]


def check_available(pins: Sequence[str], *, step: str) -> None:
    """Stop before installing when apt's sources no longer hold a locked version, naming each
    package, its version and the sources (after fresh lists: old ones may hide it)."""
    if not pins:
        return
    argv = ["apt-get", "install", "-s", "--no-install-recommends", *pins]
    for attempt in range(2):
        if attempt or not apt_lists_present():
            probe(apt_get(["update"]), step=step, env=apt_env())
        proc = probe(argv, step=step, env={**os.environ, "LC_ALL": "C"})
        missing = missing_versions(proc.stderr + proc.stdout)
        if not missing:
            return
    raise StepError(step, f"LOCKED: {', '.join(missing)} no longer available from apt's "
                    f"sources ({'; '.join(apt_sources()) or 'none configured'}): the archive "
                    "dropped the locked version; run `inv lock` to lock what it has now")


def python_debs(closure: Mapping[str, str]) -> List[str]:
    """`name=version` of the Python packages (python3-*, python-*) of an apt closure."""
    return [f"{name}={version}" for name, version in sorted(closure.items())
            if name.startswith(("python3-", "python-"))]


def install_python_debs(closure: Mapping[str, str]) -> None:
    """Install the closure's Python packages where the lock stage resolves pip, as the image's
    apt installs come before its pip step: a requirement a Debian package satisfies is then
    none of pip's, in the lock as in an unlocked build (else the lock would hold the index's
    newest version, and a locked build would install it over Debian's)."""
    debs = python_debs(closure)
    if debs:
        apt_install(debs, step="lock", dry_run=False,
                    what="installing the apt closure's Python packages (for pip's dry run)")
