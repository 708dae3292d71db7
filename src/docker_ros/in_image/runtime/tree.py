"""The dev image's sources: the repository without ADDITIONAL_FILES_DIR, whose files the files
step puts at /docker-ros/additional-files (docker-ros removed the folder from the dev image's
sources too: large files, models or maps, were not in the image twice).
`python3 -m docker_ros.in_image.runtime.tree`: run by the image's tree stage.
Standard library only, Python 3.8+ (runs inside images)."""

import logging
import sys
from pathlib import Path
from typing import List, Optional

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.entry import image_main
from docker_ros.in_image.runtime.files import remove_tree, repository_path
from docker_ros.in_image.runtime.workspace import Workspace

LOG = logging.getLogger(__name__)


def additional_files_in_sources(ws: Workspace, settings: Settings) -> Optional[Path]:
    """The ADDITIONAL_FILES_DIR folder in the sources, or None when there is none (or it is the
    repository itself, which stays)."""
    folder = repository_path(ws, settings, "additional_files_dir", step="files")
    if folder.resolve() == ws.target.resolve() or not (folder.is_dir() or folder.is_symlink()):
        return None
    return folder


def drop_additional_files(ws: Workspace, settings: Settings) -> None:
    folder = additional_files_in_sources(ws, settings)
    if folder is not None:
        LOG.info("files: %s is not among the dev image's sources (its files are in "
                 "/docker-ros/additional-files)", ws.relative(folder))
        remove_tree(folder, step="files", dry_run=False)


def main(argv: List[str]) -> int:
    return image_main(argv, module="runtime.tree", step="files",
                      description="Remove ADDITIONAL_FILES_DIR from the dev image's sources "
                      "(the tree stage).", arguments=[],
                      action=lambda ws, settings, args: drop_additional_files(ws, settings))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
