"""The workspace layout, step errors and the Starting/Finished log lines.
Standard library only, Python 3.8+ (runs inside images)."""

import contextlib
import json
import logging
import os
import shlex
import sys
import time
from pathlib import Path
from typing import Any, Callable, Dict, Iterator, Sequence, Tuple

from docker_ros.core.errors import DockerRosError

LOG = logging.getLogger("docker_ros")


STATE_DIR_NAME = ".docker-ros"


# Directories never searched for packages or special files.
# (.gitlab-ci-local: gitlab-ci-local's copies of the repository, made inside it.)
SKIP_DIRS = {
    ".git", ".hg", ".svn", "build", "install", "log", STATE_DIR_NAME, "__pycache__",
    ".gitlab-ci-local",
}


IGNORE_MARKERS = ("COLCON_IGNORE", "CATKIN_IGNORE", "AMENT_IGNORE")


PHASES = ("collect", "apply", "all")


class StepError(DockerRosError):
    """An expected failure of a step: printed as one line, exit code 1 (or the command's)."""

    def __init__(self, step: str, message: str, returncode: int = 1) -> None:
        super().__init__(f"{step}: {message}")
        self.step = step
        self.message = message
        self.returncode = returncode
        self.exit_code = returncode or 1

    def said_more(self, more: str) -> str:
        """The message with more at the end of its first line (the lines below it are the
        failed tool's own, see faults.tool_lines)."""
        first, newline, rest = self.message.partition("\n")
        return first + more + newline + rest


def read_user_text(path: "os.PathLike[str] | str", error: Callable[[str], Exception],
                   shown: str = "") -> str:
    """A file of the user's as UTF-8 text; one that is not (Latin-1, the UTF-16 of Windows
    PowerShell) raises error("<shown> is not UTF-8 text (<reason>): save it as UTF-8"), the
    caller's usual error (e.g. functools.partial(StepError, step))."""
    try:
        return Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{shown or path} is not UTF-8 text ({exc.reason} at byte {exc.start}): "
                    "save it as UTF-8") from None


class Workspace:
    """A colcon workspace: <root>/src/target is the repository, <root>/src/upstream the imports."""

    def __init__(self, root: "os.PathLike[str] | str") -> None:
        # absolute: vcs and the hooks run in other folders (WORKSPACE=../ws)
        self.root = Path(root).absolute()

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

    def relative(self, path: Path) -> str:
        """`path` relative to the workspace root (same text on the host and in the image)."""
        try:
            return Path(path).relative_to(self.root).as_posix()
        except ValueError:
            return str(path)

    def read_state(self, name: str, default: object = None) -> object:
        path = self.state / name
        if not path.exists():
            return default
        return json.loads(path.read_text())

    def require_sources(self, step: str) -> None:
        """Collect phases read the repository: a missing src/target is a setup error."""
        if not self.target.is_dir():
            raise StepError(
                step,
                f"{self.target} does not exist: the repository must be src/target of the "
                f"workspace {self.root}",
            )

    def require_state(self, step: str, name: str) -> object:
        """State a previous collect phase wrote; a clear error when it is missing."""
        path = self.state / name
        if not path.exists():
            raise StepError(
                step, f"{path} not found: run `{step}` with phase collect (or all) first"
            )
        try:
            return json.loads(path.read_text())
        except ValueError as exc:
            raise StepError(
                step, f"{path} is not valid JSON ({exc}): re-run its collect phase"
            ) from None

    def load_plan(self, step: str, name: str) -> Dict[str, Any]:
        """The JSON object a previous collect phase wrote (see require_state)."""
        data = self.require_state(step, name)
        return data if isinstance(data, dict) else {}

    def save_plan(self, step: str, name: str, plan: object, *, dry_run: bool) -> None:
        """Write a collect phase's result (a dry run only says so)."""
        if dry_run:
            dry(step, f"write {self.state / name}")
        else:
            self.write_state(name, plan)

    def write_state(self, name: str, data: object) -> Path:
        """Deterministic JSON (sorted keys) so identical inputs give byte-identical files."""
        self.state.mkdir(parents=True, exist_ok=True)
        path = self.state / name
        path.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
        return path


def phases(step: str, phase: str) -> Tuple[bool, bool]:
    """(collect?, apply?) for a phase name."""
    if phase not in PHASES:
        raise StepError(step, f"unknown phase {phase!r}; use one of {', '.join(PHASES)}")
    return phase in ("collect", "all"), phase in ("apply", "all")


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


def planned_step(ws: "Workspace", step: str, state_file: str, *, phase: str, dry_run: bool,
                 collect: "Callable[[], Dict[str, Any]]",
                 apply: "Callable[[Dict[str, Any]], None]") -> None:
    """The two phases of a step that collects a plan: collect writes what collect() returns to
    state_file, apply hands apply() the plan just collected or, alone, the one collect wrote
    earlier; between the Starting/Finished lines."""
    do_collect, do_apply = phases(step, phase)
    with step_log(step):
        plan: Dict[str, Any] = {}
        if do_collect:
            plan = collect()
            ws.save_plan(step, state_file, plan, dry_run=dry_run)
        if do_apply:
            apply(plan if do_collect else ws.load_plan(step, state_file))


def format_argv(argv: Sequence[str]) -> str:
    return " ".join(shlex.quote(a) for a in argv)


def dry(step: str, text: str) -> None:
    """What a dry run would do, on stdout (the same prefix as dry-run commands)."""
    print(f"[dry-run] {step}: {text}", flush=True)


def setup_logging(verbose: bool = False) -> None:
    logging.basicConfig(
        stream=sys.stderr,
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(message)s",
    )


DEFAULT_WORKSPACE = "/docker-ros/ws"
