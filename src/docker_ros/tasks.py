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
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path
from typing import Any, Callable, Dict, Iterator, List, Mapping, Sequence, Tuple

from invoke import Collection, Context, Exit, Task

from docker_ros.host import build, engine
from docker_ros.host.build import BuiltImage
from docker_ros.host.config import config_table, input_problems, read_settings
from docker_ros.host.lock import lock_status
from docker_ros.in_image.runtime.lock import LockError
from docker_ros.in_image.runtime.workspace import StepError, Workspace, format_argv, setup_logging
from docker_ros.in_image.settings import (
    FIELDS,
    Settings,
    SettingsError,
    default_doc,
    display_value,
    env_name,
    flag_name,
    host_platform,
    is_secret,
    kind_of,
    made_images,
    parse_set,
    require,
    required_for_build,
    settings_where,
)
from docker_ros.in_image.steps import BY_NAME, STEPS

Flag = Tuple[str, object, str]  # name, default, help
DRY_RUN: Flag = ("dry_run", False, "Print exactly what would be done; change nothing")
HOST: Flag = ("host", False, "Run the steps directly on this machine instead of in an image")
IN_CONTAINER: Flag = (
    "in_container", False,
    "Run in a container of the image state just before the step (built up to there), the "
    "repository mounted when the step reads sources; tag the result <IMAGE>-after-<step>",
)
SHELL_ON_FAILURE: Flag = (
    "shell_on_failure", False,
    "When a step fails, open a shell in the state just before the failed command (no "
    "terminal: tag that state <IMAGE>-failed-<step> and print how to enter it)",
)

DEV_STEPS = tuple(s for s in STEPS if BY_NAME[s].stage in ("source", "dependencies-dev"))


class TaskError(Exception):
    """An expected failure outside the steps (bad repository layout, failed build...)."""


# Settings every image, host-step or pushing task takes as flags (their declarations' `flags`);
# any other setting: --set NAME=VALUE.
IMAGE_SETTINGS = settings_where("flags", "image")
HOST_SETTINGS = settings_where("flags", "host")
PUSH_SETTINGS = settings_where("flags", "push")
SET: Flag = ("set", None, "Any setting, as NAME=VALUE (repeatable), e.g. --set ENABLE_SLIM=false")
# Secrets are never flags (a command line is visible to every process on the machine); every
# task still parses them, to say so (and where they go) instead of invoke's "No idea what".
SECRETS = settings_where("secret", True)


def secret_flag_refusal(task: str, given: Sequence[str]) -> str:
    """The message for secrets given as flags ('' when none was)."""
    if not given:
        return ""
    names = ", ".join(env_name(n) for n in given)
    return (f"docker-ros {task}: {' and '.join(flag_name(n) for n in given)}: a secret is never "
            f"a flag (a command line is visible to every process on this machine); set {names}"
            " in the environment or in the project's .env file")


class SettingsTask(Task):
    """A Task with chosen short flags (e.g. dev-shell's -c) although auto_shortflags is off:
    automatic ones would differ between tasks, as every setting is a flag of every task."""

    def __init__(self, *args: Any, shortflags: Mapping[str, str], **kwargs: Any) -> None:
        self.shortflags = shortflags
        super().__init__(*args, **kwargs)

    def arg_opts(self, name: str, default: str, taken_names: Any) -> Dict[str, Any]:
        opts = super().arg_opts(name, default, taken_names)
        if name in self.shortflags:
            opts["names"].append(self.shortflags[name])
        return opts


