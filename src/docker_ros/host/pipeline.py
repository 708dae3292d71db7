"""The host side of the tasks: the build, test, slim and push flows, the host steps, the
steps in a container and the CI job. Plain functions with explicit parameters; the
command line (docker_ros.cli.tasks) declares the tasks and calls them."""

from __future__ import annotations

import contextlib
import dataclasses
import getpass
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import (
    Any,
    Callable,
    Collection,
    Dict,
    Iterator,
    List,
    Mapping,
    Optional,
    Sequence,
    Tuple,
)

from docker_ros.core import errors
from docker_ros.core.ci import missing_tasks
from docker_ros.core.display import missing_required, require, required_for_build
from docker_ros.core.errors import DockerRosError
from docker_ros.core.loading import host_platform
from docker_ros.core.settings import Settings, SettingsError, env_name
from docker_ros.host import (
    build,
    buildcontext,
    builder,
    buildplan,
    container,
    devshell,
    engine,
    faults,
    jobsummary,
    refs,
    slim,
    slimoptions,
)
from docker_ros.host.build import BuiltImage
from docker_ros.host.config import image_problems, input_problems
from docker_ros.host.lockpins import lock_status
from docker_ros.host.login import job_login, plan_login
from docker_ros.host.push import plan_outputs, registry_warning, write_outputs
from docker_ros.in_image import testing
from docker_ros.in_image.runtime.workspace import STATE_DIR_NAME, Workspace, format_argv
from docker_ros.in_image.steps import BY_NAME, STEPS, run_step

DEV_STEPS = tuple(s for s in STEPS if BY_NAME[s].stage in ("source", "dependencies-dev"))


class TaskError(DockerRosError):
    """An expected failure outside the steps (bad repository layout, failed build...), and the
    task's exit code."""

    def __init__(self, message: str, returncode: int = 1) -> None:
        super().__init__(message)
        self.returncode = returncode
        self.exit_code = returncode or 1


class TaskFailed(TaskError):
    """A task process of `docker-ros ci` failed: it told why (on GitHub, in an annotation)."""


# What the steps, colcon and `inv test` make in a workspace (src/ with the src/target link).
WORKSPACE_ENTRIES = ("src", STATE_DIR_NAME, "additional-files", "build", "install", "log",
                     "test-results")


def workspace_problem(root: Path, repository: Path, entries: Sequence[str],
                      linked: bool) -> Optional[str]:
    """Why the folder at root (both paths resolved; its entries, and whether its src/target is
    a link) cannot be the host workspace. The steps write src/, .docker-ros/ and
    additional-files/ there: it must not be the repository, lie inside it or hold it, and must
    be new, empty or one of ours (src/target)."""
    if root == repository or repository in root.parents:
        return (f"WORKSPACE '{root}' is inside the repository {repository}: the host steps "
                "would write into it; give a folder outside it (unset: ~/.cache/docker-ros/ws/)")
    if root in repository.parents:
        return (f"WORKSPACE '{root}' holds the repository {repository}: give a folder of its "
                "own (unset: ~/.cache/docker-ros/ws/)")
    foreign = sorted(e for e in entries
                     if e not in WORKSPACE_ENTRIES or (e == "src" and not linked))
    if foreign:
        return (f"WORKSPACE '{root}' holds other files ({', '.join(foreign[:3])}) and is no "
                "docker-ros workspace (no src/target link): give a new or empty folder")
    return None


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
    ws, repository = checked_workspace(settings)
    if dry_run and not ws.target.is_symlink():
        with tempfile.TemporaryDirectory(prefix="docker-ros-dry-run-") as tmp:
            print(f"[dry-run] would create {ws.root} with src/target -> {repository}"
                  f" (showing the steps in a temporary workspace: {tmp})")
            temporary = Workspace(tmp)
            link_repository(temporary, repository)
            yield temporary
        return
    claim_workspace(settings, ws, repository)
    yield ws


def checked_workspace(settings: Settings) -> Tuple[Workspace, Path]:
    """WORKSPACE and the repository, refused (TaskError) when it cannot be the workspace."""
    assert settings.workspace
    ws = Workspace(Path(settings.workspace).expanduser())
    repository = Path(settings.build_context).resolve()
    root = ws.root.resolve()
    problem = workspace_problem(root, repository, os.listdir(root) if root.is_dir() else [],
                                ws.target.is_symlink())
    if problem:
        raise TaskError(problem)
    return ws, repository


