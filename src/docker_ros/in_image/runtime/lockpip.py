"""pip under docker-ros.lock: what pip would install (its dry-run report), the constraint
lines of a locked install, and whether pip's sources still have the locked versions."""

import json
import os
import re
import subprocess
import tempfile
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence

from docker_ros.in_image.runtime.pipinstall import (
    install_flags,
    probe_python,
    python_command,
    requirement_files,
)
from docker_ros.in_image.runtime.process import is_root, probe
from docker_ros.in_image.runtime.workspace import StepError

PIP_NAME = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)")


def pip_name(requirement: str) -> str:
    """The normalised project name of a requirement (PEP 503)."""
    match = PIP_NAME.match(requirement)
    return re.sub(r"[-_.]+", "-", match.group(1)).lower() if match else requirement


def parse_pip_report(report: Mapping[str, Any]) -> Dict[str, Dict[str, str]]:
    """name -> {version, sha256} from `pip install --dry-run --report` (pip >= 22.2)."""
    found: Dict[str, Dict[str, str]] = {}
    for item in report.get("install") or []:
        meta = item.get("metadata") or {}
        entry = {"version": str(meta.get("version", ""))}
        hashes = ((item.get("download_info") or {}).get("archive_info") or {}).get("hashes") or {}
        if hashes.get("sha256"):
            entry["sha256"] = hashes["sha256"]
        found[pip_name(str(meta.get("name", "")))] = entry
    return found


def pip_constraints(locked: Mapping[str, Mapping[str, str]]) -> Optional[List[str]]:
    """The constraint lines (`name==version`) under which a locked step installs its pip
    requirements as written: every package pip installs for them, dependencies included, at
    its locked version (a requirement satisfied where the lock was written, so not in its
    report, is left to the locked system). None when the lock recorded no pip version at all
    (no report): the checked requirements are installed unconstrained."""
    lines = [f"{name}=={entry['version']}" for name, entry in sorted(locked.items())
             if entry.get("version")]
    return lines or None


def pip_dry_run(requirements: Sequence[str], constraints: Sequence[str], options: Sequence[str],
                *, step: str) -> "subprocess.CompletedProcess[str]":
    """`pip install --dry-run -r` of the requirement lines under the constraint lines, with
    the flags the pip step would use where this runs (PEP 668, --user)."""
    python = python_command()
    flags = install_flags(probe_python(python, step=step), root=is_root())
    with tempfile.TemporaryDirectory(prefix="docker-ros-lock-pip-") as tmp:
        path = requirement_files(Path(tmp), requirements, constraints)
        return probe([python, "-m", "pip", "install", "--dry-run", *options, *flags,
                      "-r", str(path)], step=step)


def pip_report(requirements: Sequence[str], constraints: Sequence[str] = (), *,
               step: str = "lock") -> Dict[str, Dict[str, str]]:
    """name -> {version, sha256} of what `pip install -r` of the requirement lines (under the
    constraint lines) would install where this runs (`--dry-run --report`, pip >= 22.2)."""
    if not requirements:
        return {}
    proc = pip_dry_run(requirements, constraints, ["--quiet", "--report", "-"], step=step)
    try:
        report = json.loads(proc.stdout)
    except ValueError:
        raise StepError(step, f"pip cannot resolve {', '.join(requirements)} (exit code "
                        f"{proc.returncode}): {proc.stderr.strip().splitlines()[-1:]}") from None
    return parse_pip_report(report)


# pip's words for a requirement no version of which it can install
PIP_NO_MATCH = re.compile(r"No matching distribution found for ([A-Za-z0-9][A-Za-z0-9._-]*)")
PIP_SOURCE = re.compile(r"(?:--index-url|--extra-index-url|--find-links|-i|-f)[ =]+(\S+)")


def pip_sources(requirements: Sequence[str], environ: Optional[Mapping[str, str]] = None
                ) -> List[str]:
    """Where pip looks: the requirement files' index and find-links options, pip's environment
    variables, else PyPI."""
    env = os.environ if environ is None else environ
    found = [m for line in requirements if line.startswith("-") for m in PIP_SOURCE.findall(line)]
    found += [env[v] for v in ("PIP_INDEX_URL", "PIP_EXTRA_INDEX_URL", "PIP_FIND_LINKS")
              if env.get(v)]
    if not any("--index-url" in line or line.startswith("-i") or "--no-index" in line
               for line in requirements) and not env.get("PIP_INDEX_URL"):
        found.append("https://pypi.org/simple (pip's default index)")
    return found


# with constraints pip says ResolutionImpossible, naming the constraints it could not meet
PIP_CONSTRAINT = re.compile(r"The user requested \(constraint\) ([A-Za-z0-9][A-Za-z0-9._-]*)==")


def unavailable_pins(pip_stderr: str, constraints: Sequence[str]) -> List[str]:
    """The locked `name==version` lines pip could not meet: no distribution found for the
    requirement, or (under the constraints) no version matching the locked one."""
    pinned = {pip_name(line): line for line in constraints}
    names = PIP_NO_MATCH.findall(pip_stderr)
    if "ResolutionImpossible" in pip_stderr:
        names += PIP_CONSTRAINT.findall(pip_stderr)
    return sorted({pinned[pip_name(n)] for n in names if pip_name(n) in pinned})


def check_pip_available(requirements: Sequence[str], constraints: Sequence[str], *,
                        step: str) -> None:
    """Stop before installing when pip's sources no longer hold a locked version, naming each
    package, its version and the sources (another failure is left to the install to report)."""
    if not requirements or not constraints:
        return
    proc = pip_dry_run(requirements, constraints, [], step=step)
    missing = unavailable_pins(proc.stdout + proc.stderr, constraints) if proc.returncode else []
    if missing:
        raise StepError(step, f"LOCKED: {', '.join(missing)} no longer available from pip's "
                        f"sources ({'; '.join(pip_sources(requirements))}): run `inv lock` to "
                        "lock what they have now")