def settings_task(
    name: str,
    help: str,
    flags: Sequence[Flag] = (),
    uses: Sequence[str] = (),
    shortflags: Mapping[str, str] = {},
    lenient: bool = False,
) -> Callable[..., Task]:
    """Make an invoke Task whose flags are the task's own, one per setting it uses, and
    --set NAME=VALUE for any other setting (the full reference: README and `inv config`);
    a flag whose default is a list may be given several times. `lenient`: invalid values
    reach the task in Settings.problems instead of stopping it."""

    def decorate(func: Callable[..., Any]) -> Task:
        own = [f[0] for f in flags]
        settings_flags = [n for n in dict.fromkeys(uses) if n not in own and not is_secret(n)]

        def body(c: Context, **kwargs: Any) -> Any:
            setup_logging()
            hear_interrupts()
            refused = secret_flag_refusal(name, [n for n in SECRETS if kwargs.pop(n) is not None])
            if refused:
                raise Exit(refused, code=2)
            if invoke_dry(c):
                # invoke's -R/--dry means "do not act": our dry run, or a refusal, never ignored.
                if "dry_run" not in kwargs:
                    raise Exit(f"docker-ros {name}: has no dry run; invoke's -R/--dry is only "
                               "accepted by tasks with --dry-run", code=2)
                kwargs["dry_run"] = True
            try:
                # A named flag beats a --set of the same setting.
                overrides: Dict[str, object] = dict(parse_set(kwargs.pop("set") or ()))
                overrides.update({n: kwargs.pop(n) for n in settings_flags
                                  if kwargs[n] is not None})
                for n in settings_flags:
                    kwargs.pop(n, None)
                cfg = c.config.get("docker_ros", None) or {}
                settings = read_settings(dict(cfg), overrides, lenient=lenient, command=name)
                return func(c, settings, **kwargs)
            except KeyboardInterrupt:
                raise Exit(f"docker-ros {name}: interrupted", code=130) from None
            except (SettingsError, StepError, TaskError, LockError) as exc:
                code = getattr(exc, "returncode", 1) or 1
                where = exc.step if isinstance(exc, StepError) else name
                text = exc.message if isinstance(exc, StepError) else str(exc)
                raise Exit(f"docker-ros {where}: {text}", code=code) from None

        keyword = inspect.Parameter.KEYWORD_ONLY
        params = [inspect.Parameter("c", inspect.Parameter.POSITIONAL_OR_KEYWORD)]
        params += [inspect.Parameter(n, keyword, default=d) for n, d, _ in [*flags, SET]]
        # Secrets get no flag: a command line is visible to every process on the machine.
        params += [inspect.Parameter(n, keyword, default=None) for n in settings_flags]
        params += [inspect.Parameter(n, keyword, default=None) for n in SECRETS]
        body.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
        # First paragraph: the one line of `--list` (at most 76 characters, a test checks);
        # the others wrapped for 80 columns.
        first, *rest = help.split("\n\n")
        body.__doc__ = "\n\n".join([first, *(textwrap.fill(part, 76) for part in rest)])
        body.__name__ = name.replace("-", "_")
        help_map: Dict[str, str] = {n: h for n, _, h in [*flags, SET]}
        for n in settings_flags:
            help_map[n] = setting_help(n)
        for n in SECRETS:
            help_map[n] = f"Refused (a secret): set {env_name(n)} in the env or .env"
        repeatable = ["set"] + [n for n, d, _ in flags if isinstance(d, list)]
        # `--enable-slim` alone means true; `--enable-slim=false` (or a value after it) too.
        optional = [n for n in settings_flags if kind_of(n) == "bool"] + list(SECRETS)
        return SettingsTask(body, name=name, help=help_map, auto_shortflags=False,
                            iterable=repeatable, optional=optional, shortflags=shortflags)

    return decorate


def hear_interrupts() -> None:
    """Ctrl-C raises KeyboardInterrupt (exit 130, "interrupted") even when we started with
    SIGINT ignored, as a background job of a script does: buildx and docker (Go) stop on it
    anyway, and their failure must not be reported as a failed build."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def setting_help(name: str) -> str:
    """A setting's flag help: its description and default (the flag names the variable).
    A default with a word too long for the help column is left to `inv config`."""
    default = default_doc(name).replace("`", "").replace("*", "")
    text = str(FIELDS[name].metadata["help"])
    if not default or max(len(word) for word in default.split()) > 24:
        return text
    return f"{text} (default: {default})"


def invoke_dry(c: Context) -> bool:
    """invoke's core flag -R/--dry (config run.dry)."""
    try:
        return bool(c.config.run.dry)
    except AttributeError:
        return False


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
    problems = input_problems(settings, targets, images=bool(targets))
    if problems:
        raise SettingsError("invalid configuration:\n  " + "\n  ".join(problems.values()))


