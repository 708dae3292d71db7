"""pip where the steps run: the ROS environment's python3, the flags it needs (PEP 668, --user),
requirement files, installs and pip's reason for a failure."""

import json
import os
import re
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

from docker_ros.in_image.runtime.process import ERROR_LINE, is_root, probe, run, run_tee
from docker_ros.in_image.runtime.workspace import (
    LOG,
    StepError,
    format_argv,
)

PYTHON_ENV = "DOCKER_ROS_PYTHON"
# pip learnt --break-system-packages (PEP 668) in 23.0.1.
BREAK_SYSTEM_PACKAGES_SINCE = (23, 0, 1)

# Runs in the target interpreter (any Python 3): what decides pip's flags.
PROBE = """
import json, os, sys, sysconfig
venv = sys.prefix != getattr(sys, "base_prefix", sys.prefix)
marker = os.path.join(sysconfig.get_path("stdlib"), "EXTERNALLY-MANAGED")
try:
    import pip
    version = pip.__version__
except Exception:
    version = None
print(json.dumps({"externally_managed": os.path.isfile(marker) and not venv,
                  "in_venv": venv, "pip": version}))
"""


def python_command(environ: Optional[Mapping[str, str]] = None) -> str:
    """The ROS environment's python3 from PATH (DOCKER_ROS_PYTHON overrides, for tests)."""
    env = os.environ if environ is None else environ
    return env.get(PYTHON_ENV) or "python3"


def requirement_files(
    directory: Path, requirements: Sequence[str], constraints: Sequence[str]
) -> Path:
    """requirements.txt in `directory` with the lines (and -c constraints.txt when any)."""
    lines = list(requirements)
    if constraints:
        (directory / "constraints.txt").write_text("\n".join(constraints) + "\n")
        lines.insert(0, "-c constraints.txt")  # (read relative to requirements.txt)
    path = directory / "requirements.txt"
    path.write_text("\n".join(lines) + "\n")
    return path


def version_tuple(version: Optional[str]) -> Tuple[int, ...]:
    parts = []
    for part in (version or "").split("."):
        match = re.match(r"\d+", part)
        if not match:
            break
        parts.append(int(match.group()))
    return tuple(parts)


def install_flags(probe: Mapping[str, Any], *, root: bool) -> List[str]:
    """pip install flags for the target interpreter: PEP 668 and where to install."""
    flags: List[str] = []
    # An older pip predates PEP 668 and installs without asking.
    supported = version_tuple(probe.get("pip")) >= BREAK_SYSTEM_PACKAGES_SINCE
    if probe.get("externally_managed") and supported:
        flags.append("--break-system-packages")
    if not root and not probe.get("in_venv"):
        flags.append("--user")
    return flags


def pip_install_argv(python: str, arguments: Sequence[str], flags: Sequence[str]) -> List[str]:
    return [python, "-m", "pip", "install", *flags, *arguments]


def probe_python(python: str, *, step: str) -> Dict[str, Any]:
    """Ask the interpreter about PEP 668, virtualenv and its pip (read-only; also in dry runs)."""
    proc = probe([python, "-c", PROBE], step=step, hint=f"set {PYTHON_ENV} or PATH")
    try:
        data = json.loads(proc.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        raise StepError(
            step, f"cannot probe {python} (exit code {proc.returncode}): {proc.stderr.strip()}"
        ) from None
    if not data.get("pip"):
        raise StepError(
            step, f"{python} has no pip module: install python3-pip (e.g. in ADDITIONAL_DEBS_FILE)"
        )
    return dict(data)


def pip_install(arguments: Sequence[str], *, step: str, dry_run: bool, what: str = "") -> None:
    """Install requirements (argv items) with the ROS environment's python3 -m pip."""
    if not arguments:
        LOG.info("%s: no pip requirements to install", step)
        return
    python = python_command()
    flags = install_flags(probe_python(python, step=step), root=is_root())
    argv = pip_install_argv(python, arguments, flags)
    if dry_run:
        run(argv, step=step, dry_run=True)
        return
    returncode, lines = run_tee(argv, step=step, on_line=lambda line: bool(tls_failure(line)))
    tls = [tls_failure(line) for line in lines if tls_failure(line)]
    if tls:  # we stopped pip (its exit code is our signal's), it did not fail by itself
        raise StepError(step, f"{what + ' ' if what else ''}stopped at pip's first TLS failure "
                        f"(it retries for minutes): {format_argv(argv)}: {tls[0]}", 1)
    if returncode != 0:
        raise StepError(step, f"{what + ' ' if what else ''}failed with exit code {returncode}: "
                        f"{format_argv(argv)}: {pip_reason(lines)}", returncode)


def pip_reason(lines: Sequence[str]) -> str:
    """pip's reason for the one-line error: its last `ERROR:` line, else its `× ...` summary
    (a package whose metadata could not be made ends with `hint: See above for details.`)
    with the requirement it was collecting; and the failed build's own first error line, else
    its last (`RuntimeError: ...`, `fatal error: Python.h: No such file or directory`)."""
    text = [line.strip() for line in lines if line.strip()]
    if not text:
        return "no output"
    errors = [line for line in text if line.startswith("ERROR: ")]
    summaries = [line[1:].strip() for line in text if line.startswith("×")]
    collecting = [m.group(1) for m in (re.match(r"^(?:Collecting|Processing) (\S+)", line)
                                       for line in text) if m]
    if errors:
        cause = errors[-1][len("ERROR: "):]
    elif summaries:
        cause = summaries[-1].rstrip(".") + (f" ({collecting[-1]})" if collecting else "")
    else:
        cause = text[-1]
    output = build_output(text)
    named = [line for line in output if ERROR_LINE.search(line)]
    shown = named[0] if named else output[-1] if output else ""
    if shown and shown not in cause:
        cause += f"; the build's output says: {shown}"
    return cause


def build_output(text: Sequence[str]) -> List[str]:
    """The lines of the last failed build step pip shows (`╰─> [N lines of output]` ... `[end
    of output]`), stripped."""
    ends = [i for i, line in enumerate(text) if line == "[end of output]"]
    if not ends:
        return []
    starts = [i for i, line in enumerate(text[:ends[-1]]) if line.startswith("╰─> [")]
    return list(text[starts[-1] + 1 if starts else ends[-1]:ends[-1]])


def tls_failure(line: str) -> str:
    """The cause and what to do, when a pip output line says TLS verification failed (pip would
    retry for minutes; a proxy that re-signs HTTPS does not go away by retrying)."""
    if "CERTIFICATE_VERIFY_FAILED" not in line:
        return ""
    host = re.search(r"host='([^']+)'", line)
    return ("TLS certificate verification failed (CERTIFICATE_VERIFY_FAILED"
            + (f", {host.group(1)}" if host else "") + "): if HTTPS goes through a proxy that "
            "re-signs it, set EXTRA_CA_CERTS to the proxy's CA certificate (PEM file or folder)")