def claim_workspace(settings: Settings, ws: Workspace, repository: Path) -> None:
    """src/target -> the repository: the workspace is this repository's from now on (another
    of the same folder name gets a default WORKSPACE of its own, settings.default_workspace)."""
    try:
        link_repository(ws, repository)
    except OSError as exc:
        raise TaskError(f"WORKSPACE '{settings.workspace}' cannot be created/used: "
                        f"{exc.strerror or exc}; give a writable folder") from None


def host_options(step: str, ws: Workspace) -> Dict[str, str]:
    return {"destination": str(ws.root / "additional-files")} if step == "files" else {}


def check_inputs(settings: Settings, targets: Sequence[str] = (),
                 required: Sequence[str] = ()) -> None:
    """Missing required values, bad paths and image names, all at once, before anything
    runs (a missing value alone keeps its own one-line message)."""
    missing = missing_required(settings, required)
    problems = input_problems(settings, targets, images=bool(targets))
    if missing and not problems:
        raise SettingsError(missing)
    stop_on({"required": missing, **problems} if missing else problems)


def stop_on(problems: Mapping[str, str]) -> None:
    """One SettingsError listing every problem (setting name -> message), if there is one."""
    if problems:
        raise SettingsError("invalid configuration:\n  " + "\n  ".join(problems.values()))


def run_host_steps(settings: Settings, steps: Sequence[str], *, dry_run: bool,
                   required: Sequence[str] = ()) -> None:

    check_inputs(settings, required=required)
    with host_workspace(settings, dry_run=dry_run) as ws:
        for step in steps:
            run_step(step, ws, settings, phase="all", dry_run=dry_run, **host_options(step, ws))


def run_in_container(settings: Settings, plan: Any, *, dry_run: bool,
                     shell_on_failure: bool) -> str:
    """Build the plan's start stage, run its commands in one container, tag the result."""

    runs_command = plan.start == "run" or ("command",) in plan.commands
    check_inputs(settings, ("run",) if runs_command else ("dev",),
                 ["base_image"] + (["command"] if runs_command else []))
    repository = f"{Path(settings.build_context).resolve()}:{container.TARGET_DIR}"
    mount = f" -v {repository}" if plan.sources else ""
    if dry_run:
        argv = buildplan.plan_shown(settings, shown_builder(settings), target=plan.start,
                                platform=settings.platform[0],
                                tag=container.tag_of(settings, "stage", plan.start))
        print("[dry-run] build:", format_argv(argv))
        print(f"[dry-run] in one container of it{f' ({mount.strip()})' if mount else ''}:")
        for command in plan.commands:
            print("[dry-run]   " + container.shown(command))
        print(f"[dry-run] commit and tag {plan.tag}")
        return plan.tag
    build.check_engine(settings)
    tag = container.run_plan(settings, plan, shell_on_failure=shell_on_failure)
    line = container.docker_run_line(tag, [repository] if plan.sources else [], ["bash"],
                                     tty=True, cli=container.docker_cli(settings))
    print(f"tagged {tag}\n  enter it: {line}")
    return tag


def composite_flow(settings: Settings, name: str, *, host: bool, dry_run: bool, in_container: bool,
               shell_on_failure: bool) -> None:
    if host and in_container:
        raise TaskError("--host and --in-container: choose one")
    if in_container:

        run_in_container(settings, container.plan_composite(settings, name), dry_run=dry_run,
                         shell_on_failure=shell_on_failure)
    elif host:
        if shell_on_failure:
            raise TaskError("--shell-on-failure needs --in-container or an image build")
        run_host_steps(settings, DEV_STEPS if name == "dev" else STEPS, dry_run=dry_run,
                       required=["command"] if name == "run" else [])
    else:
        build_targets(settings, (name,), dry_run=dry_run, shell_on_failure=shell_on_failure)


def shown_builder(settings: Settings) -> builder.Builder:
    """The builder a dry run shows the builds in: inspected as a build would (when BUILDER,
    CACHE_TO or the environment picks one), a builder that cannot be is the dry run's error."""
    return build.selected_builder(settings)