def run_host_steps(settings: Settings, steps: Sequence[str], *, dry_run: bool) -> None:
    from docker_ros.in_image.steps import run_step

    check_inputs(settings)
    with host_workspace(settings, dry_run=dry_run) as ws:
        for step in steps:
            run_step(step, ws, settings, phase="all", dry_run=dry_run, **host_options(step, ws))


def make_step_task(step: str) -> Task:
    number = f"{STEPS.index(step) + 1}/{len(STEPS)}"
    summary = (f"[step {number}] {BY_NAME[step].help}\n\nRuns on this machine, in WORKSPACE; "
               "with --in-container in a container of the image state before the step.")

    @settings_task(step, summary, [DRY_RUN, IN_CONTAINER, SHELL_ON_FAILURE],
                   uses=BY_NAME[step].settings + HOST_SETTINGS + ("base_image", "image"))
    def step_task(c: Context, settings: Settings, *, dry_run: bool, in_container: bool,
                  shell_on_failure: bool) -> None:
        if in_container:
            from docker_ros.host import container

            run_in_container(settings, container.plan_step(settings, step), dry_run=dry_run,
                             shell_on_failure=shell_on_failure)
            return
        if shell_on_failure:
            raise TaskError("--shell-on-failure needs --in-container (on the host, your own "
                            "shell is where the step failed)")
        run_host_steps(settings, [step], dry_run=dry_run)

    return step_task


def run_in_container(settings: Settings, plan: Any, *, dry_run: bool,
                     shell_on_failure: bool) -> str:
    """Build the plan's start stage, run its commands in one container, tag the result."""
    from docker_ros.host import container

    runs_command = plan.start == "run" or ("command",) in plan.commands
    require(settings, ["base_image"] + (["command"] if runs_command else []))
    check_inputs(settings, ("run",) if runs_command else ("dev",))
    mount = f" -v {Path(settings.build_context).resolve()}:{container.TARGET_DIR}"
    mount = mount if plan.sources else ""
    if dry_run:
        argv = build.plan_shown(settings, target=plan.start, platform=settings.platform[0],
                                tag=container.tag_of(settings, "stage", plan.start))
        print("[dry-run] build:", format_argv(argv))
        print(f"[dry-run] in one container of it{f' ({mount.strip()})' if mount else ''}:")
        for command in plan.commands:
            print("[dry-run]   " + container.shown(command))
        print(f"[dry-run] commit and tag {plan.tag}")
        return plan.tag
    try:
        build.check_engine(settings)
        tag = container.run_plan(settings, plan, shell_on_failure=shell_on_failure)
    except build.BuildError as exc:
        raise TaskError(str(exc)) from None
    print(f"tagged {tag}\n  enter it: docker run --rm -it{mount} {tag} bash")
    return tag


@settings_task(
    "config", "Print every setting, its effective value and its source; mark invalid ones",
    lenient=True,
)
def config(c: Context, settings: Settings) -> None:
    problems = input_problems(settings, settings.target, images=True)
    print(config_table(settings, problems))
    print(lock_status(settings))
    messages = [*(why for _, why in settings.problems.values()), *problems.values()]
    if messages:
        raise TaskError("invalid configuration:\n  " + "\n  ".join(messages))


@settings_task(
    "lock", "Write docker-ros.lock: what a build installs, per target and PLATFORM\n\n"
    "Resolves in the image's lock stages, where the installs run, without building the "
    "images: imported commits, apt and pip versions (dependencies included), the collect "
    "phases' inputs and the rosdep rules' digest; the base image's digest from the host. "
    "--host: this machine's entry, for the host steps. --check: write nothing, print what "
    "differs and exit non-zero when the lock is stale.",
    [("check", False, "Compare with docker-ros.lock and print the differences; write nothing"),
     ("host", False, "Lock this machine's host entry (host steps) instead of the images")],
    uses=("build_context", "base_image", "platform")
    + tuple(n for n in IMAGE_SETTINGS if n != "locked"),  # (it resolves afresh, unlocked)
)
def lock_task(c: Context, settings: Settings, *, check: bool, host: bool) -> None:
    from docker_ros.host.lock import lock

    started = time.monotonic()
    if not host:
        require(settings, required_for_build(settings))
        try:
            build.check_engine()
        except build.BuildError as exc:
            raise TaskError(str(exc)) from None
    try:
        changes = lock(settings, check=check, host=host, out=sys.stdout)
    except build.BuildError as exc:
        raise TaskError(f"resolving the lock failed: {exc}") from None
    print("\n".join(changes) or "docker-ros.lock: up to date")
    print(f"lock: {time.monotonic() - started:.1f} s")
    if check and changes:
        raise TaskError("docker-ros.lock is stale: run `inv lock`")


