"""Invoke tasks: one per pipeline step, the composites, and the image commands.

Tasks are thin: they read the settings (every setting is also a flag of every task) and hand
over to docker_ros.host.pipeline (the build, test, slim, push and CI flows) or the step modules.
Errors users can fix end as one line and a non-zero exit.
"""

from __future__ import annotations

import dataclasses
import inspect
import os
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple, Union

from invoke import Argument, Collection, Context, Exit, Task

import docker_ros
from docker_ros.host import baseimage, build, container, devcontainer, devshell, engine
from docker_ros.host.config import config_table, input_problems, read_settings
from docker_ros.host.lock import lock, lock_status
from docker_ros.host.pipeline import (
    TaskError,
    TaskFailed,
    build_targets,
    build_until,
    check_slim_options,
    composite_flow,
    logged_in_job,
    push_and_report,
    require_tasks,
    run_ci_plan,
    run_dev_shell,
    run_host_steps,
    run_in_container,
    run_test_stage,
    slim_one,
    slimmed_here,
)
from docker_ros.host.push import manifest, official_only_names, push, push_targets
from docker_ros.in_image.ci import error_annotation, plan_ci_job, slim_skipped
from docker_ros.in_image.runtime.lock import LockError
from docker_ros.in_image.runtime.workspace import StepError, setup_logging
from docker_ros.in_image.settings import (
    FIELDS,
    Settings,
    SettingsError,
    default_doc,
    env_name,
    flag_name,
    has_bare_set,
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

    def get_arguments(self, ignore_unknown_help: Optional[bool] = None) -> List[Argument]:
        """A repeatable flag with an optional value (--set) starts without a raw value, so that
        invoke gives a bare one True (invoke would drop it silently): parse_set refuses it."""
        args = super().get_arguments(ignore_unknown_help)
        for arg in args:
            if arg.kind is list and arg.optional:
                arg.raw_value = None
        return args


def settings_task(
    name: str,
    help: str,
    flags: Sequence[Flag] = (),
    uses: Sequence[str] = (),
    shortflags: Mapping[str, str] = {},
    lenient: bool = False,
    logs_in: Union[bool, str] = False,
    login_required: bool = False,
    helps: Mapping[str, str] = {},
) -> Callable[..., Task]:
    """Make an invoke Task whose flags are the task's own, one per setting it uses, and
    --set NAME=VALUE for any other setting (the full reference: the docs' configuration
    reference and `inv config`);
    a flag whose default is a list may be given several times. `lenient`: invalid values
    reach the task in Settings.problems instead of stopping it. `logs_in`: a task that reaches
    a registry (a private BASE_IMAGE, CACHE_FROM/CACHE_TO, pushes) runs logged in with
    REGISTRY_USER/REGISTRY_PASSWORD when they are set, in a DOCKER_CONFIG of its own, removed
    at its end (see logs_in_now); a failed login stops only a task that `login_required`
    (pushes), others go on with a warning (they may need no registry). `helps`: a setting's
    flag help where this task needs another than the declaration's."""

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
                given = list(kwargs.pop("set") or ())
                # (a flag after a bare --set may have been taken as its value: refused already)
                if has_bare_set(sys.argv[1:]) and not any(
                        item is True or str(item).startswith("-") for item in given):
                    given.append(True)
                overrides: Dict[str, object] = dict(parse_set(given))
                overrides.update({n: kwargs.pop(n) for n in settings_flags
                                  if kwargs[n] is not None})
                for n in settings_flags:
                    kwargs.pop(n, None)
                near = [k for k in c.config if k != "docker_ros" and
                        str(k).lower().replace("-", "_") in ("docker_ros", "dockerros")]
                if near:  # (its settings would be ignored without a word)
                    raise SettingsError(f"invoke configuration: `{near[0]}:` is not read; the "
                                        "settings go under `docker_ros:`")
                cfg = c.config.get("docker_ros", None) or {}
                if not isinstance(cfg, Mapping):
                    raise SettingsError(f"invoke configuration: `docker_ros:` is {cfg!r}: "
                                        "give it the settings as NAME: value lines")
                settings = read_settings(dict(cfg), overrides, lenient=lenient, command=name)
                if not logs_in_now(logs_in, kwargs):
                    return func(c, settings, **kwargs)
                with logged_in_job(settings, f"docker-ros {name}", required=login_required,
                                   dry_run=bool(kwargs.get("dry_run"))):
                    return func(c, settings, **kwargs)
            except KeyboardInterrupt as exc:
                # (a build's names what BuildKit had tagged before the Ctrl-C: build.noted)
                detail = f" ({exc})" if str(exc) else ""
                if isinstance(exc, Terminated):
                    raise Exit(f"docker-ros {name}: terminated (SIGTERM){detail}",
                               code=143) from None
                raise Exit(f"docker-ros {name}: interrupted{detail}", code=130) from None
            except (SettingsError, StepError, TaskError, LockError, engine.EngineError) as exc:
                code = getattr(exc, "returncode", 1) or 1
                where = exc.step if isinstance(exc, StepError) else name
                text = exc.message if isinstance(exc, StepError) else str(exc)
                annotation = error_annotation(os.environ, f"docker-ros {where}", text)
                if annotation and not isinstance(exc, TaskFailed):  # (the task's is there)
                    print(annotation, flush=True)
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
            help_map[n] = helps.get(n) or setting_help(n)
        for n in SECRETS:
            help_map[n] = f"Refused (a secret): set {env_name(n)} in the env or .env"
        repeatable = ["set"] + [n for n, d, _ in flags if isinstance(d, list)]
        # `--enable-slim` alone means true; `--enable-slim=false` (or a value after it) too.
        # A bare --set gets True that way (invoke drops an empty one): parse_set refuses it.
        optional = [n for n in settings_flags if kind_of(n) == "bool"] + list(SECRETS) + ["set"]
        return SettingsTask(body, name=name, help=help_map, auto_shortflags=False,
                            iterable=repeatable, optional=optional, shortflags=shortflags)

    return decorate


def logs_in_now(logs_in: Union[bool, str], flags: Mapping[str, object]) -> bool:
    """Whether a task logs in: `logs_in` True (not with --host, on this machine), or the name
    of the flag that makes it reach a registry (a step's --in-container)."""
    if isinstance(logs_in, str):
        return bool(flags.get(logs_in))
    return logs_in and not flags.get("host")


class Terminated(KeyboardInterrupt):
    """SIGTERM (a cancelled CI job, `timeout`, `kill`), handled as Ctrl-C is: what the task
    made (a login's DOCKER_CONFIG, a key file, temporary folders) is removed on the way out."""


def terminated(signum: int, frame: Any) -> None:
    # Once: a second SIGTERM (the job's runner and `docker-ros ci` may both send one) must not
    # cut short the clean-up the first one started.
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise Terminated


def hear_interrupts() -> None:
    """Ctrl-C raises KeyboardInterrupt (exit 130, "interrupted") even when we started with
    SIGINT ignored, as a background job of a script does: buildx and docker (Go) stop on it
    anyway, and their failure must not be reported as a failed build. SIGTERM raises
    Terminated (exit 143), whose way out runs the same clean-ups."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, terminated)


def setting_help(name: str) -> str:
    """A setting's flag help: its description and default (the flag names the variable).
    A default with a word too long for the help column (which invoke would break) is left to
    `inv config`."""
    default = default_doc(name).replace("`", "").replace("*", "")
    text = str(FIELDS[name].metadata["help"])
    # (the defaults of the CI integrations are not this machine's: the reference lists them)
    if (not default or max(len(word) for word in default.split()) > 26
            or default.startswith("GitHub Action:")):
        return text
    if default.startswith("required"):  # no default: a value must be given
        return f"{text} ({default})"
    return f"{text} (default: {default})"


def invoke_dry(c: Context) -> bool:
    """invoke's core flag -R/--dry (config run.dry)."""
    try:
        return bool(c.config.run.dry)
    except AttributeError:
        return False


def make_step_task(step: str) -> Task:
    number = f"{STEPS.index(step) + 1}/{len(STEPS)}"
    summary = (f"[step {number}] {BY_NAME[step].help}\n\nRuns on this machine, in WORKSPACE; "
               "with --in-container in a container of the image state before the step.")

    shell_on_failure = (SHELL_ON_FAILURE[0], False,
                        "With --in-container, w" + SHELL_ON_FAILURE[2][1:])

    @settings_task(step, summary, [DRY_RUN, IN_CONTAINER, shell_on_failure],
                   uses=BY_NAME[step].settings + HOST_SETTINGS + ("base_image", "image"),
                   helps={"base_image": "Base image of --in-container (`name:tag`)"},
                   logs_in="in_container")
    def step_task(c: Context, settings: Settings, *, dry_run: bool, in_container: bool,
                  shell_on_failure: bool) -> None:
        if in_container:

            run_in_container(settings, container.plan_step(settings, step), dry_run=dry_run,
                             shell_on_failure=shell_on_failure)
            return
        if shell_on_failure:
            raise TaskError("--shell-on-failure needs --in-container (on the host, your own "
                            "shell is where the step failed)")
        run_host_steps(settings, [step], dry_run=dry_run)

    return step_task


@settings_task(
    "config", "Print every setting, its effective value and its source; mark invalid ones",
    lenient=True,
)
def config(c: Context, settings: Settings) -> None:
    problems = input_problems(settings, made_images(settings), images=True)
    missing = [n for n in required_for_build(settings) if not getattr(settings, n)]
    print(config_table(settings, problems, missing))
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
    logs_in=True,
)
def lock_task(c: Context, settings: Settings, *, check: bool, host: bool) -> None:

    started = time.monotonic()
    if not host:
        require(settings, ["base_image"])  # (COMMAND is no input of what a build installs)
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
    "run": "Build the run image (or run all ten steps --host or --in-container)\n\n"
           "--host runs the ten steps on this machine, in WORKSPACE (the tenth, command, runs "
           "COMMAND); --in-container runs them in one container, tagged <IMAGE>-after-run.",
}