def build_targets(settings: Settings, targets: Sequence[str], *, dry_run: bool,
                  shell_on_failure: bool = False, slim: bool = False,
                  only: Sequence[str] = ()) -> List[BuiltImage]:
    """Build the targets for every platform, or only those of `only` (a dev shell's, slim's:
    tagged as among every platform), and with slim the slim image after run; print the summary
    table."""
    settings = dataclasses.replace(settings, target=tuple(targets))
    platforms = [p for p in settings.platform if not only or p in only]
    check_inputs(settings, targets, required_for_build(settings))
    if slim and "run" in targets:
        check_slim_options(settings)
    assert settings.base_image
    if not dry_run:
        build.check_engine(settings)
    # every platform's base before the first build (build_images says which)
    for platform in platforms:
        (refs.shown_base if dry_run else refs.platform_base)(settings, platform)
    chosen = shown_builder(settings) if dry_run else None
    built: List[BuiltImage] = []
    for platform in platforms:
        # BUILD_STATE_FROM: the run image's build state too, for the next job's `push`
        kinds = ("dev", "run") + (("build-state",) if settings.build_state_from else ())
        tags = {t: refs.target_ref(settings, t, platform)
                for t in kinds if t in targets or (t == "build-state" and "run" in targets)}
        buildx = [] if chosen is None else builder.buildx_command(chosen, settings.builder or "")
        allow = None if chosen is None else buildplan.bake_grants(buildx, settings, "<temporary>")
        if chosen is not None and allow is not None:
            specs = {t: buildplan.shown_definition(settings, chosen, target=t, platform=platform,
                                               tag=tag) for t, tag in tags.items()}
            print("[dry-run] build:", format_argv(
                buildplan.plan_bake(specs, "<temporary>/docker-ros.bake.json", buildx, allow)))
            print(f"[dry-run] with <temporary>/docker-ros.bake.json:\n{buildplan.bake_file(specs)}",
                  end="")
        elif chosen is not None:
            for target, tag in tags.items():
                argv = buildplan.plan_shown(settings, chosen, target=target, platform=platform,
                                        tag=tag)
                print("[dry-run] build:", format_argv(argv))
        else:
            try:
                built += build.build_images(settings, targets=tags, platform=platform)
            except errors.BuildError as exc:
                # (naming what the platforms before this one built and tagged)
                exc = build.with_built(build.with_sources(exc, settings), built)
                code = reproduce_failure(settings, exc) if shell_on_failure else None
                raise TaskError(str(exc), code or 1) from None
            except KeyboardInterrupt as exc:
                raise build.noted(exc, build.built_notes(built)) from None
        if slim and "run" in targets and slimmed_here(settings, platform):
            slimmed = slim_one(settings, platform, dry_run=dry_run)
            built += [] if dry_run else [slimmed]
    if built:
        report_built(settings, built)
        print(lock_status(settings))
    return built


def report_built(settings: Settings, built: Sequence[BuiltImage]) -> None:
    """The size table of what was built or slimmed, also into the CI job's record."""
    print(build.summary_table(built))
    if not os.environ.get(jobsummary.RECORD_ENV):
        return  # (not in a CI job)
    for image in built:
        entry = {"kind": "image", **dataclasses.asdict(image), "size": engine.image_size(image.ref)}
        if image.target == "slim":
            entry["run_size"] = engine.image_size(refs.target_ref(settings, "run", image.platform))
        jobsummary.record(entry, os.environ)


def check_slim_options(settings: Settings) -> None:
    """SLIM_BUILD_ARGS, ADDITIONAL_SLIM_BUILD_ARGS and the slim image's name and tag checked
    before anything is built."""
    stop_on({name: problem for name, problem in image_problems(settings, ("slim",)).items()
             if name.startswith("slim_")})
    slimoptions.slim_options(settings)


def slimmed_here(settings: Settings, platform: str) -> bool:
    """Whether platform's run image is slimmed here (refs.slim_platforms); says when not."""
    if platform in refs.slim_platforms(settings.platform, host_platform()):
        return True
    print(f"slim: {platform}: not slimmed on this {host_platform()} runner (slimming runs the "
          f"image; as docker-ros, a multi-arch job slims the runner's architecture only)",
          flush=True)
    return False


