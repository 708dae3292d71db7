"""Invoke tasks: one per pipeline step, the composites, and the image commands.

Tasks are thin: they read the settings (every setting is also a flag of every task) and call
the step modules or the image build. Errors users can fix end as one line and a non-zero exit.
"""

from __future__ import annotations

import contextlib
import dataclasses
import getpass
import inspect
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable, Dict, Iterator, List, Sequence, Tuple

from invoke import Collection, Context, Exit, Task

from docker_ros import build
from docker_ros.build import BuiltImage
from docker_ros.config import config_table, image_problems, path_problems, read_settings
from docker_ros.settings import (
    FIELDS,
    Settings,
    SettingsError,
    is_secret,
    require,
    required_for_build,
)
from docker_ros.steps import STEPS
from docker_ros.steps.common import StepError, Workspace, format_argv, setup_logging

Flag = Tuple[str, object, str]  # name, default, help
DRY_RUN: Flag = ("dry_run", False, "Print exactly what would be done; change nothing")
HOST: Flag = ("host", False, "Run the steps directly on this machine instead of in an image")

STEP_HELP = {
    "clone": "Run the before-dependency-identification hook and import .repos files with vcstool",
    "blacklist": "Leave the packages listed in BLACKLISTED_PACKAGES_FILE out of build and deps",
    "scripts": "Run the before-dependency-installation hook script(s)",
    "rosdep": "Resolve package.xml dependencies with rosdep and install them",
    "debs": "Install the apt packages listed in ADDITIONAL_DEBS_FILE",
    "pip": "Install the pip requirements listed in ADDITIONAL_PIP_FILE",
    "files": "Copy ADDITIONAL_FILES_DIR into place (/docker-ros/additional-files in images)",
    "custom": "Run the after-dependency-installation script(s)",
    "colcon": "Build the workspace with colcon (CMAKE_ARGS; underlays /opt/ws_base_image)",
    "command": "Run COMMAND in the built workspace's environment",
}
DEV_STEPS = STEPS[: STEPS.index("custom") + 1]


class TaskError(Exception):
    """An expected failure outside the steps (bad repository layout, failed build...)."""


def settings_task(
    name: str, help: str, flags: Sequence[Flag] = (), *, lenient: bool = False
) -> Callable[..., Task]:
    """Make an invoke Task whose flags are the task's own plus one per setting (`lenient`:
    invalid values reach the task in Settings.problems instead of stopping it)."""

    def decorate(func: Callable[..., Any]) -> Task:
        own = [f[0] for f in flags]

        def body(c: Context, **kwargs: Any) -> Any:
            setup_logging()
            overrides = {n: kwargs.pop(n) for n in list(kwargs) if n in FIELDS}
            try:
                cfg = c.config.get("docker_ros", None) or {}
                settings = read_settings(dict(cfg), overrides, lenient=lenient)
                return func(c, settings, **kwargs)
            except KeyboardInterrupt:
                raise Exit(f"docker-ros {name}: interrupted", code=130) from None
            except (SettingsError, StepError, TaskError) as exc:
                code = getattr(exc, "returncode", 1) or 1
                where = exc.step if isinstance(exc, StepError) else name
                text = exc.message if isinstance(exc, StepError) else str(exc)
                raise Exit(f"docker-ros {where}: {text}", code=code) from None

        params = [inspect.Parameter("c", inspect.Parameter.POSITIONAL_OR_KEYWORD)]
        params += [
            inspect.Parameter(n, inspect.Parameter.KEYWORD_ONLY, default=d) for n, d, _ in flags
        ]
        # Secrets get no flag: a command line is visible to every process on the machine.
        params += [
            inspect.Parameter(n, inspect.Parameter.KEYWORD_ONLY, default=None)
            for n in FIELDS
            if n not in own and not is_secret(n)
        ]
        body.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
        body.__doc__ = help
        body.__name__ = name.replace("-", "_")
        help_map: Dict[str, str] = {n: h for n, _, h in flags}
        for n, f in FIELDS.items():
            if not is_secret(n):
                help_map.setdefault(n, f"{f.metadata['help']} [{n.upper()}]")
        return Task(body, name=name, help=help_map, auto_shortflags=False)

    return decorate


def link_repository(ws: Workspace, repository: Path) -> None:
    """src/target -> the repository (linked, never copied, moved or modified)."""
    if ws.target.is_symlink() or ws.target.exists():
        if ws.target.resolve() != repository:
            raise TaskError(
                f"workspace {ws.root}: src/target points to {ws.target.resolve()}, not to "
                f"{repository}; set WORKSPACE to another folder"
            )
        return
    ws.src.mkdir(parents=True, exist_ok=True)
    ws.target.symlink_to(repository, target_is_directory=True)


