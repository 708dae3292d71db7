"""The `docker-ros` console script: an invoke Program over the same tasks as `inv`."""

from __future__ import annotations

import os
import sys
import traceback
from pathlib import Path
from typing import Any, List, Optional

from invoke import Exit, Program
from invoke.config import yaml  # (the YAML module invoke reads its files with)

from docker_ros import __version__
from docker_ros.cli.tasks import ns


class DockerRosProgram(Program):
    """invoke's Program over our bundled tasks, reading invoke.yaml (key docker_ros) from the
    project we run in, as `inv` does next to tasks.py (a Program given its namespace loads no
    project configuration by itself)."""

    def parse_collection(self) -> None:
        super().parse_collection()
        self.config.set_project_location(os.getcwd())
        try:
            self.config.load_project()
        except yaml.YAMLError as exc:
            raise Exit(yaml_problem(exc, "invoke.yaml"), code=2) from None


def yaml_problem(exc: Exception, name: str) -> str:
    """One line for an invoke configuration file that is not YAML."""
    where = getattr(exc, "problem_mark", None)
    line = f" (line {where.line + 1})" if where else ""
    problem = getattr(exc, "problem", None) or exc
    return f"docker-ros: {name}{line} is not valid YAML: {problem}: fix or remove it"


def one_line_for_broken_invoke_yaml() -> None:
    """For `inv`, which reads invoke.yaml after importing tasks.py, outside any code of ours: a
    YAML error raised while invoke loads its configuration files ends as yaml_problem's line
    (exit code 2) instead of a traceback; every other exception keeps the hook it had."""
    previous = sys.excepthook

    def hook(kind: type, exc: BaseException, trace: Any) -> None:
        files = [frame.f_code.co_filename for frame, _ in traceback.walk_tb(trace)]
        if isinstance(exc, yaml.YAMLError) and any(
                Path(f).parts[-2:] == ("invoke", "config.py") for f in files):
            where = getattr(exc, "problem_mark", None)
            name = getattr(where, "name", "") or "invoke.yaml"
            print(yaml_problem(exc, name), file=sys.stderr, flush=True)
            sys.stdout.flush()
            os._exit(2)
        previous(kind, exc, trace)

    sys.excepthook = hook


def main(argv: Optional[List[str]] = None) -> None:
    ns.loaded_from = os.getcwd()
    program = DockerRosProgram(namespace=ns, name="docker-ros", binary="docker-ros",
                               version=__version__)
    try:
        program.run(None if argv is None else ["docker-ros", *argv])
    except BrokenPipeError:
        # The reader of our output (e.g. `docker-ros --list | head`) closed it: not our error.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        sys.exit(141)