COMPOSITE_HELP = {
    "dev": "Build the dev image (or run clone..custom --host or --in-container)\n\n"
           "--host runs the steps on this machine, in WORKSPACE; --in-container runs them in "
           "one container, tagged <IMAGE>-after-dev.",
    "run": "Build the run image (or run all steps and COMMAND --host or --in-container)\n\n"
           "--host runs the ten steps and COMMAND on this machine, in WORKSPACE; "
           "--in-container runs them in one container, tagged <IMAGE>-after-run.",
}


def make_composite_task(name: str) -> Task:
    @settings_task(name, COMPOSITE_HELP[name], [HOST, DRY_RUN, IN_CONTAINER, SHELL_ON_FAILURE],
                   uses=IMAGE_SETTINGS + HOST_SETTINGS + (("command",) if name == "run" else ()))
    def composite(c: Context, settings: Settings, **flags: bool) -> None:
        _composite(settings, name, **flags)

    return composite


dev, run = make_composite_task("dev"), make_composite_task("run")


def _composite(settings: Settings, name: str, *, host: bool, dry_run: bool, in_container: bool,
               shell_on_failure: bool) -> None:
    if host and in_container:
        raise TaskError("--host and --in-container: choose one")
    if name == "run" and (host or in_container) and not settings.command:
        raise SettingsError("missing required configuration: COMMAND")
    if in_container:
        from docker_ros.host import container

        run_in_container(settings, container.plan_composite(settings, name), dry_run=dry_run,
                         shell_on_failure=shell_on_failure)
    elif host:
        if shell_on_failure:
            raise TaskError("--shell-on-failure needs --in-container or an image build")
        run_host_steps(settings, DEV_STEPS if name == "dev" else STEPS, dry_run=dry_run)
    else:
        _build(settings, (name,), dry_run=dry_run, shell_on_failure=shell_on_failure)


def _build(settings: Settings, targets: Sequence[str], *, dry_run: bool,
           shell_on_failure: bool = False, slim: bool = False) -> List[BuiltImage]:
    """Build the targets for every platform (and with slim, the slim image after run); print
    the summary table."""
    settings = dataclasses.replace(settings, target=tuple(targets))
    require(settings, required_for_build(settings))
    check_inputs(settings, targets)
    if slim and "run" in targets:
        _slim_options(settings)
    assert settings.base_image
    if not dry_run:
        try:
            build.check_engine(settings)
        except build.BuildError as exc:
            raise TaskError(str(exc)) from None
    if not dry_run:
        try:  # every platform's base before the first build (build_images says which)
            for platform in settings.platform:
                build.platform_base(settings, platform)
        except build.BuildError as exc:
            raise TaskError(str(exc)) from None
    built: List[BuiltImage] = []
    for platform in settings.platform:
        # BUILD_STATE_FROM: the run image's build state too, for the next job's `push`
        kinds = ("dev", "run") + (("build-state",) if settings.build_state_from else ())
        tags = {t: build.target_ref(settings, t, platform)
                for t in kinds if t in targets or (t == "build-state" and "run" in targets)}
        if dry_run and build.can_bake(settings):
            specs = {t: build.shown_definition(settings, target=t, platform=platform, tag=tag)
                     for t, tag in tags.items()}
            print("[dry-run] build:",
                  format_argv(build.plan_bake(specs, "<temporary>/docker-ros.bake.json")))
            print(f"[dry-run] with <temporary>/docker-ros.bake.json:\n{build.bake_file(specs)}",
                  end="")
        elif dry_run:
            for target, tag in tags.items():
                argv = build.plan_shown(settings, target=target, platform=platform, tag=tag)
                print("[dry-run] build:", format_argv(argv))
        else:
            try:
                built += build.build_images(settings, targets=tags, platform=platform)
            except build.BuildError as exc:
                if shell_on_failure:
                    reproduce_failure(settings, exc)
                raise TaskError(str(exc)) from None
        if slim and "run" in targets and _slims(settings, platform):
            slimmed = _slim(settings, platform, dry_run=dry_run)
            built += [] if dry_run else [slimmed]
    if built:
        print(build.summary_table(built))
        print(lock_status(settings))
    return built