@contextlib.contextmanager
def host_workspace(settings: Settings, *, dry_run: bool) -> Iterator[Workspace]:
    """The host workspace. A dry run before the first real run uses a throw-away workspace,
    so that it can show what would happen without creating WORKSPACE."""
    assert settings.workspace
    ws = Workspace(Path(settings.workspace).expanduser())
    repository = Path(settings.build_context).resolve()
    if dry_run and not ws.target.is_symlink():
        with tempfile.TemporaryDirectory(prefix="docker-ros-dry-run-") as tmp:
            print(f"[dry-run] would create {ws.root} with src/target -> {repository}"
                  f" (showing the steps in a temporary workspace: {tmp})")
            temporary = Workspace(tmp)
            link_repository(temporary, repository)
            yield temporary
        return
    link_repository(ws, repository)
    yield ws


def host_options(step: str, ws: Workspace) -> Dict[str, str]:
    return {"destination": str(ws.root / "additional-files")} if step == "files" else {}


def check_inputs(settings: Settings, targets: Sequence[str] = ()) -> None:
    """Bad paths and image names, all at once, before anything runs."""
    problems = {**path_problems(settings), **(image_problems(settings, targets) if targets else {})}
    if problems:
        raise SettingsError("invalid configuration:\n  " + "\n  ".join(problems.values()))


def run_host_steps(settings: Settings, steps: Sequence[str], *, dry_run: bool) -> None:
    from docker_ros.steps import run_step

    check_inputs(settings)
    with host_workspace(settings, dry_run=dry_run) as ws:
        for step in steps:
            run_step(step, ws, settings, phase="all", dry_run=dry_run, **host_options(step, ws))


def make_step_task(step: str) -> Task:
    @settings_task(step, STEP_HELP[step] + " (on the host)", [DRY_RUN])
    def step_task(c: Context, settings: Settings, *, dry_run: bool) -> None:
        run_host_steps(settings, [step], dry_run=dry_run)

    return step_task


@settings_task(
    "config", "Print every setting, its effective value and its source; mark invalid ones",
    lenient=True,
)
def config(c: Context, settings: Settings) -> None:
    problems = {**path_problems(settings), **image_problems(settings, settings.target)}
    print(config_table(settings, problems))
    messages = [*(why for _, why in settings.problems.values()), *problems.values()]
    if messages:
        raise TaskError("invalid configuration:\n  " + "\n  ".join(messages))


@settings_task("dev", "Build the dev image, or with --host run clone..custom here", [HOST, DRY_RUN])
def dev(c: Context, settings: Settings, *, host: bool, dry_run: bool) -> None:
    if host:
        run_host_steps(settings, DEV_STEPS, dry_run=dry_run)
        return
    _build(settings, ("dev",), dry_run=dry_run)


@settings_task(
    "run", "Build the run image, or with --host run all ten steps and COMMAND here", [HOST, DRY_RUN]
)
def run(c: Context, settings: Settings, *, host: bool, dry_run: bool) -> None:
    if host:
        if not settings.command:
            raise SettingsError("missing required configuration: COMMAND")
        run_host_steps(settings, STEPS, dry_run=dry_run)
        return
    _build(settings, ("run",), dry_run=dry_run)


def _build(settings: Settings, targets: Sequence[str], *, dry_run: bool) -> List[BuiltImage]:
    """Build the targets for every platform; print the summary table."""
    settings = dataclasses.replace(settings, target=tuple(targets))
    require(settings, required_for_build(settings))
    check_inputs(settings, targets)
    assert settings.base_image
    if not dry_run:
        try:
            build.check_engine()
        except build.BuildError as exc:
            raise TaskError(str(exc)) from None
    if not dry_run and not build.base_image_available(settings.base_image):
        raise TaskError(
            f"BASE_IMAGE '{settings.base_image}' is neither a local image nor pullable: check "
            "the name, `docker login`, or make one with `inv bootstrap-base-image`"
        )
    built: List[BuiltImage] = []
    for platform in settings.platform:
        for target in [t for t in ("dev", "run") if t in targets]:
            tag = build.platform_ref(build.image_ref(settings, target), platform, settings.platform)
            if dry_run:
                argv = build.plan_build(settings, target=target, platform=platform,
                                        tools_image=f"{build.TOOLS_REPOSITORY}:<hash>",
                                        tag=tag, secrets={})
                print("[dry-run] build:", format_argv(argv))
                continue
            try:
                built.append(build.build_image(settings, target=target, platform=platform,
                                               tag=tag))
            except build.BuildError as exc:
                raise TaskError(str(exc)) from None
    if built:
        print(build.summary_table(built))
    return built


@settings_task(
    "build",
    "Build the TARGET images (dev, run) for every PLATFORM",
    [DRY_RUN, ("until", "", "Build only up to (and including) this step, tag the result "
               "<IMAGE>-until-<step> and stop: inspect it with `docker run -it <tag> bash`")],
)
def build_task(c: Context, settings: Settings, *, dry_run: bool, until: str) -> None:
    if until:
        _build_until(settings, until, dry_run=dry_run)
        return
    _build(settings, settings.target, dry_run=dry_run)


