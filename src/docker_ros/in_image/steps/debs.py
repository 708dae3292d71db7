"""debs: install the extra apt packages listed in ADDITIONAL_DEBS_FILE(s)."""

from typing import Any, Dict, List, Sequence

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.apt import apt_install
from docker_ros.in_image.runtime.files import collect_list_entries
from docker_ros.in_image.runtime.lock import locked_arguments
from docker_ros.in_image.runtime.workspace import Workspace, planned_step

STEP = "debs"
STATE_FILE = "debs.json"


def plan_debs(entries: Sequence[str]) -> Dict[str, Any]:
    """debs.json: sorted unique package specs (`pkg`, `pkg=1.2`, `pkg/bookworm`); a line may
    hold several, separated by white space, as docker-ros's shell command allowed."""
    return {"packages": sorted({word for entry in entries for word in entry.split()})}


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: object,
) -> None:
    """collect: read the list file(s) into debs.json; apply: apt-get install them."""

    def install(plan: Dict[str, Any]) -> None:
        packages: List[str] = list(plan.get("packages") or [])
        packages = locked_arguments(ws, settings, step=STEP, kind="apt",
                                    inputs=packages, dry_run=dry_run) or packages
        apt_install(packages, step=STEP, dry_run=dry_run,
                    what="installing ADDITIONAL_DEBS_FILE packages")

    planned_step(ws, STEP, STATE_FILE, phase=phase, dry_run=dry_run, apply=install,
                 collect=lambda: plan_debs(collect_list_entries(
                     ws, STEP, settings, "additional_debs_file")[0]))
