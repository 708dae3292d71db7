"""Running commands and hook scripts: argv lists only, one clear error per failure.
Standard library only, Python 3.8+ (runs inside images)."""

import collections
import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

from docker_ros.in_image.runtime import faults
from docker_ros.in_image.runtime.workspace import LOG, StepError, dry, format_argv

# A line in which a compiler, the linker, make, CMake or Python says what is wrong (not make's
# `*** [...] Error 2`, which only says that something was; GNU ld's `cannot find -lfoo` has no
# `error:`, and collect2's `error: ld returned 1 exit status` after it does not name the library)
ERROR_LINE = re.compile(r"(^|:\s?)(fatal )?[Ee]rror:\s|^CMake Error|undefined reference to|"
                        r"\bld: cannot find |No rule to make target|^\S+Error: ")


def run(
    argv: Sequence[str],
    *,
    step: str,
    dry_run: bool = False,
    cwd: Optional[Path] = None,
    env: Optional[Mapping[str, str]] = None,
    capture: bool = False,
    what: str = "",
) -> str:
    """Run one argv (never a shell string). Raises StepError naming the command and exit code.

    `what` names the file or item at fault in the error (e.g. a script path).
    Returns captured stdout when capture=True.
    """
    shown = format_argv(argv)
    if dry_run:
        dry(step, shown + (f"  (in {cwd})" if cwd else ""))
        return ""
    LOG.info("%s: %s", step, shown)
    full_env = None if env is None else dict(env)
    sys.stdout.flush()
    try:
        # (not captured: its output passes through us, its last lines kept for the error)
        proc = subprocess.Popen(
            executable_argv(argv),
            cwd=str(cwd) if cwd else None,
            env=full_env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE if capture else subprocess.STDOUT,
            universal_newlines=True,
            errors="replace",
        )
    except FileNotFoundError:
        raise StepError(step, f"command not found: {argv[0]} (needed for: {shown})"
                        f"{host_tool_hint(argv[0])}", 127) from None
    tail: collections.deque[str] = collections.deque(maxlen=TAIL_LINES)
    try:
        if capture:
            stdout, stderr = proc.communicate()
        else:
            stdout, stderr = "", ""
            passed_through(proc, tail)
    except BaseException:  # interrupted or terminated: the command does not outlive us
        stop_tree(proc)
        raise
    if proc.returncode != 0:
        detail = ""
        if capture and stderr and stderr.strip():
            detail = ": " + stderr.strip().splitlines()[-1]
        subject = f"{what} " if what else ""
        raise StepError(
            step,
            f"{subject}failed with exit code {proc.returncode}: {shown}{detail}"
            + "".join(f"\n  {line}" for line in fault_lines(list(tail), cwd)),
            proc.returncode,
        )
    return stdout if capture else ""


# How many of a command's last lines are kept for its error message.
TAIL_LINES = 400


def passed_through(proc: "subprocess.Popen[str]", tail: "collections.deque[str]") -> None:
    """Copy the command's output to our stdout as it comes, keeping its last lines in tail."""
    assert proc.stdout is not None
    with proc.stdout:
        for line in proc.stdout:
            sys.stdout.write(line)
            sys.stdout.flush()
            tail.append(line.rstrip("\n"))
    proc.wait()


def fault_lines(lines: Sequence[str], cwd: Optional[Path]) -> List[str]:
    """The lines a failed command's error adds: the tool's own error lines and, on the host,
    a host it could not reach and a full disk with the room left where the step writes (in
    an image, the host names those from the build's log, with the engine's data root)."""
    shown = faults.tool_lines(lines)
    if hook_context() != "host":
        return shown
    url, reason = faults.unreachable(lines)
    if reason:
        shown.append(faults.network_line(url or "a server", reason))
    if faults.disk_full(lines):
        shown.append(faults.host_disk_line(free_places([Path(cwd or os.getcwd()),
                                                        Path(tempfile.gettempdir())])))
    return shown


def free_places(paths: Sequence[Path]) -> List[Tuple[str, Optional[int]]]:
    """(path, bytes free) of each file system of paths, once (None: not readable)."""
    places: List[Tuple[str, Optional[int]]] = []
    devices = set()
    for path in paths:
        try:
            device = path.stat().st_dev
            free: Optional[int] = shutil.disk_usage(str(path)).free
        except OSError:
            device, free = None, None
        if device is None or device not in devices:
            devices.add(device)
            places.append((str(path), free))
    return places


