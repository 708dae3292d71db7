"""pip: install the extra pip requirements listed in ADDITIONAL_PIP_FILE(s).

collect reads the files by pip's rules (runtime.requirements: continuations, comments, nested
-r/-c files relative to the naming file) into pip.json; apply writes those lines into a
requirement file of its own and lets pip read it (`pip install -r`), so requirement syntax,
options, hashes and `${VARIABLES}` mean what they mean to pip. No shell ever sees them."""

import re
import tempfile
from pathlib import Path
from typing import Any, Dict, List, Sequence

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.files import find_special_files, unique
from docker_ros.in_image.runtime.lock import locked_arguments
from docker_ros.in_image.runtime.pipinstall import pip_install, requirement_files
from docker_ros.in_image.runtime.requirements import read_requirement_file
from docker_ros.in_image.runtime.workspace import (
    LOG,
    StepError,
    Workspace,
    planned_step,
)

STEP = "pip"
STATE_FILE = "pip.json"


def collect_requirements(ws: Workspace, settings: Settings) -> Dict[str, List[str]]:
    """The plan: the requirement and constraint lines of every ADDITIONAL_PIP_FILE."""
    requirements: List[str] = []
    constraints: List[str] = []
    files = find_special_files(ws, settings, "additional_pip_file", step=STEP)
    if not files:
        LOG.info("%s: no %s found, nothing to do", STEP, settings.additional_pip_file)
    for path in files:
        read = read_requirement_file(path, step=STEP)
        nested = [ws.relative(p) for p in read.files[1:]]
        LOG.info("%s: %d entries in %s%s", STEP, len(read.requirements), path,
                 f" (with {', '.join(nested)})" if nested else "")
        requirements += read.requirements
        constraints += read.constraints
    plan = {"requirements": unique(requirements)}
    return {**plan, "constraints": unique(constraints)} if constraints else plan


def install_requirements(
    requirements: Sequence[str], constraints: Sequence[str], *, dry_run: bool, what: str
) -> None:
    """pip install -r a requirement file holding the collected lines."""
    if not requirements:
        LOG.info("%s: no pip requirements to install", STEP)
        return
    for line in requirements:
        LOG.info("%s: requirement %s", STEP, line)
    for line in constraints:
        LOG.info("%s: constraint %s", STEP, line)
    with tempfile.TemporaryDirectory(prefix="docker-ros-pip-") as tmp:
        path = requirement_files(Path(tmp), requirements, constraints)
        try:
            pip_install(["-r", str(path)], step=STEP, dry_run=dry_run, what=what)
        except StepError as exc:
            raise StepError(STEP, named_lines(exc.message, path), exc.returncode) from None


def named_lines(message: str, path: Path) -> str:
    """pip's `(from line N of <our temporary requirements.txt>)` as the line itself: the user's
    file has other line numbers, and the temporary one is gone."""
    lines = path.read_text().splitlines()

    def line(match: "re.Match[str]") -> str:
        number = int(match.group(1))
        text = lines[number - 1] if 0 < number <= len(lines) else "?"
        return f"(from the requirement line {text!r})"

    return re.sub(r"\(from line (\d+) of " + re.escape(str(path)) + r"\)", line, message)


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: object,
) -> None:
    """collect: read the requirement file(s) into pip.json; apply: pip install them."""

    def install(plan: Dict[str, Any]) -> None:
        requirements = list(plan.get("requirements") or [])
        # LOCKED: the lines checked against the lock, installed under its versions
        locked = locked_arguments(ws, settings, step=STEP, kind="pip", inputs=requirements,
                                  dry_run=dry_run) or []
        install_requirements(requirements, [*(plan.get("constraints") or []), *locked],
                             dry_run=dry_run, what="installing ADDITIONAL_PIP_FILE requirements")

    planned_step(ws, STEP, STATE_FILE, phase=phase, dry_run=dry_run, apply=install,
                 collect=lambda: collect_requirements(ws, settings))
