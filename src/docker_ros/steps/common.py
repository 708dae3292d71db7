"""Shared plumbing of the ten steps. Standard library only, Python 3.8+ (runs inside base images)."""

import contextlib
import fnmatch
import json
import logging
import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Dict, Iterator, List, Mapping, Optional, Sequence

LOG = logging.getLogger("docker_ros")

STATE_DIR_NAME = ".docker-ros"
# Directories never searched for packages or special files.
SKIP_DIRS = {".git", ".hg", ".svn", "build", "install", "log", STATE_DIR_NAME, "__pycache__"}
IGNORE_MARKERS = ("COLCON_IGNORE", "CATKIN_IGNORE", "AMENT_IGNORE")


class StepError(Exception):
    """An expected failure of a step: printed as one line, exit code 1 (or the command's)."""

    def __init__(self, step: str, message: str, returncode: int = 1) -> None:
        super().__init__(f"{step}: {message}")
        self.step = step
        self.message = message
        self.returncode = returncode


class Workspace:
    """A colcon workspace: <root>/src/target is the repository, <root>/src/upstream the imports."""

    def __init__(self, root: "os.PathLike[str] | str") -> None:
        self.root = Path(root)

    @property
    def src(self) -> Path:
        return self.root / "src"

    @property
    def target(self) -> Path:
        return self.src / "target"

    @property
    def upstream(self) -> Path:
        return self.src / "upstream"

    @property
    def install(self) -> Path:
        return self.root / "install"

    @property
    def state(self) -> Path:
        """Data handed from one step to the next (resolved dependencies, blacklist, hooks)."""
        return self.root / STATE_DIR_NAME

    def read_state(self, name: str, default: object = None) -> object:
        path = self.state / name
        if not path.exists():
            return default
        return json.loads(path.read_text())

    def write_state(self, name: str, data: object) -> Path:
        self.state.mkdir(parents=True, exist_ok=True)
        path = self.state / name
        path.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
        return path


@contextlib.contextmanager
def step_log(step: str) -> Iterator[None]:
    """colcon-style `Starting >>> step` / `Finished <<< step [1.2s]` lines."""
    LOG.info("Starting >>> %s", step)
    start = time.monotonic()
    try:
        yield
    except StepError:
        LOG.error("Failed   <<< %s [%.1fs]", step, time.monotonic() - start)
        raise
    LOG.info("Finished <<< %s [%.1fs]", step, time.monotonic() - start)


def format_argv(argv: Sequence[str]) -> str:
    return " ".join(shlex.quote(a) for a in argv)


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
        print(f"[dry-run] {step}: {shown}" + (f"  (in {cwd})" if cwd else ""))
        return ""
    LOG.info("%s: %s", step, shown)
    full_env = None if env is None else dict(env)
    try:
        proc = subprocess.run(
            list(argv),
            cwd=str(cwd) if cwd else None,
            env=full_env,
            stdout=subprocess.PIPE if capture else None,
            stderr=subprocess.PIPE if capture else None,
            universal_newlines=True,
        )
    except FileNotFoundError:
        raise StepError(step, f"command not found: {argv[0]} (needed for: {shown})", 127)
    if proc.returncode != 0:
        detail = ""
        if capture and proc.stderr:
            detail = ": " + proc.stderr.strip().splitlines()[-1]
        subject = f"{what} " if what else ""
        raise StepError(
            step,
            f"{subject}failed with exit code {proc.returncode}: {shown}{detail}",
            proc.returncode,
        )
    return proc.stdout if capture else ""


def walk(root: Path) -> Iterator[Path]:
    """Every directory below root (root first), skipping VCS/build dirs; follows symlinks once."""
    seen = set()
    for dirpath, dirnames, _ in os.walk(str(root), followlinks=True):
        real = os.path.realpath(dirpath)
        if real in seen:
            dirnames[:] = []
            continue
        seen.add(real)
        dirnames[:] = sorted(d for d in dirnames if d not in SKIP_DIRS)
        yield Path(dirpath)


def find_special_files(
    ws: Workspace, relative_path: str, *, recursive: bool, pattern: Optional[str] = None
) -> List[Path]:
    """docker-ros's file discovery: the configured file in the repository, and with
    `recursive` every file of the same name (or matching `pattern`) anywhere in the workspace."""
    found: List[Path] = []
    top = ws.target / relative_path
    if top.is_file():
        found.append(top)
    if recursive:
        name = Path(relative_path).name
        for directory in walk(ws.src):
            for entry in sorted(directory.iterdir()):
                matches = fnmatch.fnmatch(entry.name, pattern) if pattern else entry.name == name
                if matches and entry.is_file() and entry not in found:
                    found.append(entry)
    return found


def read_list_file(path: Path) -> List[str]:
    """Lines of a list file without comments (# ...), blank lines and surrounding spaces."""
    items = []
    for line in path.read_text().splitlines():
        # As pip: a comment starts at a '#' at line start or after white space (not in URLs).
        line = re.sub(r"(^|\s)#.*$", "", line).strip()
        if line:
            items.append(line)
    return items


def env_flag(environ: Mapping[str, str], name: str, default: bool) -> bool:
    """Strict boolean from an environment variable (true/false/1/0/yes/no, any case)."""
    raw = environ.get(name)
    if raw is None or raw == "":
        return default
    word = raw.strip().lower()
    if word in ("true", "1", "yes"):
        return True
    if word in ("false", "0", "no"):
        return False
    raise StepError("config", f"{name}={raw!r} is not a boolean; use true/false/1/0/yes/no")


def is_root() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0


def privileged(argv: Sequence[str]) -> List[str]:
    """Prefix with sudo when not root (host mode for a normal user)."""
    return list(argv) if is_root() else ["sudo", *argv]


def setup_logging(verbose: bool = False) -> None:
    logging.basicConfig(
        stream=sys.stderr,
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(message)s",
    )


def apt_env() -> Dict[str, str]:
    env = dict(os.environ)
    env["DEBIAN_FRONTEND"] = "noninteractive"
    return env