def slim_one(settings: Settings, platform: str, *, dry_run: bool) -> BuiltImage:

    result = slim.slim_image(settings, platform, dry_run=dry_run)
    return BuiltImage("slim", result.ref, platform, result.seconds, reused=result.reused)


def results_root(settings: Settings, results_dir: str) -> Path:
    """Where the tests' results go: --results-dir, else TEST_RESULTS_DIR, else outside the
    repository (never written into the user's sources unasked)."""
    given = results_dir or settings.test_results_dir
    if given:
        return Path(given).expanduser().resolve()
    assert settings.workspace
    return Path(settings.workspace).expanduser() / "test-results"


def results_origin(settings: Settings, results_dir: str) -> str:
    """The flag or variable results_root took the folder from, for messages."""
    if results_dir:
        return "--results-dir"
    if settings.test_results_dir:
        return f"TEST_RESULTS_DIR ({settings.source_of('test_results_dir')})"
    return f"TEST_RESULTS_DIR (default: in WORKSPACE, {settings.source_of('workspace')})"


def results_in_context(results: Path, context: Path, origin: str) -> Optional[str]:
    """A warning when the results folder lies in the build context: every run then changes
    the context (the dev image's sources, and a full colcon build: a file outside every
    package changed). None when it lies outside."""
    context = context.expanduser().resolve()
    if results != context and context not in results.parents:
        return None
    if results != context and buildcontext.left_out(str(results.relative_to(context))):
        return None  # (our .dockerignore leaves it out: docker-ros-test-results, ...)
    return (f"docker-ros test: warning: {origin}: {results} is in the build context "
            f"({context}): the next build sees the results as changed sources (copied into the "
            "dev image, a full colcon build); give a folder outside the repository")


def run_test_stage(settings: Settings, *, results_dir: str, dry_run: bool) -> None:
    """Build the test stage per platform, export its results; fail when a test failed.
    (The dev stage needs no COMMAND.)"""

    require(settings, ["base_image"])
    root = results_root(settings, results_dir)
    origin = results_origin(settings, results_dir)
    if not (results_dir or settings.test_results_dir):
        # the results go into WORKSPACE: refused as the host steps refuse it, and claimed
        ws, repository = checked_workspace(settings)
        if not dry_run:
            claim_workspace(settings, ws, repository)
    warning = results_in_context(root, Path(settings.build_context), origin)
    if warning:
        print(warning)
    failures = []
    for platform in settings.platform:
        dest = root if len(settings.platform) == 1 else root / platform
        problem = testing.check_results_dir(dest)
        if problem:
            raise TaskError(f"{origin}: {problem}")
        tag = refs.target_ref(settings, "dev", platform) + "-test"
        run = {"DOCKER_ROS_TEST_RUN": str(time.time_ns())}
        with tempfile.TemporaryDirectory(prefix="docker-ros-test-") as tmp:
            output = f"type=local,dest={tmp}"
            if dry_run:
                argv = buildplan.plan_shown(settings, shown_builder(settings),
                                        target="test-results", platform=platform, tag=tag,
                                        output=output, extra_build_args=run)
                print("[dry-run] test:", format_argv(argv))
                print(f"[dry-run] test: would copy the results to {dest}")
                continue
            try:
                build.check_engine(settings)
                build.build_image(settings, target="test-results", platform=platform, tag=tag,
                                  output=output, extra_build_args=run)
                outcome = testing.read_outcome(Path(tmp))
            except FileNotFoundError as exc:
                raise TaskError(str(exc)) from None
            counts = testing.summarize(Path(tmp) / testing.JUNIT)
            cases = testing.failed_cases(Path(tmp) / testing.JUNIT)
            build_error = testing.read_build_error(Path(tmp))
            packages = testing.package_test_failures(Path(tmp) / "log" / "test")
            try:
                testing.install_results(Path(tmp), dest)
            except OSError as exc:
                raise TaskError(f"{origin}: cannot copy the results to {dest}: "
                                f"{exc.strerror or exc}; give a writable folder") from None
        print(f"docker-ros test ({platform}): {testing.format_summary(counts)} "
              f"(JUnit XML and logs in {dest})")
        failed = testing.verdict(outcome, counts, cases, build_error, packages)
        if failed:
            failures.append(f"{failed} ({platform})")
    if failures:
        raise TaskError("; ".join(failures) + "; see the output above")