def make_composite_task(name: str) -> Task:
    @settings_task(name, COMPOSITE_HELP[name], [HOST, DRY_RUN, IN_CONTAINER, SHELL_ON_FAILURE],
                   uses=IMAGE_SETTINGS + HOST_SETTINGS + (("command",) if name == "run" else ()),
                   logs_in=True)
    def composite(c: Context, settings: Settings, **flags: bool) -> None:
        composite_flow(settings, name, **flags)

    return composite


dev, run = make_composite_task("dev"), make_composite_task("run")


@settings_task(
    "build",
    "Build the TARGET images (dev, run) for every PLATFORM",
    [DRY_RUN, SHELL_ON_FAILURE,
     ("until", "", "Build only up to (and including) this step, tag the result "
      "<IMAGE>-until-<step>, print how to enter it and run the next step, and stop")],
    uses=("target",) + IMAGE_SETTINGS + ("command", "enable_slim"),
    logs_in=True,
)
def build_task(c: Context, settings: Settings, *, dry_run: bool, shell_on_failure: bool,
               until: str) -> None:
    if until:
        build_until(settings, until, dry_run=dry_run, shell_on_failure=shell_on_failure)
        return
    if settings.enable_slim and "run" not in settings.target and (
            settings.source_of("enable_slim") != "default"):
        print(f"build: ENABLE_SLIM slims the run image, which TARGET {','.join(settings.target)} "
              "does not build: no slim image (add run to TARGET for one)", flush=True)
    build_targets(settings, settings.target, dry_run=dry_run, shell_on_failure=shell_on_failure,
           slim=settings.enable_slim)
    if settings.enable_industrial_ci:
        run_test_stage(settings, results_dir="", dry_run=dry_run)


