"""Invoke tasks: one per pipeline step, the composites, and the image commands.

Tasks are thin: they read the settings (every setting is also a flag of every task) and hand
over to docker_ros.host.pipeline (the build, test, slim, push and CI flows) or the step modules.
Errors users can fix end as one line and a non-zero exit.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import List, Mapping

from invoke import Collection, Context, Exit, Task

import docker_ros
from docker_ros.cli.settingstask import (
    DRY_RUN,
    HOST,
    HOST_SETTINGS,
    IMAGE_SETTINGS,
    IN_CONTAINER,
    PUSH_SETTINGS,
    SHELL_ON_FAILURE,
    Flag,
    settings_task,
)
from docker_ros.core import errors
from docker_ros.core.display import made_images, require, required_for_build
from docker_ros.core.settings import (
    FIELDS,
    Settings,
)
from docker_ros.in_image.steps import BY_NAME, STEPS

DOTENV: Flag = ("dotenv", "", "Write docker-ros's _IMAGE_* image names, and the digests "
                 "(`<name>_DIGEST`) of those the job pushed, to this dotenv file")


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
        # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
        # ~0.1-0.3 s; --help and --list need only the task declarations)
        from docker_ros.host import container
        from docker_ros.host.pipeline import (  # (start-up, as above)
            TaskError,
            run_host_steps,
            run_in_container,
        )
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
    # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
    # ~0.1-0.3 s; --help and --list need only the task declarations)
    from docker_ros.host.config import config_table, input_problems
    from docker_ros.host.lockpins import lock_status  # (start-up, as above)
    from docker_ros.host.pipeline import TaskError  # (start-up, as above)
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
    # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
    # ~0.1-0.3 s; --help and --list need only the task declarations)
    from docker_ros.host import build
    from docker_ros.host.lock import lock  # (start-up, as above)
    from docker_ros.host.pipeline import TaskError  # (start-up, as above)
    started = time.monotonic()
    if not host:
        require(settings, ["base_image"])  # (COMMAND is no input of what a build installs)
        build.check_engine()
    try:
        changes = lock(settings, check=check, host=host, out=sys.stdout)
    except errors.BuildError as exc:
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
        # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
        # ~0.1-0.3 s; --help and --list need only the task declarations)
        from docker_ros.host.pipeline import composite_flow
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
    # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
    # ~0.1-0.3 s; --help and --list need only the task declarations)
    from docker_ros.host.pipeline import build_targets, build_until, run_test_stage
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
    # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
    # ~0.1-0.3 s; --help and --list need only the task declarations)
    from docker_ros.host import build, engine, refs
    from docker_ros.host.pipeline import (  # (start-up, as above)
        build_targets,
        check_slim_options,
        report_built,
        slim_one,
        slimmed_here,
    )
    settings = dataclasses.replace(settings, target=("run",))
    check_slim_options(settings)
    here = [p for p in settings.platform if slimmed_here(settings, p)]
    if not dry_run:
        # (the builder first: a docker context's engine holds the run image)
        build.check_engine(settings)
    missing = [] if dry_run else [ref for ref in (refs.target_ref(settings, "run", p)
                                                  for p in here)
                                  if not engine.local_or_pulled(ref)]
    if missing:  # (the platforms slimmed here only: another one may build under QEMU)
        print(f"slim: run image {', '.join(missing)} neither local nor pullable: building it")
        build_targets(settings, ("run",), dry_run=dry_run, slim=True, only=here)
        return
    slimmed = [slim_one(settings, p, dry_run=dry_run) for p in here]
    if not dry_run:
        report_built(settings, slimmed)


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
    # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
    # ~0.1-0.3 s; --help and --list need only the task declarations)
    from docker_ros.host.pipeline import run_test_stage
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
    # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
    # ~0.1-0.3 s; --help and --list need only the task declarations)
    from docker_ros.host.pipeline import TaskError, build_targets, push_and_report
    from docker_ros.host.push import official_only_names, push, push_targets  # (start-up, as above)
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
    [DOTENV, DRY_RUN],
    uses=("target", "image", "image_tag", "platform") + PUSH_SETTINGS,
    logs_in=True,
    login_required=True,
)
def manifest_task(c: Context, settings: Settings, *, dotenv: str, dry_run: bool) -> None:
    # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
    # ~0.1-0.3 s; --help and --list need only the task declarations)
    from docker_ros.host import jobsummary  # (start-up, as above)
    from docker_ros.host.pipeline import push_and_report, require_tasks
    from docker_ros.host.push import manifest  # (start-up, as above)
    images = made_images(settings)
    if "slim" in images:
        require_tasks([["slim"]], ns.task_names)
    with jobsummary.job_record() as record:
        push_and_report(settings, images, manifest, dry_run=dry_run)
        pushed = jobsummary.pushed_digests(jobsummary.read_record(record))
    write_image_references(settings, dotenv, pushed)


@settings_task(
    "ci",
    "One CI job: build, test, slim, push (GitHub Action, GitLab template)\n\n"
    "Each a `docker-ros` task: build, test (ENABLE_INDUSTRIAL_CI), slim (ENABLE_SLIM), push.",
    [DOTENV, DRY_RUN],
    uses=("target",) + IMAGE_SETTINGS + ("command",) + PUSH_SETTINGS,
    logs_in=True,
    login_required=True,
)
def ci_task(c: Context, settings: Settings, *, dotenv: str, dry_run: bool) -> None:
    # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
    # ~0.1-0.3 s, reading settings and CI variables (core.loading, core.ci) ~10 ms; --help and
    # --list need only the task declarations)
    from docker_ros.core.ci import plan_ci_job, slim_skipped  # (start-up, as above)
    from docker_ros.core.loading import host_platform  # (start-up, as above)
    from docker_ros.host import jobsummary  # (start-up, as above)
    from docker_ros.host.pipeline import check_slim_options, require_tasks, run_ci_plan
    host = host_platform()
    plan = plan_ci_job(target=settings.target, enable_industrial_ci=settings.enable_industrial_ci,
                       enable_slim=settings.enable_slim, slims_here=host in settings.platform)
    require_tasks(plan, ns.task_names)
    if "slim" in made_images(settings) and ["slim"] not in plan:
        print(slim_skipped(settings.platform, host), flush=True)
    if ["slim"] in plan:
        check_slim_options(settings)
    with jobsummary.job_record() as record:
        run_ci_plan(settings, plan, dry_run=dry_run)
        pushed = jobsummary.pushed_digests(jobsummary.read_record(record))
    write_image_references(settings, dotenv, pushed)


def write_image_references(settings: Settings, path: str, pushed: Mapping[str, str]) -> None:
    """docker-ros's `_IMAGE_*` names of this pipeline's images (image_references), the build
    states this job pushed (build_state_references) and, for each name the job pushed (pushed:
    name -> registry digest, from the job's record), `<variable>_DIGEST` (digest_references),
    written to path, when given, as a dotenv file (GitLab's `artifacts: reports: dotenv:`)."""
    # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
    # ~0.1-0.3 s, reading CI variables (core.ci) a few ms; --help and --list need only the task
    # declarations)
    from docker_ros.core.ci import (
        build_state_references,
        detect_pipeline,
        digest_references,
        docker_tag_part,
        image_references,
    )
    from docker_ros.host.pipeline import TaskError  # (start-up, as above)
    from docker_ros.host.refs import target_ref  # (start-up, as above)
    if not path:
        return
    pipeline = detect_pipeline(os.environ)
    git_tag = docker_tag_part(pipeline.ref) if pipeline and pipeline.kind == "tag" else ""
    images = {"RUN": (str(settings.image_name), str(settings.image_tag)),
              "DEV": (str(settings.dev_image_name), str(settings.dev_image_tag)),
              "SLIM": (str(settings.slim_image_name), str(settings.slim_image_tag))}
    states = {p: target_ref(settings, "build-state", p) for p in settings.platform}
    references = (image_references(images, settings.image_postfix or "", git_tag)
                  + build_state_references(states, pushed))
    lines = [f"{name}={value}\n" for name, value in
             references + digest_references(references, pushed)]
    try:
        Path(path).write_text("".join(lines))
    except OSError as exc:
        raise TaskError(f"--dotenv {path}: cannot write it: {exc.strerror or exc}") from None
    print(f"image names (docker-ros's _IMAGE_* variables) and the pushed ones' digests "
          f"written to {path}", flush=True)


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
    # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
    # ~0.1-0.3 s; --help and --list need only the task declarations)
    from docker_ros.host import devshell
    from docker_ros.host.pipeline import run_dev_shell  # (start-up, as above)
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
        ("check", False, "Change nothing; exit 1 when the file is not up to date with the "
         "settings (the host user it maps may be another: for CI)"),
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
    # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
    # ~0.1-0.3 s; --help and --list need only the task declarations)
    from docker_ros.host import devcontainer, devshell
    code = devcontainer.run(settings, devshell.ShellOptions(
        volumes=volume, env=env, network=network, privileged=privileged, devices=device),
        x11=x11, gpus=gpus, check=check, force=force, dry_run=dry_run)
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
    # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
    # ~0.1-0.3 s; --help and --list need only the task declarations)
    from docker_ros.host import baseimage, buildcontext
    from docker_ros.host.pipeline import TaskError  # (start-up, as above)
    if flavor not in baseimage.FLAVORS:
        raise TaskError(f"--flavor {flavor!r}: use one of {', '.join(baseimage.FLAVORS)}")
    tag = tag or baseimage.default_tag(flavor)
    with tempfile.TemporaryDirectory(prefix="docker-ros-ca-") as tmp:
        # (ros1-ubuntu's pip behind a TLS-intercepting proxy)
        bundle = buildcontext.extra_ca_bundle(settings, Path(tmp))
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
    # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
    # ~0.1-0.3 s; --help and --list need only the task declarations)
    from docker_ros.host import baseimage, container
    from docker_ros.host.config import read_settings  # (start-up, as above)
    from docker_ros.host.pipeline import TaskError, build_targets  # (start-up, as above)
    project = EXAMPLE
    if not project.is_dir():
        raise TaskError(f"{project} not found: the example ships with the source repository")
    given = {n: getattr(settings, n) for n in FIELDS if settings.source_of(n) == "flag"}
    settings = read_settings({}, {**given, "build_context": str(project)}, project_dir=project)
    assert settings.base_image
    # the engine that keeps the images BUILDER builds (a docker context's own), base included
    cli = container.docker_cli(settings)
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