def reproduce_failure(settings: Settings, error: errors.BuildError) -> Optional[int]:
    """--shell-on-failure of an image build: the failed step again, in a container of the state
    before it, with the shell where it fails; the step's exit code there, if it failed."""

    if error.stage not in container.STAGES:
        print(f"docker-ros build: --shell-on-failure: the failure is not in one of the ten "
              f"steps (stage {error.stage or 'unknown'}); no shell to open")
        return None
    try:
        return container.reproduce(settings, error, out=sys.stdout)
    except errors.BuildError as exc:
        print(f"docker-ros build: --shell-on-failure: {exc}")
        return None


def build_until(settings: Settings, step: str, *, dry_run: bool,
                 shell_on_failure: bool) -> None:

    if step not in STEPS:
        raise TaskError(f"--until {step!r}: use one of {', '.join(STEPS)}")
    plan = container.plan_until(settings, step)
    tag = run_in_container(settings, plan, dry_run=dry_run, shell_on_failure=shell_on_failure)
    following = container.next_command(step)
    if following and not dry_run:
        line = container.docker_run_line(tag, [], [*container.STEP_MODULE, *following],
                                         tty=False, cli=container.docker_cli(settings))
        print(f"  next step: {line}")


def push_and_report(
    settings: Settings, targets: Sequence[str], action: Callable[..., Dict[str, str]], *,
    dry_run: bool
) -> None:
    """Run push or manifest; print the pushed names and digests, hand them to the CI as
    outputs and to the job's record."""

    warning = registry_warning(settings, targets)
    if warning:
        print(f"{action.__name__}: {warning}", file=sys.stderr, flush=True)
    pushed = action(settings, targets, dry_run=dry_run)
    for name, digest in pushed.items():
        print(f"pushed {name}" + (f" ({digest})" if digest else ""))
        jobsummary.record({"kind": "pushed", "name": name, "digest": digest}, os.environ)
    if pushed:
        write_outputs(plan_outputs(settings, targets, pushed), os.environ)


@contextlib.contextmanager
def logged_in_job(settings: Settings, label: str, *, dry_run: bool,
                  required: bool = True) -> Iterator[None]:
    """REGISTRY_USER/REGISTRY_PASSWORD logged in before anything else of the job (a private
    BASE_IMAGE or CACHE_FROM), into a DOCKER_CONFIG of the job's own, removed at its end; a
    failed login that is not `required` is a warning (see login.job_login)."""

    argv = plan_login(settings)
    if dry_run:
        if argv:
            print(f"[dry-run] {label}: {format_argv(argv)} (password on standard input, "
                  "task-private DOCKER_CONFIG)")
        yield
        return
    with job_login(settings, os.environ, label=label, required=required):
        yield


def require_tasks(plan: Sequence[Sequence[str]], task_names: Collection[str]) -> None:
    """The tasks a CI plan runs exist here (task_names: the invoke collection's)."""

    problems = missing_tasks(plan, task_names)
    if problems:
        raise TaskError("; ".join(problems))


def run_ci_plan(settings: Settings, plan: Sequence[Sequence[str]], *, dry_run: bool) -> None:
    """A CI job's tasks, each a `docker-ros` process, in order; the first failure stops it. The
    tasks re-read .env, invoke.yaml and the environment; flags given to `ci` go along, as given
    (a tag without IMAGE_POSTFIX) and before the plan's own (its --set wins: a build that
    leaves testing to `test`), and so does a dry run (each task's, which prints its commands
    and image names)."""
    given = [arg for n, text in settings.flags.items()
             for arg in ("--set", f"{env_name(n)}={text}")]
    for task, *args in plan:
        argv = [task, *given, *args, *(["--dry-run"] if dry_run else [])]
        command = [sys.executable, "-m", "docker_ros", *argv]
        print(f"docker-ros ci: docker-ros {format_argv(argv)}", flush=True)
        process = subprocess.Popen(command)
        try:
            code = process.wait()
        except KeyboardInterrupt:
            let_end(process)
            raise
        if code != 0:
            raise TaskFailed(f"`docker-ros {task}` failed with exit code {code}; "
                             "nothing after it ran")