@settings_task(
    "slim",
    "Slim the run image: keep what COMMAND uses, check it runs alike\n\n"
    "Traces COMMAND in the run image (pulled or built if missing), keeps what it opens plus "
    "the library closure and the include paths of SLIM_BUILD_ARGS, and tags "
    "SLIM_IMAGE_NAME:SLIM_IMAGE_TAG only when the result behaves like the run image.",
    [DRY_RUN],
    uses=IMAGE_SETTINGS + ("command", "slim_build_args", "additional_slim_build_args"),
    logs_in=True,
)
def slim_task(c: Context, settings: Settings, *, dry_run: bool) -> None:
    settings = dataclasses.replace(settings, target=("run",))
    check_slim_options(settings)
    here = [p for p in settings.platform if slimmed_here(settings, p)]
    if not dry_run:
        try:  # (the builder first: a docker context's engine holds the run image)
            build.check_engine(settings)
        except build.BuildError as exc:
            raise TaskError(str(exc)) from None
    missing = [] if dry_run else [ref for ref in (build.target_ref(settings, "run", p)
                                                  for p in here)
                                  if not engine.local_or_pulled(ref)]
    if missing:  # (the platforms slimmed here only: another one may build under QEMU)
        print(f"slim: run image {', '.join(missing)} neither local nor pullable: building it")
        build_targets(settings, ("run",), dry_run=dry_run, slim=True, only=here)
        return
    slimmed = [slim_one(settings, p, dry_run=dry_run) for p in here]
    if not dry_run:
        print(build.summary_table(slimmed))


@settings_task(
    "test",
    "colcon test in the dev image; JUnit XML and logs copied to the host\n\n"
    "Builds the dev stage (from cache), runs colcon build, colcon test and colcon test-result "
    "in it, copies the results to --results-dir and fails when a test fails.",
    [DRY_RUN, ("results_dir", "", "Folder for the JUnit XML, logs and exit codes (default "
               "TEST_RESULTS_DIR, else <WORKSPACE>/test-results; replaced only if empty or "
               "made by an earlier run)")],
    uses=IMAGE_SETTINGS + ("command", "workspace"),
    logs_in=True,
)
def test_task(c: Context, settings: Settings, *, dry_run: bool, results_dir: str) -> None:
    run_test_stage(settings, results_dir=results_dir, dry_run=dry_run)