def probe(
    argv: Sequence[str],
    *,
    step: str,
    env: Optional[Mapping[str, str]] = None,
    hint: str = "",
    text: bool = True,
) -> "subprocess.CompletedProcess[Any]":
    """Run a command whose exit code and output the caller judges (a look-up, never raises for
    a non-zero exit); a missing program is a StepError with exit code 127 and the hint."""
    try:
        return subprocess.run(executable_argv(argv), env=None if env is None else dict(env),
                              capture_output=True, text=text)
    except FileNotFoundError:
        raise StepError(step, f"command not found: {argv[0]}" + (f" ({hint})" if hint else "")
                        + host_tool_hint(argv[0]), 127) from None


# The tools of the host-mode steps: the `host` extra of docker-ros (images get them in prepare).
HOST_TOOLS = ("vcs", "rosdep", "colcon")
# (not on PyPI: the extra is installed from where this project is, a checkout or its git URL)
HOST_EXTRA = "pip install '<docker-ros checkout>[host]' (the host extra)"


def tool_path(program: str, executable: Optional[str] = None) -> str:
    """Where a host-mode tool is: on the host beside our interpreter first (docker-ros
    installed in a venv that is not activated, or with pipx, has its vcs, rosdep and colcon
    there, not on PATH), else `program` itself (found on PATH, as always in images)."""
    executable = sys.executable if executable is None else executable
    if program in HOST_TOOLS and executable and hook_context() == "host":
        beside = os.path.join(os.path.dirname(executable), program)
        if os.path.isfile(beside) and os.access(beside, os.X_OK):
            return beside
    return program


def executable_argv(argv: Sequence[str]) -> List[str]:
    """argv as run: a host-mode tool by its tool_path (logs and errors keep the short name)."""
    return [tool_path(argv[0]), *argv[1:]] if argv else []


def host_tool_hint(program: str) -> str:
    """What to do when one of the host-mode steps' tools is missing on the host ('' otherwise)."""
    if program in HOST_TOOLS and hook_context() == "host":
        return (f"; on the host the steps need vcstool, rosdep and colcon (looked for beside "
                f"{sys.executable} and on PATH): {HOST_EXTRA}")
    return ""


def hook_context(environ: Optional[Mapping[str, str]] = None) -> str:
    """Where hooks run: `image` (an image build, whose images set DOCKER_ROS=1) or `host`."""
    env = os.environ if environ is None else environ
    return "image" if env.get("DOCKER_ROS") == "1" else "host"


def script_hint(content: bytes) -> str:
    """What to do about a failed hook script whose content we recognise as the cause."""
    if b"\r\n" in content:
        return ("; the script has Windows (CRLF) line endings, which bash cannot run: convert it"
                " (`dos2unix FILE`, or `git config core.autocrlf input` and check it out again)")
    return ""


# the folder the docker_ros package is imported from (/docker-ros/lib in image builds)
OWN_LIB = Path(__file__).resolve().parents[3]


def without_own_lib(pythonpath: Optional[str], lib: Path = OWN_LIB) -> Optional[str]:
    """PYTHONPATH without the entries naming lib (None when nothing is left): the step code's
    own path is not the hooks' business; the rest (the base image's) is theirs."""
    if pythonpath is None:
        return None
    kept = [entry for entry in pythonpath.split(os.pathsep)
            if entry and os.path.abspath(entry) != str(lib)]
    return os.pathsep.join(kept) or None


# Sourced by bash before a hook (BASH_ENV): when a command stops the script under `set -e`
# (bash -e, or the script's own `set -e`), write its exit code, line, file and text to
# $DOCKER_ROS_HOOK_FAILED. errtrace reports a command failing in a function at its own line; the
# errexit check keeps a script that runs on after failures (`set +e`) from leaving a record.
# Bash scripts run by the hook get no BASH_ENV, so no trap.
FAILED_LINE_TRAP = """unset BASH_ENV
set -o errtrace
trap 'docker_ros_s=$?; case $- in *e*) printf "%s\\t%s\\t%s\\t%s" "$docker_ros_s" "$LINENO" \\
  "${BASH_SOURCE[0]}" "$BASH_COMMAND" >"$DOCKER_ROS_HOOK_FAILED";; esac' ERR
"""


def failed_line(record: str, script: Path) -> str:
    """'; it stopped at line N: `command` (exit code C)' from the trap's record ('' for none);
    a line of a file the script sourced names that file."""
    fields = record.split("\t", 3)
    if len(fields) != 4 or not fields[1].isdigit():
        return ""
    status, line, source, command = fields
    command = command.strip().splitlines()[0] if command.strip() else ""
    if len(command) > 200:
        command = command[:200] + "..."
    where = "" if source in (str(script), "") else f" of {source}"
    return f"; it stopped at line {line}{where}: `{command}` (exit code {status})"