def let_end(task: subprocess.Popen, grace: float = 10.0) -> None:
    """After Ctrl-C or SIGTERM: let a task process clean up and end (subprocess.call killed it,
    and its temporary folders and buildx run stayed). A terminal's Ctrl-C and a runner's
    SIGTERM to the job's processes reach it too; a signal to this process alone does not, so
    after grace seconds it gets SIGTERM (a second one is ignored by a task: tasks.terminated)."""
    try:
        task.wait(timeout=grace)
    except subprocess.TimeoutExpired:
        task.terminate()
        task.wait()


def run_dev_shell(settings: Settings, options: devshell.ShellOptions, *, x11: str,
                  rebuild: bool, dry_run: bool) -> int:
    """`inv dev-shell`: the dev image (built first when missing or rebuild) as a container for
    the host user; options.gpus as asked (auto: the nvidia runtime's), X11 as x11 asks (auto:
    a local DISPLAY whose socket exists). Returns the container's exit code (0 on a dry run,
    which prints the docker run command)."""
    shell_platform = devshell.shell_platform(settings, host_platform())
    ref = refs.target_ref(settings, "dev", shell_platform)
    devshell.check_shell_options(options.volumes, options.env)
    blacklisted = devshell.blacklisted_names(settings)
    display = os.environ.get("DISPLAY", "")
    display = display if devshell.select_x11(x11, display) else ""
    runtimes = devshell.docker_runtimes() if options.gpus == "auto" else []
    gpus = devshell.select_gpus(options.gpus, runtimes)
    user = devshell.HostUser(os.getuid(), os.getgid(), getpass.getuser(),
                             tty=sys.stdin.isatty() and sys.stdout.isatty())
    with tempfile.TemporaryDirectory(prefix="docker-ros-dev-shell-") as tmp:
        cookie = devshell.write_cookie(display, os.environ, Path(tmp) / "xauth") if display else ""
        shell, note = devshell.shell_colcon_defaults(
            blacklisted, options, Path(settings.build_context).resolve(), user.cwd, os.environ,
            Path(tmp) / "colcon-defaults.yaml")
        if note:
            print(note, file=sys.stderr, flush=True)
        argv = devshell.dev_shell_argv(settings, ref, dataclasses.replace(
            shell, gpus=gpus, x11_display=display, xauthority=cookie), user)
        if dry_run:  # (the X cookie and colcon defaults files are gone when it ends)
            print(format_argv([arg.replace(tmp, "<temporary>") for arg in argv]))
            return 0
        check_shell_engine(settings)
        image = None if rebuild else engine.inspect_image(ref)
        if image is None:  # (the shell's platform only: another one may build under QEMU)
            build_targets(settings, ("dev",), dry_run=False, only=[shell_platform])
        else:
            repository = Path(settings.build_context)
            folders = buildcontext.imports_folders(settings, repository)
            current = buildcontext.imports_digest(repository, folders)
            stale = buildcontext.stale_dev_image((image.get("Config") or {}).get("Labels") or {},
                                          current, ref)
            if stale:
                print(stale, file=sys.stderr, flush=True)
        container = subprocess.Popen(argv)
        try:
            code = container.wait()
        except KeyboardInterrupt:  # (SIGTERM too: the docker CLI stops the container; killed,
            let_end(container)     # as subprocess.call did, it left the container running)
            raise
        if code and not faults.engine_answers():  # (125 when it broke off, else the shell's)
            raise TaskError(faults.engine_lost_line(
                faults.task_doing("dev-shell"), f"`docker run` ended with exit code {code} "
                "and the engine no longer answers"), code)
        return code


def check_shell_engine(settings: Settings) -> None:
    """The dev shell's `docker run` uses the CLI's engine: a BUILDER whose engine keeps the
    images elsewhere (a docker context's docker driver) would build the dev image there and
    then have `docker run` look for it on a registry. Stop first, saying what to do."""
    chosen = build.selected_builder(settings)
    elsewhere = builder.images_host(chosen, engine.cli_host(os.environ))
    if elsewhere:
        raise TaskError(
            f"BUILDER '{chosen.name}' keeps its images in the engine at {elsewhere}, but the "
            f"shell's `docker run` uses the local engine ({engine.cli_host(os.environ)}): run "
            f"`DOCKER_CONTEXT={chosen.name} inv dev-shell` instead (without BUILDER; the "
            "repository is mounted from that engine's machine)")