@settings_task(
    "push",
    "Build the TARGET images, then push them with docker-ros's tags\n\n"
    "Several platforms: one manifest list per image. REGISTRY_USER and REGISTRY_PASSWORD "
    "(the password: environment or .env only) log in first (a private BASE_IMAGE or "
    "CACHE_FROM), into a DOCKER_CONFIG of the task's own that is removed at its end.",
    [DRY_RUN],
    uses=("target",) + IMAGE_SETTINGS + ("command",) + PUSH_SETTINGS,
    logs_in=True,
    login_required=True,
)
def push_task(c: Context, settings: Settings, *, dry_run: bool) -> None:

    targets = push_targets(settings)
    unpushable = official_only_names(settings, targets)
    if unpushable:
        raise TaskError("; ".join(unpushable))
    build_targets(settings, settings.target, dry_run=dry_run, slim=settings.enable_slim)
    push_and_report(settings, targets, push, dry_run=dry_run)


@settings_task(
    "manifest",
    "Write multi-arch manifest lists over the pushed `-<arch>` images\n\n"
    "IMAGE_NAME:IMAGE_TAG (and dev, slim) over the `-<arch>` images that one CI job per "
    "PLATFORM pushed with ENABLE_SINGLEARCH_PUSH.",
    [DRY_RUN],
    uses=("target", "image", "image_tag", "platform") + PUSH_SETTINGS,
    logs_in=True,
    login_required=True,
)
def manifest_task(c: Context, settings: Settings, *, dry_run: bool) -> None:

    images = made_images(settings)
    if "slim" in images:
        require_tasks([["slim"]], ns.task_names)
    push_and_report(settings, images, manifest, dry_run=dry_run)


@settings_task(
    "ci",
    "One CI job: build, test, slim, push (GitHub Action, GitLab template)\n\n"
    "Each a `docker-ros` task: build, test (ENABLE_INDUSTRIAL_CI), slim (ENABLE_SLIM), push.",
    [DRY_RUN],
    uses=("target",) + IMAGE_SETTINGS + ("command",) + PUSH_SETTINGS,
    logs_in=True,
    login_required=True,
)
def ci_task(c: Context, settings: Settings, *, dry_run: bool) -> None:

    host = host_platform()
    plan = plan_ci_job(target=settings.target, enable_industrial_ci=settings.enable_industrial_ci,
                       enable_slim=settings.enable_slim, slims_here=host in settings.platform)
    require_tasks(plan, ns.task_names)
    if "slim" in made_images(settings) and ["slim"] not in plan:
        print(slim_skipped(settings.platform, host), flush=True)
    if ["slim"] in plan:
        check_slim_options(settings)
    run_ci_plan(settings, plan, dry_run=dry_run)


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
    logs_in=True,
)
def dev_shell(
    c: Context, settings: Settings, *, cmd: str, volume: List[str], env: List[str],
    network: str, name: str, privileged: bool, device: List[str], x11: str, gpus: str,
    rebuild: bool, dry_run: bool,
) -> None:
    code = run_dev_shell(settings, devshell.ShellOptions(
        command=cmd, volumes=volume, env=env, network=network, name=name, privileged=privileged,
        devices=device, gpus=gpus), x11=x11, rebuild=rebuild, dry_run=dry_run)
    if code:
        raise Exit(code=code)


@settings_task(
    "devcontainer",
    "Write .devcontainer/devcontainer.json for the dev image (as dev-shell runs it)\n\n"
    "A second run keeps your own edits (docs/devcontainer.md).",
    [
        ("volume", [], "Extra mount HOST:CONTAINER[:ro] (repeatable)"),
        ("env", [], "Environment variable NAME=VALUE, or NAME for the host's (repeatable)"),
        ("network", "", "Container network, e.g. host (which also shares IPC, for DDS)"),
        ("privileged", False, "Run privileged (all devices)"),
        ("device", [], "Host device to add, e.g. /dev/ttyUSB0 (repeatable)"),
        ("x11", "auto", "X11 forwarding: auto = when DISPLAY is a local display; true; false"),
        ("gpus", "auto", "auto = all when the host has the nvidia runtime; none; or a --gpus "
         "value"),
        ("check", False, "Change nothing; exit 1 when the file is not up to date (for CI)"),
        ("force", False, "Merge into a devcontainer.json docker-ros did not write"),
        DRY_RUN,
    ],
    uses=IMAGE_SETTINGS,
)
def devcontainer_task(
    c: Context, settings: Settings, *, volume: List[str], env: List[str], network: str,
    privileged: bool, device: List[str], x11: str, gpus: str, check: bool, force: bool,
    dry_run: bool,
) -> None:
    try:
        code = devcontainer.run(settings, devshell.ShellOptions(
            volumes=volume, env=env, network=network, privileged=privileged, devices=device),
            x11=x11, gpus=gpus, check=check, force=force, dry_run=dry_run)
    except devcontainer.DevcontainerError as exc:
        raise TaskError(str(exc)) from None
    if code:
        raise Exit(code=code)