def _build_until(settings: Settings, step: str, *, dry_run: bool) -> None:
    if step not in build.STAGE_OF_STEP:
        raise TaskError(f"--until {step!r}: use one of {', '.join(build.STAGE_OF_STEP)}")
    require(settings, ["base_image"] + (["command"] if step == "command" else []))
    check_inputs(settings, ("run",))
    stage, tag = build.STAGE_OF_STEP[step], build.until_ref(settings, step)
    platform = settings.platform[0]
    if dry_run:
        argv = build.plan_build(settings, target=stage, platform=platform,
                                tools_image=f"{build.TOOLS_REPOSITORY}:<hash>", tag=tag,
                                secrets={})
        print("[dry-run] build:", format_argv(argv))
        return
    try:
        build.check_engine()
        built = build.build_image(settings, target=stage, platform=platform, tag=tag)
    except build.BuildError as exc:
        raise TaskError(str(exc)) from None
    print(build.summary_table([built]))
    print(f"built up to {step} (stage {stage}): docker run --rm -it {tag} bash")


@settings_task(
    "push",
    "Build the TARGET images, then push them (docker-ros tags; one manifest list per image "
    "for several platforms); REGISTRY_USER/REGISTRY_PASSWORD log in first",
    [DRY_RUN],
)
def push_task(c: Context, settings: Settings, *, dry_run: bool) -> None:
    from docker_ros.push import push

    _build(settings, settings.target, dry_run=dry_run)
    try:
        for name in push(settings, settings.target, dry_run=dry_run):
            print(f"pushed {name}")
    except build.BuildError as exc:
        raise TaskError(str(exc)) from None


@settings_task(
    "dev-shell",
    "Interactive shell in the dev image: repository mounted, host user mapped, ws sourced",
    [("rebuild", False, "Build the dev image first even if it exists")],
)
def dev_shell(c: Context, settings: Settings, *, rebuild: bool) -> None:
    ref = build.image_ref(settings, "dev")
    if rebuild or not build.image_exists(ref):
        _build(settings, ("dev",), dry_run=False)
    argv = dev_shell_argv(settings, ref, uid=os.getuid(), gid=os.getgid(),
                          user=getpass.getuser(), tty=sys.stdin.isatty())
    raise SystemExit(subprocess.call(argv))


def dev_shell_argv(
    settings: Settings, ref: str, *, uid: int, gid: int, user: str, tty: bool
) -> List[str]:
    repository = Path(settings.build_context).resolve()
    argv = ["docker", "run", "--rm", "-i"] + (["-t"] if tty else [])
    argv += ["-v", f"{repository}:/docker-ros/ws/src/target"]
    argv += ["-e", f"DOCKER_UID={uid}", "-e", f"DOCKER_GID={gid}", "-e", f"DOCKER_USER={user}"]
    return argv + [ref, "bash"]


@settings_task(
    "bootstrap-base-image",
    "Build a ROS base image from a Debian mirror with debootstrap (no registry needed)",
    [
        ("flavor", "ros1", "ros1 (Debian bookworm + ROS 1) or ros2 (Debian trixie + ament/colcon)"),
        ("tag", "", "Image tag (default docker-ros/<flavor>:<suite>)"),
        ("mirror", "http://deb.debian.org/debian", "Debian mirror"),
        ("force", False, "Rebuild even if the tag exists"),
    ],
)
def bootstrap_base_image(
    c: Context, settings: Settings, *, flavor: str, tag: str, mirror: str, force: bool
) -> None:
    from docker_ros import baseimage

    if flavor not in baseimage.FLAVORS:
        raise TaskError(f"--flavor {flavor!r}: use one of {', '.join(baseimage.FLAVORS)}")
    tag = tag or baseimage.default_tag(flavor)
    for platform in settings.platform:
        ref = tag if len(settings.platform) == 1 else f"{tag}-{platform}"
        print(baseimage.bootstrap(flavor, tag=ref, mirror=mirror, platform=platform, force=force))


@settings_task(
    "example",
    "Bootstrap the ROS 1 base image if missing, build the example's dev+run images, run it",
    [("seconds", 20, "How long to let the example's run image run")],
)
def example(c: Context, settings: Settings, *, seconds: int) -> None:
    from docker_ros import baseimage

    project = Path(__file__).resolve().parents[2] / "example"
    if not project.is_dir():
        raise TaskError(f"{project} not found: the example ships with the source repository")
    settings = read_settings({}, {"build_context": str(project)}, project_dir=project)
    assert settings.base_image
    # Made once with debootstrap, then reused while its recipe is unchanged.
    baseimage.bootstrap("ros1", tag=settings.base_image)
    images = _build(settings, ("dev", "run"), dry_run=False)
    run_ref = next(i.ref for i in images if i.target == "run")
    print(f"docker run --rm {run_ref}   (stopped after {seconds} s)")
    try:
        subprocess.run(["docker", "run", "--rm", "--init", "--name", "docker-ros-example",
                        run_ref], timeout=seconds)
    except subprocess.TimeoutExpired:
        subprocess.run(["docker", "rm", "-f", "docker-ros-example"], capture_output=True)


def collection() -> Collection:
    ns = Collection()
    for step in STEPS:
        ns.add_task(make_step_task(step))
    for task in (config, dev, run, build_task, push_task, dev_shell, bootstrap_base_image,
                 example):
        ns.add_task(task)
    return ns


ns = collection()

