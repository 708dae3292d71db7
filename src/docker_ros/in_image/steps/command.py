"""command: the run image's launch command (COMMAND); on the host, run it in the built
workspace's environment. In an image build (phase collect) it only checks that COMMAND is set:
the Dockerfile makes it the default command."""

import logging
from pathlib import Path
from typing import List

from docker_ros.in_image.runtime.process import run
from docker_ros.in_image.runtime.rosenv import sourced_env, workspace_setup_files
from docker_ros.in_image.runtime.workspace import StepError, Workspace, dry, phases, step_log
from docker_ros.in_image.settings import Settings

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
    **options: object,
) -> None:
    """collect: validate COMMAND; apply/all: run it with `bash -c` in the sourced environment.
    A failing command fails the step with the command's exit code."""
    do_collect, do_apply = phases(STEP, phase)
    with step_log(STEP):
        command = settings.command
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
