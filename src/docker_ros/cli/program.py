"""The `docker-ros` console script: an invoke Program over the same tasks as `inv`."""

from __future__ import annotations

import os
import sys
import traceback
from pathlib import Path
from typing import Any, List, Optional

from invoke import Exit, Program
from invoke.config import yaml  # (the YAML module invoke reads its files with)
from invoke.exceptions import AmbiguousEnvVar

from docker_ros import __version__
from docker_ros.cli.tasks import ns
from docker_ros.in_image.runtime.workspace import read_user_text


class DockerRosProgram(Program):
    """invoke's Program over our bundled tasks, reading invoke.yaml (key docker_ros) from the
    project we run in, as `inv` does next to tasks.py (a Program given its namespace loads no
    project configuration by itself)."""

    def parse_collection(self) -> None:
        super().parse_collection()
        self.config.set_project_location(os.getcwd())
        try:
            self.config.load_project()
        except Exception as exc:
            problem = invoke_file_problem(exc, "invoke.yaml")
            if problem is None:
                raise
            raise Exit(problem, code=2) from None


def yaml_problem(exc: Exception, name: str) -> str:
    """One line for an invoke configuration file that is not YAML."""
    where = getattr(exc, "problem_mark", None)
    line = f" (line {where.line + 1})" if where else ""
    problem = getattr(exc, "problem", None) or exc
    return f"docker-ros: {name}{line} is not valid YAML: {problem}: fix or remove it"


def invoke_file_problem(exc: BaseException, name: str = "") -> Optional[str]:
    """One line for an exception raised while invoke loads or merges a configuration file
    (None for any other): not YAML, not UTF-8, a top level that is no mapping (invoke's
    merge_dicts fails on it). `name`: the file as shown, else the one invoke was reading."""
    frames = [frame for frame, _ in traceback.walk_tb(exc.__traceback__)
              if Path(frame.f_code.co_filename).parts[-2:] == ("invoke", "config.py")]
    if not frames:
        return None
    paths = [frame.f_locals.get("path") for frame in frames
             if frame.f_code.co_name in ("_load_yaml", "_load_json", "_merge_file")]
    name = name or str(paths[-1] if paths else "") or "invoke.yaml"
    if isinstance(exc, yaml.YAMLError):
        where = getattr(exc, "problem_mark", None)
        return yaml_problem(exc, name if paths else getattr(where, "name", "") or name)
    if isinstance(exc, UnicodeDecodeError):
        try:
            read_user_text(name, ValueError)
        except ValueError as problem:
            return f"docker-ros: {problem}"
    if isinstance(exc, AmbiguousEnvVar):
        # invoke's environment loader: two keys that are one name to it (image_tag, IMAGE_TAG)
        var = str(exc).rpartition(" ")[2]
        key = var.replace("DOCKER_ROS_", "", 1).lower() if var.startswith("DOCKER_ROS_") else var
        return (f"docker-ros: {name}: {key} is given twice under docker_ros: (keys that differ "
                "in case only, as image_tag and IMAGE_TAG, are one setting): keep one")
    if isinstance(exc, AttributeError) and any(f.f_code.co_name == "_merge_file" for f in frames):
        return f"docker-ros: {name}: the top level must be a mapping (key docker_ros:)"
    return None


def flag_value_problem(exc: BaseException) -> Optional[str]:
    """One line for a flag value invoke's parser could not turn into the flag's type
    (`--seconds abc`: a ValueError from its Argument.set_value); None for any other exception."""
    task = ""
    for frame, _ in traceback.walk_tb(exc.__traceback__):
        where = Path(frame.f_code.co_filename).parts[-2:]
        if where == ("parser", "parser.py"):  # (the parse machine: the task being parsed)
            task = getattr(getattr(frame.f_locals.get("self"), "context", None), "name", task)
        if where == ("parser", "argument.py") and frame.f_code.co_name == "set_value":
            argument = frame.f_locals["self"]
            kind = {int: "a whole number"}.get(argument.kind, argument.kind.__name__)
            flag = "--" + str(argument.name).replace("_", "-")
            label = f"docker-ros {task}" if task else "docker-ros"
            return f"{label}: {flag} takes {kind}, not {frame.f_locals.get('value')!r}"
    return None


def one_line_for_invoke_errors() -> None:
    """For `inv`, which parses the flags and reads invoke.yaml after importing tasks.py, outside
    any code of ours (and for `docker-ros`): an invoke configuration file invoke cannot load
    (invoke_file_problem) or a flag value of the wrong type (flag_value_problem) ends as one line
    (exit code 2) instead of a traceback; every other exception keeps the hook it had."""
    previous = sys.excepthook

    def hook(kind: type, exc: BaseException, trace: Any) -> None:
        problem = invoke_file_problem(exc) or flag_value_problem(exc)
        if problem is not None:
            print(problem, file=sys.stderr, flush=True)
            sys.stdout.flush()
            os._exit(2)
        previous(kind, exc, trace)

    sys.excepthook = hook


def main(argv: Optional[List[str]] = None) -> None:
    ns.loaded_from = os.getcwd()
    one_line_for_invoke_errors()  # (invoke reads the environment layer when it executes)
    program = DockerRosProgram(namespace=ns, name="docker-ros", binary="docker-ros",
                               version=__version__)
    try:
        program.run(None if argv is None else ["docker-ros", *argv])
    except BrokenPipeError:
        # The reader of our output (e.g. `docker-ros --list | head`) closed it: not our error.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        sys.exit(141)