@settings_task(
    "build",
    "Build the TARGET images (dev, run) for every PLATFORM",
    [DRY_RUN, SHELL_ON_FAILURE,
     ("until", "", "Build only up to (and including) this step, tag the result "
      "<IMAGE>-until-<step> and stop; the README shows how to run the next step in it")],
    uses=("target",) + IMAGE_SETTINGS + ("command", "enable_slim"),
)
def build_task(c: Context, settings: Settings, *, dry_run: bool, shell_on_failure: bool,
               until: str) -> None:
    if until:
        _build_until(settings, until, dry_run=dry_run, shell_on_failure=shell_on_failure)
        return
    _build(settings, settings.target, dry_run=dry_run, shell_on_failure=shell_on_failure,
           slim=settings.enable_slim)
    if settings.enable_industrial_ci:
        _test(settings, results_dir="", dry_run=dry_run)


def _slim_options(settings: Settings) -> None:
    """SLIM_BUILD_ARGS and ADDITIONAL_SLIM_BUILD_ARGS checked before anything is built."""
    from docker_ros.host import slim

    try:
        slim.parse_slim_args(slim.slim_args(settings))
    except slim.SlimError as exc:
        raise TaskError(str(exc)) from None


def _slims(settings: Settings, platform: str) -> bool:
    """Whether platform's run image is slimmed here (build.slim_platforms); says when not."""
    if platform in build.slim_platforms(settings.platform, host_platform()):
        return True
    print(f"slim: {platform}: not slimmed on this {host_platform()} runner (slimming runs the "
          f"image; as docker-ros, a multi-arch job slims the runner's architecture only)",
          flush=True)
    return False


def _slim(settings: Settings, platform: str, *, dry_run: bool) -> BuiltImage:
    from docker_ros.host import slim

    try:
        result = slim.slim_image(settings, platform, dry_run=dry_run)
    except slim.SlimError as exc:
        raise TaskError(str(exc)) from None
    return BuiltImage("slim", result.ref, platform, result.seconds)


@settings_task(
    "slim",
    "Slim the run image: keep what COMMAND uses, check it runs alike\n\n"
    "Traces COMMAND in the run image (pulled or built if missing), keeps what it opens plus "
    "the library closure and the include paths of SLIM_BUILD_ARGS, and tags "
    "SLIM_IMAGE_NAME:SLIM_IMAGE_TAG only when the result behaves like the run image.",
    [DRY_RUN],
    uses=IMAGE_SETTINGS + ("command", "slim_build_args", "additional_slim_build_args"),
)
def slim_task(c: Context, settings: Settings, *, dry_run: bool) -> None:
    settings = dataclasses.replace(settings, target=("run",))
    _slim_options(settings)
    refs = [build.platform_ref(build.image_ref(settings, "run"), p, settings.platform)
            for p in settings.platform]
    if not dry_run and not all(engine.local_or_pulled(ref) for ref in refs):
        print(f"slim: run image {', '.join(refs)} neither local nor pullable: building it")
        _build(settings, ("run",), dry_run=dry_run, slim=True)
        return
    slimmed = [_slim(settings, p, dry_run=dry_run) for p in settings.platform
               if _slims(settings, p)]
    if not dry_run:
        print(build.summary_table(slimmed))


def default_results_dir(settings: Settings) -> Path:
    """Outside the repository (never written into the user's sources unasked)."""
    assert settings.workspace
    return Path(settings.workspace).expanduser() / "test-results"