def run_script(
    argv: Sequence[str], script: Path, *, step: str, dry_run: bool, cwd: Path, what: str
) -> None:
    """Run a user hook (argv ends with the script) with DOCKER_ROS_CONTEXT=image|host set and
    the environment docker-ros's hooks had (PYTHONPATH without the step code's folder);
    a failure names the line that stopped a bash script, and a cause we recognise says what
    to do. A BASH_ENV of the user's is left alone (then no line is named)."""
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    pythonpath = without_own_lib(os.environ.get("PYTHONPATH"))
    if pythonpath is not None:
        env["PYTHONPATH"] = pythonpath
    env["DOCKER_ROS_CONTEXT"] = hook_context()
    with tempfile.TemporaryDirectory(prefix="docker-ros-hook-") as tmp:
        record = Path(tmp) / "failed"
        if "BASH_ENV" not in env:
            (Path(tmp) / "trap.sh").write_text(FAILED_LINE_TRAP)
            env.update(BASH_ENV=str(Path(tmp) / "trap.sh"), DOCKER_ROS_HOOK_FAILED=str(record))
        try:
            run(argv, step=step, dry_run=dry_run, cwd=cwd, what=what, env=env)
        except StepError as exc:
            line = failed_line(record.read_text(errors="replace"), script) \
                if record.is_file() else ""
            hint = script_hint(script.read_bytes()) if script.is_file() else ""
            if not line and not hint:
                raise
            raise StepError(step, exc.said_more(line + hint), exc.returncode) from None


def run_tee(
    argv: Sequence[str],
    *,
    step: str,
    cwd: Optional[Path] = None,
    env: Optional[Mapping[str, str]] = None,
    on_line: Optional[Callable[[str], bool]] = None,
    shown: Callable[[str], str] = str,
) -> Tuple[int, List[str]]:
    """Run argv with stdout+stderr streamed line by line to our stdout (the user sees the tool's
    output as it comes) and also returned, for parsing. Returns (exit code, lines).
    `on_line` returning True stops the command (a failure already known, no use waiting);
    `shown` makes each line what is printed and returned (e.g. with passwords hidden)."""
    LOG.info("%s: %s", step, format_argv(argv))
    sys.stdout.flush()
    lines: List[str] = []
    try:
        proc = subprocess.Popen(
            executable_argv(argv),
            cwd=str(cwd) if cwd else None,
            env=None if env is None else dict(env),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            universal_newlines=True,
            errors="replace",
        )
    except FileNotFoundError:
        raise StepError(
            step, f"command not found: {argv[0]} (needed for: {format_argv(argv)})"
            f"{host_tool_hint(argv[0])}", 127) from None
    assert proc.stdout is not None
    try:
        with proc.stdout:
            for line in proc.stdout:
                line = shown(line)
                sys.stdout.write(line)
                sys.stdout.flush()
                line = line.rstrip("\n")
                lines.append(line)
                if on_line and on_line(line):
                    stop_tree(proc)
                    break
    except BaseException:  # interrupted or terminated: the command does not outlive us
        stop_tree(proc)
        raise
    return proc.wait(), lines


def descendants(pid: int, proc_root: Path = Path("/proc")) -> List[int]:
    """The processes below pid, at any depth (read from /proc; none where there is none)."""
    children: Dict[int, List[int]] = {}
    for stat in proc_root.glob("[0-9]*/stat"):
        try:  # `pid (comm) state ppid ...`; comm may hold spaces and parentheses
            parent = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue  # ended meanwhile
        children.setdefault(parent, []).append(int(stat.parent.name))
    found: List[int] = []
    waiting = [pid]
    while waiting:
        below = children.get(waiting.pop(), [])
        found.extend(below)
        waiting.extend(below)
    return found


def stop_tree(proc: "subprocess.Popen[str]") -> None:
    """SIGTERM to a command and to every process below it, then wait for the command (SIGKILL
    to them all after 10 s). A signal to the command alone (as SIGTERM to our process alone:
    `kill`, a CI runner, `docker-ros ci`) leaves its children running, such as the git clones
    of vcs or the compilers of colcon."""
    for sig in (signal.SIGTERM, signal.SIGKILL):  # (SIGKILL: what is left 10 s later)
        for pid in [proc.pid, *descendants(proc.pid)]:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, sig)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=10)
            return


def is_root() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0


def privileged(argv: Sequence[str]) -> List[str]:
    """Prefix with sudo when not root (host mode for a normal user)."""
    return list(argv) if is_root() else ["sudo", *argv]
