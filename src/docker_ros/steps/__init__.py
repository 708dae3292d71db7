"""The ten pipeline steps. Standard library only, Python 3.8+: this package runs inside images."""

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the settings type only; nothing outside the standard library at run time
    from docker_ros.settings import Settings
    from docker_ros.steps.common import Workspace

STEPS = (
    "clone",
    "blacklist",
    "scripts",
    "rosdep",
    "debs",
    "pip",
    "files",
    "custom",
    "colcon",
    "command",
)
# Image-only preparation of the base (not a pipeline step; no host task).
IMAGE_STEPS = ("prepare",)


def run_step(
    name: str,
    ws: "Workspace",
    settings: "Settings",
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: str,
) -> None:
    """Run one step by name: `docker_ros.steps.<name>.main(ws, settings, ...)`."""
    if name not in STEPS + IMAGE_STEPS:
        from docker_ros.steps.common import StepError

        raise StepError(name, f"unknown step {name!r}; steps: {', '.join(STEPS)}")
    module = importlib.import_module(f"docker_ros.steps.{name}")
    module.main(ws, settings, phase=phase, dry_run=dry_run, **options)
