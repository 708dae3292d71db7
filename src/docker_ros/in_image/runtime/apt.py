"""apt-get, non-interactive and with the build's caches.
Standard library only, Python 3.8+ (runs inside images)."""

import glob
import os
from pathlib import Path
from typing import Dict, List, Sequence

from docker_ros.in_image.runtime.process import hook_context, is_root, run
from docker_ros.in_image.runtime.workspace import LOG, StepError

# dpkg's record of what is installed
DPKG_STATUS = Path("/var/lib/dpkg/status")


def apt_env() -> Dict[str, str]:
    env = dict(os.environ)
    env["DEBIAN_FRONTEND"] = "noninteractive"
    return env


def apt_get(args: Sequence[str]) -> List[str]:
    """apt-get argv, non-interactive also through sudo (which resets the environment)."""
    if is_root():
        return ["apt-get", *args]
    return ["sudo", "DEBIAN_FRONTEND=noninteractive", "apt-get", *args]


def apt_lists_present(lists_dir: Path = Path("/var/lib/apt/lists")) -> bool:
    """Whether apt has package lists (images usually delete them: then `apt-get update` first)."""
    return bool(glob.glob(str(lists_dir / "*_Packages*")))


def install_options(context: str) -> List[str]:
    """apt-get install options for where it runs (hook_context). In an image, dpkg skips its
    fsync calls (--force-unsafe-io, as Docker's own Debian images build): a crash loses only
    a layer that is built again, while on overlayfs the syncs cost a large share of the
    install time. Never on the host, whose package database a crash could leave broken."""
    options = ["-y", "--no-install-recommends"]
    if context == "image":
        options += ["-o", "Dpkg::Options::=--force-unsafe-io"]
    return options


def apt_install(packages: Sequence[str], *, step: str, dry_run: bool, what: str = "") -> None:
    """apt-get install, updating the lists when absent or stale."""
    if not packages:
        LOG.info("%s: no apt packages to install", step)
        return
    install = apt_get(["install", *install_options(hook_context()), *packages])
    update = apt_get(["update"])
    if dry_run:
        if not apt_lists_present():
            run(update, step=step, dry_run=True)
        run(install, step=step, dry_run=True)
        return
    if not apt_lists_present():
        run(update, step=step, env=apt_env())
    try:
        run(install, step=step, env=apt_env(), what=what)
    except StepError as exc:
        if exc.returncode == 127:
            raise
        # Stale lists (host, or an apt cache mount) make apt miss packages: update once, retry.
        LOG.info("%s: apt-get install failed, updating package lists and retrying", step)
        run(update, step=step, env=apt_env())
        run(install, step=step, env=apt_env(), what=what)
