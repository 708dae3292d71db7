"""files: copy ADDITIONAL_FILES_DIR into the image at /docker-ros/additional-files/."""

import logging
from pathlib import Path
from typing import Optional

from docker_ros.core.settings import Settings, explicitly_set
from docker_ros.in_image.runtime.files import copy_tree, remove_tree, repository_path
from docker_ros.in_image.runtime.workspace import StepError, Workspace, dry, phases, step_log

STEP = "files"
STATE_DIR = "additional-files"
DEFAULT_DESTINATION = "/docker-ros/additional-files"
LOG = logging.getLogger(__name__)


def collect(ws: Workspace, settings: Settings, *, dry_run: bool) -> None:
    """Mirror the folder into <state>/additional-files (always created, maybe empty, so the
    image can COPY it unconditionally)."""
    ws.require_sources(STEP)
    source = repository_path(ws, settings, "additional_files_dir", step=STEP)
    staged = ws.state / STATE_DIR
    remove_tree(staged, step=STEP, dry_run=dry_run)
    if dry_run:
        dry(STEP, f"create {staged}")
    else:
        staged.mkdir(parents=True)
    if source.is_dir():
        copy_tree(source, staged, step=STEP, dry_run=dry_run)
    elif explicitly_set(settings, "additional_files_dir"):
        raise StepError(STEP, f"ADDITIONAL_FILES_DIR '{settings.additional_files_dir}' is no "
                        "folder in the repository (set explicitly): fix the path or unset it")
    else:
        LOG.info(
            "%s: no %s folder in %s, nothing to copy",
            STEP,
            settings.additional_files_dir,
            ws.target,
        )


def apply(
    ws: Workspace, destination: Path, *, dry_run: bool, source: Optional[Path] = None
) -> None:
    """Copy the staged files (or `source`) into destination, merging with what is there."""
    staged = source if source is not None else ws.state / STATE_DIR
    if not staged.is_dir() or not any(staged.iterdir()):
        LOG.info("%s: no additional files to copy", STEP)
        return
    copy_tree(staged, destination, step=STEP, dry_run=dry_run)


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: object,
) -> None:
    """collect: stage the folder in the state dir; apply: copy it to `destination`."""
    do_collect, do_apply = phases(STEP, phase)
    destination = Path(str(options.get("destination") or DEFAULT_DESTINATION))
    with step_log(STEP):
        if do_collect:
            collect(ws, settings, dry_run=dry_run)
        if do_apply:
            # A dry run staged nothing: show the copy from the folder itself.
            source = (repository_path(ws, settings, "additional_files_dir", step=STEP)
                      if dry_run and do_collect else None)
            apply(ws, destination, dry_run=dry_run, source=source)
