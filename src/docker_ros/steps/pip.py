"""pip: install the extra pip requirements listed in ADDITIONAL_PIP_FILE(s).

Each requirement is one argv item (`pkg>=1.2`, `pkg[extra]`, `pkg; python_version>"3"`):
no shell ever sees them. Lines starting with `-` are pip options (`--extra-index-url URL`)
and are split like a shell would, but still passed as an argv list."""

import json
import os
import re
import shlex
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

from docker_ros.runtime.files import collect_list_entries, unique
from docker_ros.runtime.lock import locked_arguments
from docker_ros.runtime.process import is_root, probe, run, run_tee
from docker_ros.runtime.workspace import LOG, StepError, Workspace, format_argv, phases, step_log
from docker_ros.settings import Settings

STEP = "pip"
STATE_FILE = "pip.json"
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


def requirement_arguments(entries: Sequence[str]) -> List[str]:
    """pip argv items for requirement-file lines: one item per requirement, options split."""
    args: List[str] = []
    for entry in entries:
        if entry.startswith("-"):
            args.extend(shlex.split(entry))
            continue
        # Per-requirement options (`pkg==1 --hash=sha256:...`) follow the requirement.
        match = re.search(r"\s+(--\S.*)$", entry)
        if match:
            args.append(entry[: match.start()])
            args.extend(shlex.split(match.group(1)))
        else:
            args.append(entry)
    return args


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
    if returncode != 0:
        tls = [tls_failure(line) for line in lines if tls_failure(line)]
        cause = tls[0] if tls else (lines[-1].strip() if lines else "no output")
        raise StepError(step, f"{what + ' ' if what else ''}failed with exit code {returncode}: "
                        f"{format_argv(argv)}: {cause}", returncode or 1)


def tls_failure(line: str) -> str:
    """The cause and what to do, when a pip output line says TLS verification failed (pip would
    retry for minutes; a proxy that re-signs HTTPS does not go away by retrying)."""
    if "CERTIFICATE_VERIFY_FAILED" not in line:
        return ""
    host = re.search(r"host='([^']+)'", line)
    return ("TLS certificate verification failed (CERTIFICATE_VERIFY_FAILED"
            + (f", {host.group(1)}" if host else "") + "): if HTTPS goes through a proxy that "
            "re-signs it, set EXTRA_CA_CERTS to the proxy's CA certificate (PEM file or folder)")


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: str,
) -> None:
    """collect: read the requirement file(s) into pip.json; apply: pip install them."""
    do_collect, do_apply = phases(STEP, phase)
    with step_log(STEP):
        plan: Dict[str, Any] = {}
        if do_collect:
            entries, _ = collect_list_entries(ws, STEP, settings, "additional_pip_file")
            plan = {"requirements": unique(entries)}
            ws.save_plan(STEP, STATE_FILE, plan, dry_run=dry_run)
        if do_apply:
            if not do_collect:
                plan = ws.load_plan(STEP, STATE_FILE)
            requirements = list(plan.get("requirements") or [])
            arguments = locked_arguments(ws, settings, step=STEP, kind="pip",
                                         inputs=requirements) or requirement_arguments(requirements)
            pip_install(
                arguments,
                step=STEP,
                dry_run=dry_run,
                what="installing ADDITIONAL_PIP_FILE requirements",
            )
