"""The install space as the run image's COMMAND check sees it: every file, folder and symlink
with its mode, and the compiled files (ELF objects, static archives) empty. The check reads
names, modes and the setup scripts it sources, never a compiled file's bytes: after an edit
that changes only compiled files the view is as it was, and BuildKit, whose COPY is
content-addressed, finds the check cached (the run stage no longer waits for it).
`python3 -m docker_ros.in_image.runtime.installview INSTALL VIEW`: run by the build stage.
Standard library only, Python 3.8+ (runs inside images)."""

import os
import shutil
import stat
import sys
from pathlib import Path
from typing import List

from docker_ros.in_image.runtime.entry import image_main
from docker_ros.in_image.runtime.files import is_elf

AR_MAGIC = b"!<arch>\n"  # (static libraries)


def compiled(path: Path) -> bool:
    if is_elf(path):
        return True
    with path.open("rb") as handle:
        return handle.read(len(AR_MAGIC)) == AR_MAGIC


def make_view(install: Path, view: Path) -> None:
    """Write the view of install into view (which must not exist)."""
    folders = []
    view.mkdir(parents=True)
    for dirpath, dirnames, filenames in os.walk(str(install)):
        folder = Path(dirpath)
        target = view / folder.relative_to(install)
        target.mkdir(exist_ok=True)
        folders.append((folder, target))
        for name in sorted(dirnames + filenames):
            source, copy = folder / name, target / name
            mode = os.lstat(str(source)).st_mode
            if stat.S_ISLNK(mode):
                os.symlink(os.readlink(str(source)), str(copy))
            elif stat.S_ISREG(mode):
                if compiled(source):
                    copy.touch()
                else:
                    shutil.copyfile(str(source), str(copy))
                os.chmod(str(copy), stat.S_IMODE(mode))
    for folder, target in reversed(folders):  # (last: a read-only folder took its files)
        os.chmod(str(target), stat.S_IMODE(os.lstat(str(folder)).st_mode))


def main(argv: List[str]) -> int:
    return image_main(argv, module="runtime.installview", step="colcon",
                      description="Write the view of the install space INSTALL that the "
                      "COMMAND check reads to VIEW (the build stage).",
                      arguments=["INSTALL", "VIEW"], settings=False,
                      action=lambda ws, settings, args: make_view(Path(args[0]), Path(args[1])))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
