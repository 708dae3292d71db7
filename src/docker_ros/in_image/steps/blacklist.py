"""blacklist: ROS packages that are neither built nor used for dependencies.

Nothing is deleted (on the host src/target is the user's repository): the result is
`blacklist.json`, which rosdep and colcon (`--packages-ignore`) read. In the image's copy of
the sources (option mark_ignored, never on the host) each blacklisted package also gets a
COLCON_IGNORE file, so that a plain `colcon build` or `colcon list` in a dev container does
not see it either."""

import logging
from pathlib import Path
from typing import Any, Dict, List, Sequence

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.files import collect_list_entries, unique
from docker_ros.in_image.runtime.packages import Package, find_packages
from docker_ros.in_image.runtime.workspace import Workspace, dry, phases, step_log

STEP = "blacklist"
STATE_FILE = "blacklist.json"
LOG = logging.getLogger(__name__)


def plan_blacklist(
    names: Sequence[str], packages: Sequence[Package], ws: Workspace
) -> Dict[str, Any]:
    """The blacklist.json content: listed names, the packages they match, unknown names."""
    matched: Dict[str, List[str]] = {}
    for package in packages:
        if package.name in names:
            matched.setdefault(package.name, []).append(ws.relative(package.path))
    return {
        "names": sorted(set(names)),
        "packages": {name: sorted(paths) for name, paths in sorted(matched.items())},
        "unknown": sorted(set(names) - set(matched)),
    }


def listed_names(entries: Sequence[str]) -> List[str]:
    """The package names of a blacklist file's lines: a line may hold several (docker-ros
    passed lines to a shell command)."""
    return unique([word for entry in entries for word in entry.split()])


def compute(ws: Workspace, settings: Settings) -> Dict[str, Any]:
    entries, _ = collect_list_entries(ws, STEP, settings, "blacklisted_packages_file")
    return plan_blacklist(listed_names(entries), find_packages(ws, settings, step=STEP), ws)


def blacklisted_packages(ws: Workspace, settings: Settings) -> List[str]:
    """Names of the blacklisted packages found in the workspace, from blacklist.json when the
    blacklist step ran, else computed now (without writing state)."""
    data = ws.read_state(STATE_FILE)
    if not isinstance(data, dict):
        LOG.info("%s not in %s: computing the blacklist now", STATE_FILE, ws.state)
        data = compute(ws, settings)
    packages = data.get("packages") or {}
    return sorted(packages)


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: object,
) -> None:
    """Find the blacklisted packages and record them in blacklist.json (single phase)."""
    phases(STEP, phase)
    with step_log(STEP):
        data = compute(ws, settings)
        for name in data["unknown"]:
            LOG.warning("%s: blacklisted package %r matches no package in %s", STEP, name, ws.src)
        for name, paths in data["packages"].items():
            LOG.info(
                "%s: %s (%s) is neither built nor used for dependencies",
                STEP,
                name,
                ", ".join(paths),
            )
        ws.save_plan(STEP, STATE_FILE, data, dry_run=dry_run)
        if options.get("mark_ignored"):
            for paths in data["packages"].values():
                for path in paths:
                    mark_ignored(ws.root / path, dry_run=dry_run)


def mark_ignored(package: Path, *, dry_run: bool) -> None:
    marker = package / "COLCON_IGNORE"
    if dry_run:
        dry(STEP, f"create {marker}")
        return
    marker.write_text("blacklisted by docker-ros (BLACKLISTED_PACKAGES_FILE)\n")