@settings_task(
    "bootstrap-base-image",
    "Build a ROS base image from a Debian/Ubuntu mirror (debootstrap, no registry)",
    [
        ("flavor", "ros1", "ros1 (Debian bookworm + ROS 1), ros2 (Debian trixie + ament/colcon) "
         "or ros1-ubuntu (Ubuntu 22.04 jammy + its ROS 1, colcon and vcstool from PyPI)"),
        ("tag", "", "Image tag (default docker-ros/<ros1|ros2>:<suite>); the image of another "
         "architecture than this machine's is tagged <tag>-<arch> (a BASE_IMAGE of <tag> finds "
         "it when building for that PLATFORM)"),
        ("mirror", "", "Debian or Ubuntu mirror (default: deb.debian.org; archive.ubuntu.com, "
         "ports.ubuntu.com for arm64)"),
        ("force", False, "Rebuild even if the tag exists"),
    ],
    uses=("platform", "extra_ca_certs"),
)
def bootstrap_base_image(
    c: Context, settings: Settings, *, flavor: str, tag: str, mirror: str, force: bool
) -> None:

    if flavor not in baseimage.FLAVORS:
        raise TaskError(f"--flavor {flavor!r}: use one of {', '.join(baseimage.FLAVORS)}")
    tag = tag or baseimage.default_tag(flavor)
    with tempfile.TemporaryDirectory(prefix="docker-ros-ca-") as tmp:
        try:  # (ros1-ubuntu's pip behind a TLS-intercepting proxy)
            bundle = build.extra_ca_bundle(settings, Path(tmp))
        except build.BuildError as exc:
            raise TaskError(str(exc)) from None
        for platform in settings.platform:
            print(baseimage.bootstrap(flavor, tag=tag, mirror=mirror, platform=platform,
                                      force=force, ca_bundle=bundle))


# the bundled example workspace at the source repository's root (two levels above the package,
# src/docker_ros): an installed wheel has none
EXAMPLE = Path(docker_ros.__file__).resolve().parents[2] / "example"


@settings_task(
    "example",
    "Build and run the bundled example (bootstraps its ROS 1 base image)",
    [("seconds", 20, "How long to let the example's run image run")],
)
def example(c: Context, settings: Settings, *, seconds: int) -> None:

    project = EXAMPLE
    if not project.is_dir():
        raise TaskError(f"{project} not found: the example ships with the source repository")
    given = {n: getattr(settings, n) for n in FIELDS if settings.source_of(n) == "flag"}
    settings = read_settings({}, {**given, "build_context": str(project)}, project_dir=project)
    assert settings.base_image
    # the engine that keeps the images BUILDER builds (a docker context's own), base included
    try:
        cli = container.docker_cli(settings)
    except build.BuildError as exc:
        raise TaskError(str(exc)) from None
    # Made once with debootstrap, then reused while its recipe is unchanged.
    baseimage.bootstrap("ros1", tag=settings.base_image, cli=cli,
                        network=settings.build_network or "")
    images = build_targets(settings, ("dev", "run"), dry_run=False)
    run_ref = next(i.ref for i in images if i.target == "run")
    print(f"{' '.join(cli)} run --rm {run_ref}   (stopped after {seconds} s)")
    try:
        subprocess.run([*cli, "run", "--rm", "--name", "docker-ros-example", run_ref],
                       timeout=seconds)
    except subprocess.TimeoutExpired:
        subprocess.run([*cli, "rm", "-f", "docker-ros-example"], capture_output=True)


def collection() -> Collection:
    ns = Collection()
    for step in STEPS:
        ns.add_task(make_step_task(step))
    for task in (config, dev, run, build_task, test_task, slim_task, push_task, manifest_task,
                 ci_task, dev_shell, devcontainer_task, lock_task,
                 bootstrap_base_image, example):
        ns.add_task(task)
    return ns


ns = collection()