def _test(settings: Settings, *, results_dir: str, dry_run: bool) -> None:
    """Build the test stage per platform, export its results; fail when a test failed."""
    from docker_ros.in_image import testing

    require(settings, required_for_build(settings))
    root = Path(results_dir).resolve() if results_dir else default_results_dir(settings)
    failures = []
    for platform in settings.platform:
        dest = root if len(settings.platform) == 1 else root / platform
        problem = testing.check_results_dir(dest)
        if problem:
            raise TaskError(f"--results-dir: {problem}")
        tag = build.platform_ref(build.image_ref(settings, "dev") + "-test", platform,
                                 settings.platform)
        run = {"DOCKER_ROS_TEST_RUN": str(time.time_ns())}
        with tempfile.TemporaryDirectory(prefix="docker-ros-test-") as tmp:
            output = f"type=local,dest={tmp}"
            if dry_run:
                argv = build.plan_shown(settings, target="test-results", platform=platform,
                                        tag=tag, output=output, extra_build_args=run)
                print("[dry-run] test:", format_argv(argv))
                print(f"[dry-run] test: would copy the results to {dest}")
                continue
            try:
                build.check_engine(settings)
                build.build_image(settings, target="test-results", platform=platform, tag=tag,
                                  output=output, extra_build_args=run)
                outcome = testing.read_outcome(Path(tmp))
            except (build.BuildError, FileNotFoundError) as exc:
                raise TaskError(str(exc)) from None
            counts = testing.summarize(Path(tmp) / testing.JUNIT)
            testing.install_results(Path(tmp), dest)
        print(f"docker-ros test ({platform}): {testing.format_summary(counts)} "
              f"(JUnit XML and logs in {dest})")
        failed = testing.verdict(outcome, counts)
        if failed:
            failures.append(f"{failed} ({platform})")
    if failures:
        raise TaskError("; ".join(failures) + "; see the output above")


@settings_task(
    "test",
    "colcon test in the dev image; JUnit XML and logs copied to the host\n\n"
    "Builds the dev stage (from cache), runs colcon build, colcon test and colcon test-result "
    "in it, copies the results to --results-dir and fails when a test fails.",
    [DRY_RUN, ("results_dir", "", "Folder for the JUnit XML, logs and exit codes (default "
               "<WORKSPACE>/test-results; replaced only if empty or made by an earlier run)")],
    uses=IMAGE_SETTINGS + ("workspace",),
)
def test_task(c: Context, settings: Settings, *, dry_run: bool, results_dir: str) -> None:
    _test(settings, results_dir=results_dir, dry_run=dry_run)


def reproduce_failure(settings: Settings, error: build.BuildError) -> None:
    """--shell-on-failure of an image build: the failed step again, in a container of the state
    before it, with the shell where it fails."""
    from docker_ros.host import container

    if error.stage not in container.STAGES:
        print(f"docker-ros build: --shell-on-failure: the failure is not in one of the ten "
              f"steps (stage {error.stage or 'unknown'}); no shell to open")
        return
    try:
        container.reproduce(settings, error, out=sys.stdout)
    except build.BuildError as exc:
        print(f"docker-ros build: --shell-on-failure: {exc}")


def _build_until(settings: Settings, step: str, *, dry_run: bool,
                 shell_on_failure: bool) -> None:
    from docker_ros.host import container

    if step not in STEPS:
        raise TaskError(f"--until {step!r}: use one of {', '.join(STEPS)}")
    plan = container.plan_until(settings, step)
    tag = run_in_container(settings, plan, dry_run=dry_run, shell_on_failure=shell_on_failure)
    following = container.next_command(step)
    if following and not dry_run:
        print(f"  next step: docker run --rm {tag} {container.shown(following)}")


@settings_task(
    "push",
    "Build the TARGET images, then push them with docker-ros's tags\n\n"
    "Several platforms: one manifest list per image. REGISTRY_USER and REGISTRY_PASSWORD "
    "(environment or .env only) log in first.",
    [DRY_RUN],
    uses=("target",) + IMAGE_SETTINGS + ("command",) + PUSH_SETTINGS,
)
def push_task(c: Context, settings: Settings, *, dry_run: bool) -> None:
    from docker_ros.host.push import push, push_targets

    _build(settings, settings.target, dry_run=dry_run, slim=settings.enable_slim)
    _push_and_report(settings, push_targets(settings), push, dry_run=dry_run)


def _push_and_report(
    settings: Settings, targets: Sequence[str], action: Callable[..., List[str]], *, dry_run: bool
) -> None:
    """Run push or manifest; print the pushed names and hand them to the CI as outputs."""
    from docker_ros.host.push import plan_outputs, write_outputs

    try:
        pushed = action(settings, targets, dry_run=dry_run)
    except build.BuildError as exc:
        raise TaskError(str(exc)) from None
    for name in pushed:
        print(f"pushed {name}")
    if pushed:
        write_outputs(plan_outputs(settings, targets, pushed), os.environ)


