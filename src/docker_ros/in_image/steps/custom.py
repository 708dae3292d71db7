"""custom: run the after-dependency-installation hook script(s)."""

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime import hooks
from docker_ros.in_image.runtime.workspace import Workspace

STEP = "custom"


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: object,
) -> None:
    """collect: copy the AFTER_DEPENDENCY_INSTALLATION_SCRIPT(s) into the state; apply: run."""
    hooks.main(
        ws, STEP, settings, "after_dependency_installation_script", phase=phase, dry_run=dry_run
    )
