"""The `docker-ros` console script: an invoke Program over the same tasks as `inv`."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import List, Optional

from invoke import Program
from invoke.config import yaml  # (the YAML module invoke reads its files with)

from docker_ros import __version__
from docker_ros.cli.settingstask import refuse_secret_flags
from docker_ros.cli.tasks import ns
from docker_ros.in_image.runtime.workspace import read_user_text


class DockerRosProgram(Program):
    """invoke's Program over our bundled tasks, reading invoke.yaml (key docker_ros) from the
    project we run in, as `inv` does next to tasks.py (a Program given its namespace loads no
    project configuration by itself)."""

    def parse_collection(self) -> None:
        super().parse_collection()
        self.config.set_project_location(os.getcwd())
        self.config.load_project()


# invoke's configuration files (its documentation, "The configuration hierarchy"): system,
# user and project (beside tasks.py), each the first of .yaml, .yml and .json found.
CONFIG_SUFFIXES = (".yaml", ".yml", ".json")


def config_files(project: Path, *, base: bool = True) -> List[Path]:
    """The configuration files invoke reads (with base: the system's and the user's too)."""
    prefixes = [Path("/etc/invoke"), Path("~/.invoke").expanduser()] if base else []
    found = []
    for prefix in [*prefixes, project / "invoke"]:
        found += [path for path in (prefix.with_suffix(s) for s in CONFIG_SUFFIXES)
                  if path.is_file()][:1]
    return found


def yaml_problem(exc: Exception, name: str) -> str:
    """One line for an invoke configuration file that is not YAML."""
    where = getattr(exc, "problem_mark", None)
    line = f" (line {where.line + 1})" if where else ""
    problem = getattr(exc, "problem", None) or exc
    return f"docker-ros: {name}{line} is not valid YAML: {problem}: fix or remove it"


def config_file_problem(path: Path, shown: str) -> Optional[str]:
    """One line for an invoke configuration file invoke would fail on with a traceback (None
    when it loads): not UTF-8, not YAML, a top level that is no mapping, or a key under
    docker_ros: given twice in two cases (one environment variable to invoke). `shown`: the
    file as the UTF-8 and YAML messages name it."""
    try:
        text = read_user_text(path, ValueError, shown)
    except ValueError as problem:
        return f"docker-ros: {problem}"
    try:
        data = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except yaml.YAMLError as exc:
        return yaml_problem(exc, shown)
    except ValueError:  # (invoke's own message for JSON names the line)
        return None
    if data is not None and not isinstance(data, dict):
        return f"docker-ros: {path.name}: the top level must be a mapping (key docker_ros:)"
    section = (data or {}).get("docker_ros")
    keys = [str(key) for key in section] if isinstance(section, dict) else []
    twice = [key for key in keys if [k.lower() for k in keys].count(key.lower()) > 1]
    if twice:
        return (f"docker-ros: {path.name}: {twice[0].lower()} is given twice under docker_ros: "
                "(keys that differ in case only, as image_tag and IMAGE_TAG, are one setting): "
                "keep one")
    return None


def stop_on_config_problems(project: Path, *, base: bool, full_paths: bool) -> None:
    """Before invoke reads its configuration files: one that it would fail on ends the program
    as one line (exit code 2) instead of invoke's traceback."""
    for path in config_files(project, base=base):
        problem = config_file_problem(path, str(path) if full_paths else path.name)
        if problem is not None:
            print(problem, file=sys.stderr, flush=True)
            raise SystemExit(2)


def tasks_folder(start: Path) -> Path:
    """Where `inv` finds tasks.py: start or the nearest folder above it that has one."""
    return next((folder for folder in [start, *start.parents]
                 if (folder / "tasks.py").is_file()), start)


def main(argv: Optional[List[str]] = None) -> None:
    ns.loaded_from = os.getcwd()
    stop_on_config_problems(Path.cwd(), base=True, full_paths=False)
    refuse_secret_flags(sys.argv[1:] if argv is None else argv, ns)
    program = DockerRosProgram(namespace=ns, name="docker-ros", binary="docker-ros",
                               version=__version__)
    try:
        program.run(None if argv is None else ["docker-ros", *argv])
    except BrokenPipeError:
        # The reader of our output (e.g. `docker-ros --list | head`) closed it: not our error.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        sys.exit(141)