@settings_task(
    "manifest",
    "Write multi-arch manifest lists over the pushed `-<arch>` images\n\n"
    "IMAGE_NAME:IMAGE_TAG (and dev, slim) over the `-<arch>` images that one CI job per "
    "PLATFORM pushed with ENABLE_SINGLEARCH_PUSH.",
    [DRY_RUN],
    uses=("target", "image", "image_tag", "platform") + PUSH_SETTINGS,
)
def manifest_task(c: Context, settings: Settings, *, dry_run: bool) -> None:
    from docker_ros.host.push import manifest

    images = made_images(settings)
    if "slim" in images:
        _require_tasks([["slim"]])
    with _job_login(settings, "docker-ros manifest", dry_run=dry_run):
        _push_and_report(settings, images, manifest, dry_run=dry_run)


@settings_task(
    "ci",
    "One CI job: build, test, slim, push (GitHub Action, GitLab template)\n\n"
    "Each a `docker-ros` task: build, test (ENABLE_INDUSTRIAL_CI), slim (ENABLE_SLIM), push.",
    [DRY_RUN],
    uses=("target",) + IMAGE_SETTINGS + ("command",) + PUSH_SETTINGS,
)
def ci_task(c: Context, settings: Settings, *, dry_run: bool) -> None:
    from docker_ros.in_image.ci import plan_ci_job

    plan = plan_ci_job(target=settings.target, enable_industrial_ci=settings.enable_industrial_ci,
                       enable_slim=settings.enable_slim)
    _require_tasks(plan)
    if ["slim"] in plan:
        _slim_options(settings)
    # The tasks re-read .env, invoke.yaml and the environment; flags given to `ci` go along.
    given = [arg for n in FIELDS if settings.source_of(n) == "flag"
             for arg in ("--set", f"{env_name(n)}={display_value(settings, n)}")]
    with _job_login(settings, "docker-ros ci", dry_run=dry_run):
        for argv in plan:
            command = [sys.executable, "-m", "docker_ros", *argv, *given]
            print(f"docker-ros ci: docker-ros {format_argv(argv + given)}", flush=True)
            if dry_run:
                continue
            code = subprocess.call(command)
            if code != 0:
                raise TaskError(f"`docker-ros {argv[0]}` failed with exit code {code}; "
                                "nothing after it ran")


@contextlib.contextmanager
def _job_login(settings: Settings, label: str, *, dry_run: bool) -> Iterator[None]:
    """REGISTRY_USER/REGISTRY_PASSWORD logged in before anything else of the job (a private
    BASE_IMAGE or CACHE_FROM), into a DOCKER_CONFIG of the job's own, removed at its end."""
    from docker_ros.host.login import LoginError, job_login, plan_login

    argv = plan_login(settings)
    if dry_run:
        if argv:
            print(f"[dry-run] {label}: {format_argv(argv)} (password on standard input, "
                  "job-private DOCKER_CONFIG)")
        yield
        return
    try:
        with job_login(settings, os.environ, label=label):
            yield
    except LoginError as exc:
        raise TaskError(str(exc)) from None


def _require_tasks(plan: Sequence[Sequence[str]]) -> None:
    from docker_ros.in_image.ci import missing_tasks

    problems = missing_tasks(plan, ns.task_names)
    if problems:
        raise TaskError("; ".join(problems))


