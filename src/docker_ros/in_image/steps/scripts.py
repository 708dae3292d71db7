"""scripts: run the before-dependency-installation hook script(s)."""

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime import hooks
from docker_ros.in_image.runtime.workspace import Workspace

STEP = "scripts"


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: object,
) -> None:
    """collect: copy the BEFORE_DEPENDENCY_INSTALLATION_SCRIPT(s) into the state; apply: run."""
    hooks.main(
        ws, STEP, settings, "before_dependency_installation_script", phase=phase, dry_run=dry_run
    )
