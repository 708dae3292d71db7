"""command: the run image's launch command (COMMAND); on the host, run it in the built
workspace's environment. In an image build (phase collect) it only logs COMMAND (the Dockerfile
makes it the default command); the run stage then checks (--check) that what it names is
there: its programs, and the packages, executables and launch files of its ROS launchers."""

import logging
from pathlib import Path
from typing import List, Optional

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.launch import command_problems, simple_commands
from docker_ros.in_image.runtime.process import probe, run
from docker_ros.in_image.runtime.rosenv import sourced_env, workspace_setup_files
from docker_ros.in_image.runtime.workspace import StepError, Workspace, dry, phases, step_log

STEP = "command"
LOG = logging.getLogger(__name__)


def setup_files(ws: Workspace, settings: Settings) -> List[Path]:
    """ROS, the base image's workspace, then this workspace: each only when it exists."""
    return workspace_setup_files(settings, ws.install, step=STEP)


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    check: bool = False,
    **options: object,
) -> None:
    """collect: log COMMAND; apply/all: run it with `bash -c` in the sourced environment (a
    failing command fails the step with the command's exit code); check: run nothing, fail
    when what COMMAND names is missing here."""
    do_collect, do_apply = phases(STEP, phase)
    with step_log(STEP):
        command = settings.command
        if check:
            check_command(ws, settings, command, dry_run=dry_run)
            return
        if do_collect:
            # A dev-only build needs no COMMAND (the tool requires it when run is a target).
            LOG.info("%s: COMMAND=%s", STEP, command or "(not set: no run image)")
        if not do_apply:
            return
        if not command:
            raise StepError(STEP, "COMMAND is not set: set the launch command of the run image")
        files = setup_files(ws, settings)
        if dry_run:
            for path in files:
                dry(STEP, f"source {path}")
            run(["bash", "-c", command], step=STEP, dry_run=True, cwd=ws.root)
            return
        env = sourced_env(files, step=STEP)
        run(["bash", "-c", command], step=STEP, cwd=ws.root, env=env, what="COMMAND")


def check_command(ws: Workspace, settings: Settings, command: Optional[str], *,
                  dry_run: bool) -> None:
    """Stop when COMMAND names a program, package, executable or launch file that is not in
    this environment (the run image's, with the install space in)."""
    if not command or not settings.enable_command_check:
        LOG.info("%s: not checked (%s)", STEP, "ENABLE_COMMAND_CHECK=false" if command
                 else "no COMMAND")
        return
    if dry_run:
        dry(STEP, f"check that what COMMAND names is here: {command}")
        return
    env = sourced_env(setup_files(ws, settings), step=STEP)
    firsts = [words[0] for words in simple_commands(command)]
    script = 'for w; do type -t -- "$w" >/dev/null && printf "%s\\0" "$w"; done; true'
    known = probe(["bash", "-c", script, "bash", *firsts], step=STEP, env=env).stdout
    problems = command_problems(command, env, known.split("\0"))
    if problems:
        raise StepError(STEP, "COMMAND cannot start in the run image: " + "; ".join(problems))
    LOG.info("%s: what COMMAND names is in the image", STEP)