@settings_task(
    "dev-shell",
    "Shell in the dev image: repository mounted, host user mapped, ws sourced",
    [
        ("cmd", "", "Run this command (bash -c) instead of an interactive shell; its exit "
         "code is the task's"),
        ("volume", [], "Extra mount HOST:CONTAINER[:ro] (repeatable)"),
        ("env", [], "Environment variable NAME=VALUE, or NAME to pass the host's (repeatable)"),
        ("network", "", "Container network, e.g. host (which also shares IPC, for DDS)"),
        ("name", "", "Container name"),
        ("privileged", False, "Run privileged (all devices)"),
        ("device", [], "Host device to add, e.g. /dev/ttyUSB0 (repeatable)"),
        ("x11", "auto", "X11 forwarding (DISPLAY, /tmp/.X11-unix, xauth cookie): auto = when "
         "DISPLAY is a local display whose socket exists; true; false"),
        ("gpus", "auto", "docker run --gpus value (all, device=0, ...): auto = all when the "
         "nvidia runtime is in `docker info`; none"),
        ("rebuild", False, "Build the dev image first even if it exists"),
        DRY_RUN,
    ],
    uses=IMAGE_SETTINGS,
    shortflags={"cmd": "c"},
)
def dev_shell(
    c: Context, settings: Settings, *, cmd: str, volume: List[str], env: List[str],
    network: str, name: str, privileged: bool, device: List[str], x11: str, gpus: str,
    rebuild: bool, dry_run: bool,
) -> None:
    from docker_ros.host import devshell

    ref = build.image_ref(settings, "dev")
    try:
        devshell.check_volumes(volume)
        display = os.environ.get("DISPLAY", "") if devshell.select_x11(
            x11, os.environ.get("DISPLAY", "")) else ""
        runtimes = devshell.docker_runtimes() if gpus == "auto" else []
        gpu = devshell.select_gpus(gpus, runtimes)
    except devshell.DevShellError as exc:
        raise TaskError(str(exc)) from None
    user = devshell.HostUser(os.getuid(), os.getgid(), getpass.getuser(),
                             tty=sys.stdin.isatty() and sys.stdout.isatty())
    with tempfile.TemporaryDirectory(prefix="docker-ros-dev-shell-") as tmp:
        cookie = devshell.write_cookie(display, os.environ, Path(tmp) / "xauth") if display else ""
        options = devshell.ShellOptions(
            command=cmd, volumes=volume, env=env, network=network, name=name,
            privileged=privileged, devices=device, gpus=gpu, x11_display=display,
            xauthority=cookie)
        argv = devshell.dev_shell_argv(settings, ref, options, user)
        if dry_run:
            print(format_argv(argv))
            return
        if rebuild or not build.image_exists(ref):
            _build(settings, ("dev",), dry_run=False)
        code = subprocess.call(argv)
    if code:
        raise Exit(code=code)


@settings_task(
    "bootstrap-base-image",
    "Build a ROS base image from a Debian mirror (debootstrap, no registry)",
    [
        ("flavor", "ros1", "ros1 (Debian bookworm + ROS 1) or ros2 (Debian trixie + ament/colcon)"),
        ("tag", "", "Image tag (default docker-ros/<flavor>:<suite>); the image of another "
         "architecture than this machine's is tagged <tag>-<arch> (a BASE_IMAGE of <tag> finds "
         "it when building for that PLATFORM)"),
        ("mirror", "http://deb.debian.org/debian", "Debian mirror"),
        ("force", False, "Rebuild even if the tag exists"),
    ],
    uses=("platform",),
)
def bootstrap_base_image(
    c: Context, settings: Settings, *, flavor: str, tag: str, mirror: str, force: bool
) -> None:
    from docker_ros.host import baseimage

    if flavor not in baseimage.FLAVORS:
        raise TaskError(f"--flavor {flavor!r}: use one of {', '.join(baseimage.FLAVORS)}")
    tag = tag or baseimage.default_tag(flavor)
    for platform in settings.platform:
        print(baseimage.bootstrap(flavor, tag=tag, mirror=mirror, platform=platform, force=force))


@settings_task(
    "example",
    "Build and run the bundled example (bootstraps its ROS 1 base image)",
    [("seconds", 20, "How long to let the example's run image run")],
)
def example(c: Context, settings: Settings, *, seconds: int) -> None:
    from docker_ros.host import baseimage

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
        subprocess.run(["docker", "run", "--rm", "--name", "docker-ros-example",
                        run_ref], timeout=seconds)
    except subprocess.TimeoutExpired:
        subprocess.run(["docker", "rm", "-f", "docker-ros-example"], capture_output=True)


def collection() -> Collection:
    ns = Collection()
    for step in STEPS:
        ns.add_task(make_step_task(step))
    for task in (config, dev, run, build_task, test_task, slim_task, push_task, manifest_task,
                 ci_task, dev_shell, lock_task,
                 bootstrap_base_image, example):
        ns.add_task(task)
    return ns


ns = collection()

