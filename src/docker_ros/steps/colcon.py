"""colcon: `colcon build` the workspace, over ROS and the base image's workspace."""

import logging
import re
import shlex
from typing import List, Sequence

from docker_ros.settings import Settings
from docker_ros.steps.blacklist import blacklisted_packages
from docker_ros.steps.common import (
    StepError,
    Workspace,
    dry,
    phases,
    ros_setup_files,
    run,
    run_tee,
    sourced_env,
    step_log,
)

STEP = "colcon"
LOG = logging.getLogger(__name__)
_FAILED = re.compile(r"^Failed\s+<<<\s+(\S+)")


def cmake_arguments(cmake_args: str) -> List[str]:
    """CMAKE_ARGS split like a shell would (quotes keep spaces), no shell involved. colcon
    strips a leading space, which keeps `--foo` from being taken for a colcon option."""
    return [
        " " + a if a.startswith("--") or a.startswith("-h") else a for a in shlex.split(cmake_args)
    ]


def build_argv(cmake_args: str, ignore: Sequence[str]) -> List[str]:
    argv = ["colcon", "build", "--base-paths", "src"]
    if ignore:
        argv += ["--packages-ignore", *ignore]
    arguments = cmake_arguments(cmake_args)
    if arguments:
        argv += ["--cmake-args", *arguments]
    return argv


def failed_packages(lines: Sequence[str]) -> List[str]:
    """Packages colcon reports as `Failed   <<< pkg [...]`."""
    out = []
    for line in lines:
        match = _FAILED.match(line.strip())
        if match and match.group(1) not in out:
            out.append(match.group(1))
    return out


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: str,
) -> None:
    """Single phase: build with CMAKE_ARGS, blacklisted packages ignored."""
    phases(STEP, phase)
    with step_log(STEP):
        ws.require_sources(STEP)
        ignore = blacklisted_packages(ws, settings)
        argv = build_argv(settings.cmake_args, ignore)
        setup = ros_setup_files(settings)
        if dry_run:
            for path in setup:
                dry(STEP, f"source {path}")
            run(argv, step=STEP, dry_run=True, cwd=ws.root)
            return
        env = sourced_env(setup, step=STEP)
        returncode, lines = run_tee(argv, step=STEP, cwd=ws.root, env=env)
        if returncode != 0:
            failed = failed_packages(lines)
            what = (
                ("package " + ", ".join(failed) + " failed to build")
                if failed
                else ("colcon build failed")
            )
            raise StepError(
                STEP, f"{what} (exit code {returncode}); see the output above", returncode
            )
