"""debs: install the extra apt packages listed in ADDITIONAL_DEBS_FILE(s)."""

from typing import Any, Dict, List, Sequence

from docker_ros.in_image.runtime.apt import apt_install
from docker_ros.in_image.runtime.files import collect_list_entries
from docker_ros.in_image.runtime.lock import locked_arguments
from docker_ros.in_image.runtime.workspace import Workspace, phases, step_log
from docker_ros.in_image.settings import Settings

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
    **options: str,
) -> None:
    """collect: read the list file(s) into debs.json; apply: apt-get install them."""
    do_collect, do_apply = phases(STEP, phase)
    with step_log(STEP):
        plan: Dict[str, Any] = {}
        if do_collect:
            entries, _ = collect_list_entries(ws, STEP, settings, "additional_debs_file")
            plan = plan_debs(entries)
            ws.save_plan(STEP, STATE_FILE, plan, dry_run=dry_run)
        if do_apply:
            if not do_collect:
                plan = ws.load_plan(STEP, STATE_FILE)
            packages: List[str] = list(plan.get("packages") or [])
            packages = locked_arguments(ws, settings, step=STEP, kind="apt",
                                        inputs=packages, dry_run=dry_run) or packages
            apt_install(
                packages,
                step=STEP,
                dry_run=dry_run,
                what="installing ADDITIONAL_DEBS_FILE packages",
            )
