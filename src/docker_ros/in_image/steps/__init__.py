"""The ten pipeline steps. Standard library only, Python 3.8+: this package runs inside images."""

import importlib
from dataclasses import dataclass
from typing import Callable, Dict, Mapping, Tuple

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.workspace import StepError, Workspace


@dataclass(frozen=True)
class Option:
    """An option of `python3 -m docker_ros.in_image.steps` that only some steps take."""

    name: str  # as a keyword of the steps' main(); the flag is --name-with-dashes
    help: str
    choices: Tuple[str, ...] = ()
    takes_value: bool = False  # False: a switch, passed on as True


@dataclass(frozen=True)
class Step:
    """One pipeline step, declared once: the invoke task, its flags, the in-image runner's
    options and the in-container stage table derive from here, and a unit test checks the
    Dockerfile's step calls against it. Its code is `main` in the module of the same name."""

    name: str
    help: str  # the task's line in `inv --list`
    settings: Tuple[str, ...]  # the step's own variables (SPEC's table): flags of its task
    stage: str  # the Dockerfile stage where it runs (when it runs alone: `--in-container`)
    options: Tuple[str, ...] = ()  # names of OPTIONS it takes
    phases: bool = False  # resolution (collect) and installation (apply) run apart in images
    package: str = "docker_ros.in_image.steps"  # where its module is

    @property
    def module(self) -> str:
        return f"{self.package}.{self.name}"


OPTIONS = (
    Option("dependency_types", "rosdep apply, prepare: all dependencies (dev) or exec only "
           "(run)", choices=("all", "exec"), takes_value=True),
    Option("destination", "files apply: target folder (default /docker-ros/additional-files)",
           takes_value=True),
    Option("stamp_changed", "colcon: give sources whose content changed since the last build "
           "the current time (image builds, where build/ is a cache mount and COPY keeps old "
           "times)"),
    Option("mark_ignored", "blacklist: put a COLCON_IGNORE file into each blacklisted package "
           "(the image's copy of the sources; never the user's repository)"),
    Option("check", "command: check that the programs, ROS packages, executables and launch "
           "files COMMAND names are here; run nothing (the run image's build)"),
    Option("imports_only", "clone: import the .repos files present, no hook (the image's "
           "upstream stage)"),
)

DECLARED = (
    Step("clone", "Run the identification hook, import .repos files with vcstool",
         ("vcs_import_file", "enable_recursive_vcs_import", "git_https_server",
          "git_https_user", "before_dependency_identification_script"),
         "source", options=("imports_only",)),
    Step("blacklist", "Leave BLACKLISTED_PACKAGES_FILE's packages out of build and deps",
         ("blacklisted_packages_file", "enable_recursive_blacklisted_packages"),
         "source", options=("mark_ignored",)),
    Step("scripts", "Run the before-dependency-installation hook script(s)",
         ("before_dependency_installation_script",), "dependencies-dev", phases=True),
    Step("rosdep", "Resolve package.xml dependencies with rosdep and install them",
         ("ros_distro", "rosdep_rules_file"), "dependencies-dev",
         options=("dependency_types",), phases=True),
    Step("debs", "Install the apt packages listed in ADDITIONAL_DEBS_FILE",
         ("additional_debs_file", "enable_recursive_additional_debs"), "dependencies-dev",
         phases=True),
    Step("pip", "Install the pip requirements listed in ADDITIONAL_PIP_FILE",
         ("additional_pip_file", "enable_recursive_additional_pip"), "dependencies-dev",
         phases=True),
    Step("files", "Copy ADDITIONAL_FILES_DIR (images: /docker-ros/additional-files)",
         ("additional_files_dir",), "dependencies-dev", options=("destination",), phases=True),
    Step("custom", "Run the after-dependency-installation script(s)",
         ("after_dependency_installation_script",), "dependencies-dev", phases=True),
    Step("colcon", "Build the workspace with colcon (underlay: /opt/ws_base_image)",
         ("cmake_args", "ros_distro"), "build", options=("stamp_changed",)),
    Step("command", "Run COMMAND in the built workspace's environment", ("command",), "run",
         options=("check",), phases=True),
)
# Image-only preparation of the base (not a pipeline step; no host task).
PREPARE = Step("prepare", "Install python3, tini, git, vcstool, rosdep, colcon (and ROS)", (),
               "base", options=("dependency_types",), package="docker_ros.in_image.runtime")

STEPS = tuple(step.name for step in DECLARED)
IMAGE_STEPS = (PREPARE.name,)
BY_NAME = {step.name: step for step in (*DECLARED, PREPARE)}
# the steps whose resolution and installation run apart (the Dockerfile's resolve stage)
PHASED = tuple(step.name for step in DECLARED if step.phases)


def step_options(step: str, given: "Mapping[str, object]") -> "Dict[str, object]":
    """The given options (name -> value) that are step's: with several steps in one call, each
    gets only its own, as if it ran alone (--phase, --workspace and --dry-run are every step's)."""
    return {name: value for name, value in given.items() if name in BY_NAME[step].options}


def step_main(name: str) -> "Callable[..., None]":
    """A step's entry function: `main` of its declared module (imported on first use: the
    modules import this package's names)."""
    return importlib.import_module(BY_NAME[name].module).main


def run_step(
    name: str,
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: object,
) -> None:
    """Run one step by name: `<its module>.main(ws, settings, ...)`."""
    if name not in BY_NAME:
        raise StepError(name, f"unknown step {name!r}; steps: {', '.join(STEPS)}")
    step_main(name)(ws, settings, phase=phase, dry_run=dry_run, **options)
