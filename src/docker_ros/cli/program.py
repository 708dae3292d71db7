"""The `docker-ros` console script: an invoke Program over the same tasks as `inv`."""

from __future__ import annotations

import os
import sys
from typing import List, Optional

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
            where = getattr(exc, "problem_mark", None)
            line = f" (line {where.line + 1})" if where else ""
            problem = getattr(exc, "problem", None) or exc
            raise Exit(f"docker-ros: invoke.yaml{line} is not valid YAML: {problem}: fix or "
                       "remove it", code=2) from None


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
