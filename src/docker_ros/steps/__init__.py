"""The ten pipeline steps. Standard library only, Python 3.8+: this package runs inside images."""

from typing import TYPE_CHECKING, Callable, Dict

if TYPE_CHECKING:  # the settings type only; nothing outside the standard library at run time
    from docker_ros.runtime.workspace import Workspace
    from docker_ros.settings import Settings

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


def step_mains() -> "Dict[str, Callable[..., None]]":
    """Each step's entry function, by name (imported on first use: the modules import this
    package for its names)."""
    from docker_ros.runtime import prepare
    from docker_ros.steps import (
        blacklist,
        clone,
        colcon,
        command,
        custom,
        debs,
        files,
        pip,
        rosdep,
        scripts,
    )

    return {
        "clone": clone.main,
        "blacklist": blacklist.main,
        "scripts": scripts.main,
        "rosdep": rosdep.main,
        "debs": debs.main,
        "pip": pip.main,
        "files": files.main,
        "custom": custom.main,
        "colcon": colcon.main,
        "command": command.main,
        "prepare": prepare.main,
    }


def run_step(
    name: str,
    ws: "Workspace",
    settings: "Settings",
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: str,
) -> None:
    """Run one step by name: `<its module>.main(ws, settings, ...)`."""
    mains = step_mains()
    if name not in mains:
        from docker_ros.runtime.workspace import StepError

        raise StepError(name, f"unknown step {name!r}; steps: {', '.join(STEPS)}")
    mains[name](ws, settings, phase=phase, dry_run=dry_run, **options)
