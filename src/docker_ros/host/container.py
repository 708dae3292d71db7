"""Steps in a container: start from the image state just before a step (a Dockerfile stage built
with BuildKit, reused from its cache), run the Dockerfile's own step commands in one container
with the docker SDK, then commit and tag the result.

Used by `inv <step> --in-container`, `inv dev|run --in-container`, `inv build --until <step>`
and `--shell-on-failure`. The images made here are debugging images: they also hold the step
modules (/docker-ros/lib, on PYTHONPATH) and the build's settings as environment variables, so
`python3 -m docker_ros.in_image.steps <step>` works in them as written.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import io
import json
import os
import shlex
import subprocess
import sys
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple

from docker_ros.core import errors
from docker_ros.core.labels import ours
from docker_ros.core.settings import Settings, env_name
from docker_ros.host import build, buildcontext, builder, buildplan, engine, refs
from docker_ros.in_image.runtime.workspace import StepError
from docker_ros.in_image.steps import BY_NAME, PHASED, STEPS

Command = Tuple[str, ...]  # the arguments after `python3 -m docker_ros.in_image.steps`
STEP_MODULE = ("python3", "-m", "docker_ros.in_image.steps")
LIB = "/docker-ros/lib"
WORKDIR = "/docker-ros/ws"
TARGET_DIR = "/docker-ros/ws/src/target"
# As every RUN of the Dockerfile: trust EXTRA_CA_CERTS for this command only, then the step, its
# stderr (the step's log) on stdout: the engine reads two streams apart, which can reorder them.
CA_WRAPPER = ("bash", "-c", f'source {LIB}/docker_ros/docker/ca-certs.sh && exec "$@" 2>&1',
              "bash")
STATE_LABEL = ours("state")
# the steps the dependency stages install with (their apply phases)
INSTALL_STEPS = tuple(s for s in PHASED if BY_NAME[s].stage == "dependencies-dev")
# Build arguments of the Dockerfile that are ids of cache mounts, not settings.
NOT_SETTINGS = ("BASE_IMAGE", "DOCKER_ROS_TOOLS", "DOCKER_ROS_CACHE_ID", "DOCKER_ROS_APT_CACHE_ID")


@dataclass(frozen=True)
class Stage:
    """A Dockerfile stage whose RUNs are step commands, and the stage just before them."""

    name: str
    start: str
    commands: Tuple[Command, ...]
    sources: bool  # the state holds the repository (mounted at src/target in containers)


def _installs(dependency_types: str) -> Tuple[Command, ...]:
    return tuple(
        ("rosdep", "--phase", "apply", "--dependency-types", dependency_types)
        if step == "rosdep" else (step, "--phase", "apply")
        for step in INSTALL_STEPS
    )


# The step commands of the Dockerfile, stage by stage (a unit test compares them).
STAGES = {
    "source": Stage("source", "checkout", (("clone",), ("blacklist", "--mark-ignored")), True),
    "resolve": Stage(
        "resolve", "resolve-inputs",
        tuple((step, "--phase", "collect") for step in PHASED), True,
    ),
    "dependencies-run": Stage("dependencies-run", "resolved-run", _installs("exec"), False),
    "dependencies-dev": Stage("dependencies-dev", "resolved-dev", _installs("all"), False),
    "build": Stage("build", "dev", (("colcon", "--stamp-changed"),), True),
    # not a RUN: the run image's default command, run by the step as on the host
    "run": Stage("run", "run", (("command",),), False),
}
# Where a step runs when it runs alone (its install phase for the dev image).
STEP_STAGE = {step: BY_NAME[step].stage for step in STEPS}
# --until the last step of a stage: the image that stage ends in (the dependencies' last step:
# the dev image, sources in place).
ENDS_IN = {"source": "tree", "dependencies-dev": "dev", "build": "build", "run": "run"}
UNTIL_STAGE = {[s for s in STEPS if STEP_STAGE[s] == stage][-1]: image
               for stage, image in ENDS_IN.items()}
PREPARE_DEV: Command = ("prepare", "--dependency-types", "all")


@dataclass(frozen=True)
class Plan:
    """Build `start` with BuildKit, run `commands` in one container of it, tag the result."""

    start: str
    commands: Tuple[Command, ...]
    sources: bool
    tag: str
    # an image of the same state may stand in for all commands (--until), not only the earlier
    # ones (a step asked for runs again)
    reuse_all: bool = False


def tag_of(settings: Settings, kind: str, name: str) -> str:
    """<IMAGE_NAME>:<IMAGE_TAG>-<kind>-<name>, e.g. my/image:latest-after-rosdep."""
    return f"{settings.image_name}:{settings.image_tag}-{kind}-{name}"


def in_container(command: Command, *, mounted: bool) -> Command:
    """A Dockerfile command as it runs in a container. With the repository mounted, colcon does
    not stamp sources: that keeps the cache mount of image builds right and would touch the
    modification times of the user's files."""
    if mounted and command[0] == "colcon":
        return tuple(a for a in command if a != "--stamp-changed")
    return command


def plan_step(settings: Settings, step: str, *, stage: str = "") -> Plan:
    """One step alone: the state before it in its stage, the stage's earlier commands, the step."""
    home = STAGES[stage or STEP_STAGE[step]]
    index = next(i for i, c in enumerate(home.commands) if c[0] == step)
    commands = tuple(in_container(c, mounted=home.sources) for c in home.commands[: index + 1])
    return Plan(home.start, commands, home.sources, tag_of(settings, "after", step))


def plan_until(settings: Settings, step: str) -> Plan:
    """`build --until <step>`: the exact build state right after the step (no mount)."""
    tag = refs.until_ref(settings, step)
    if step in UNTIL_STAGE:
        return Plan(UNTIL_STAGE[step], (), False, tag, reuse_all=True)
    home = STAGES[STEP_STAGE[step]]
    index = next(i for i, c in enumerate(home.commands) if c[0] == step)
    return Plan(home.start, home.commands[: index + 1], False, tag, reuse_all=True)


def plan_composite(settings: Settings, name: str) -> Plan:
    """`dev`/`run` in one container: the dev image's commands in build order from the checked
    out repository (run: then colcon and COMMAND)."""
    commands = STAGES["source"].commands + STAGES["resolve"].commands + (PREPARE_DEV,)
    commands += STAGES["dependencies-dev"].commands
    if name == "run":
        commands += (("colcon",), ("command",))
    return Plan("checkout", commands, True, tag_of(settings, "after", name))


def next_command(step: str) -> Optional[Command]:
    """What to run by hand in the `--until <step>` image to go on: the next step as the dev
    build runs it (after blacklist, with sources and nothing resolved yet: both phases)."""
    order = [c for s in ("source", "dependencies-dev", "build", "run") for c in STAGES[s].commands]
    index = next(i for i, c in enumerate(order) if c[0] == step) + 1
    if index == len(order):
        return None
    return order[index][:1] if step == "blacklist" else order[index]


def step_environment(settings: Settings, declared: Sequence[str],
                     image_env: Sequence[str] = ()) -> Dict[str, str]:
    """What the Dockerfile's RUNs see: the settings it declares as ARGs (secrets never), and the
    step modules on PYTHONPATH before the start image's own entries (image_env: its Config.Env;
    a container's -e replaces the image's value, the Dockerfile's RUNs prepend to it)."""
    values = buildplan.arg_values(settings)
    env = {n: values[n] for n in declared if n in values and n not in NOT_SETTINGS}
    inherited = [e.split("=", 1)[1] for e in image_env if e.startswith("PYTHONPATH=")]
    env["PYTHONPATH"] = ":".join([LIB] + [p for p in inherited[-1:] if p])
    return env


def state_label(start_id: str, done: Sequence[Command], env: Mapping[str, str]) -> str:
    """What an image made here holds: its start image, the commands run on it, their settings."""
    digest = hashlib.sha256(json.dumps(sorted(env.items())).encode()).hexdigest()[:16]
    return json.dumps({"start": start_id, "done": [list(c) for c in done], "env": digest},
                      sort_keys=True)


def plan_resume(
    commands: Sequence[Command], start_id: str, env: Mapping[str, str],
    candidates: Mapping[str, Optional[str]], *, reuse_all: bool = False,
) -> Tuple[Optional[str], int]:
    """The image (of candidates: ref -> its state label) that has done the longest prefix of
    commands (all of them only with reuse_all) on the same start image with the same settings;
    and that prefix's length."""
    best: Tuple[Optional[str], int] = (None, 0)
    longest = len(commands) if reuse_all else len(commands) - 1
    for ref, label in candidates.items():
        for done in range(longest, best[1], -1):
            if label == state_label(start_id, commands[:done], env):
                best = (ref, done)
                break
    return best


def shown(command: Command) -> str:
    return " ".join(shlex.quote(a) for a in STEP_MODULE + command)


def docker_cli(settings: Settings) -> List[str]:
    """The docker command whose engine holds the images this run built (builder.images_cli)."""
    return builder.images_cli(build.selected_builder(settings), engine.cli_host(os.environ))


def docker_run_line(image: str, mounts: Sequence[str], args: Sequence[str], *, tty: bool,
                    cli: Sequence[str] = ("docker",)) -> str:
    """A `docker run` to print (cli: docker_cli, the engine that has image)."""
    argv = [*cli, "run", "--rm"] + (["-it"] if tty else [])
    for mount in mounts:
        argv += ["-v", mount]
    return " ".join(shlex.quote(a) for a in [*argv, image, *args])


def tools_archive() -> bytes:
    """The step modules as a tar of docker-ros/lib/... for `put_archive` at /."""
    buffer = io.BytesIO()
    with tempfile.TemporaryDirectory(prefix="docker-ros-tools-") as tmp:
        buildcontext.tools_tree(Path(tmp))
        with tarfile.open(fileobj=buffer, mode="w") as tar:
            tar.add(str(Path(tmp) / "docker-ros"), arcname="docker-ros")
    return buffer.getvalue()


@contextlib.contextmanager
def secrets_dir(settings: Settings) -> Iterator[Optional[Path]]:
    """A private folder with the secrets as files, bind-mounted read-only at /run/secrets (as
    BuildKit secrets): never in the container's config, an image or a command line."""
    values = {env_name(n): getattr(settings, n) for n in buildplan.SECRETS if getattr(settings, n)}
    if not values and not settings.extra_ca_certs:
        yield None
        return
    with tempfile.TemporaryDirectory(prefix="docker-ros-secrets-") as tmp:
        for name, value in values.items():
            path = Path(tmp) / name
            path.touch(mode=0o600)
            path.write_text(value)
        buildcontext.extra_ca_bundle(settings, Path(tmp), "EXTRA_CA_CERTS")
        yield Path(tmp)


@dataclass
class Session:
    """One container of a plan and what it needs on the host."""

    client: Any  # docker.DockerClient
    settings: Settings
    plan: Plan
    repository: Path
    secrets: Optional[Path]
    out: IO[str]
    shell_on_failure: bool
    start_config: Dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def mounts(self) -> List[str]:
        """-v mounts (host:container[:ro]) of the container; the secrets only while it runs."""
        mounts = [f"{self.repository}:{TARGET_DIR}"] if self.plan.sources else []
        if self.secrets:
            mounts.append(f"{self.secrets}:/run/secrets:ro")
        return mounts

    def create(self, image: str, env: Mapping[str, str]) -> Any:
        volumes = {}
        for mount in self.mounts:
            host, target, *mode = mount.split(":")
            volumes[host] = {"bind": target, "mode": mode[0] if mode else "rw"}
        network = self.settings.build_network or None
        container = self.client.containers.create(
            image, entrypoint=["sleep"], command=["infinity"], environment=dict(env),
            working_dir=WORKDIR, volumes=volumes, tmpfs={"/run/docker-ros": ""},
            network_mode=network, user="root",
        )
        container.start()
        return container

    def commit(self, container: Any, label: str, done: Sequence[Command], tag: str = "") -> str:
        """The container's state as an image with the start image's entry point and command
        (the container ran `sleep`); tagged when tag is given; returns the image id."""
        repository, _, version = tag.rpartition(":") if tag else ("", "", "")
        conf = {"Entrypoint": self.start_config.get("Entrypoint"),
                "Cmd": self.start_config.get("Cmd"),
                "Labels": {**(self.start_config.get("Labels") or {}), STATE_LABEL: label}}
        # the message is what `docker history` shows as the layer's comment
        message = "docker-ros: " + "; ".join(shown(c) for c in done) if done else "docker-ros"
        image = container.commit(repository=repository or None, tag=version or None, conf=conf,
                                 message=message)
        return str(image.id)

    def execute(self, container: Any, command: Command) -> int:
        """Run one step command in the container; its output goes to out as it comes."""
        api = self.client.api
        exec_id = api.exec_create(container.id, list(CA_WRAPPER + STEP_MODULE + command),
                                  workdir=WORKDIR)
        for chunk in api.exec_start(exec_id, stream=True):
            self.out.write(chunk.decode(errors="replace"))
            self.out.flush()
        return int(api.exec_inspect(exec_id)["ExitCode"])

    def on_failure(self, snapshot: str, command: Command, code: int) -> bool:
        """A shell in the state just before the failed command, or (no terminal) that state
        tagged and the commands to enter it printed; True when the snapshot is kept."""
        step = command[0]
        if sys.stdin.isatty() and sys.stdout.isatty():
            self.out.write(f"docker-ros {step}: failed with exit code {code}: {shown(command)}\n"
                           f"docker-ros {step}: a shell in the state just before it; run it "
                           "again with the line above, `exit` to leave\n")
            self.out.flush()
            argv = [*docker_cli(self.settings), "run", "--rm", "-it", "-w", WORKDIR]
            for mount in self.mounts:
                argv += ["-v", mount]
            subprocess.call(argv + [snapshot, "bash"])
            return False
        tag = tag_of(self.settings, "failed", step)
        self.client.images.get(snapshot).tag(*tag.rsplit(":", 1))
        mounts = [m for m in self.mounts if not m.endswith("/run/secrets:ro")]
        cli = docker_cli(self.settings)
        rerun = [*STEP_MODULE, *command]
        self.out.write(
            f"docker-ros {step}: no terminal for a shell; the state just before the failed "
            f"command is {tag}\n"
            f"  enter it:  {docker_run_line(tag, mounts, ['bash'], tty=True, cli=cli)}\n"
            f"  re-run it: {docker_run_line(tag, mounts, rerun, tty=False, cli=cli)}\n"
        )
        self.out.flush()
        return True

    def run(self, image: str, done: int, env: Mapping[str, str], start_id: str) -> str:
        """Run the plan's commands from done on, in one container of image; tag the result."""
        container = None
        snapshots: List[str] = []
        try:
            with engine.signals_held():
                container = self.create(image, env)
            container.put_archive("/", tools_archive())
            for index in range(done, len(self.plan.commands)):
                command = self.plan.commands[index]
                if self.shell_on_failure:
                    label = state_label(start_id, self.plan.commands[:index], env)
                    snapshots.append(self.commit(container, label, self.plan.commands[done:index]))
                code = self.execute(container, command)
                if code != 0:
                    if self.shell_on_failure and self.on_failure(snapshots[-1], command, code):
                        snapshots.pop()
                    raise StepError(command[0], f"{shown(command)} failed with exit code "
                                    f"{code} (in a container of stage {self.plan.start})", code)
            label = state_label(start_id, self.plan.commands, env)
            return self.commit(container, label, self.plan.commands[done:], self.plan.tag)
        finally:
            # Held: Ctrl-C during the removal left it to the engine, and the removal of the
            # stage tag right after failed (the container still used the image).
            if container is not None:
                with engine.signals_held():
                    container.remove(force=True)
            # newest first: an older snapshot is the parent of the newer ones (and of the
            # result, which keeps it: removing it then fails, and that is fine)
            for snapshot in reversed(snapshots):
                with contextlib.suppress(engine.sdk().errors.APIError):
                    self.client.images.remove(snapshot)


def image_label(client: Any, ref: str) -> Optional[str]:
    try:
        return client.images.get(ref).labels.get(STATE_LABEL)
    except engine.sdk().errors.ImageNotFound:
        return None


def run_plan(
    settings: Settings,
    plan: Plan,
    *,
    shell_on_failure: bool = False,
    out: IO[str] = sys.stdout,
) -> str:
    """Build the plan's start stage, run its commands in a container (resuming from an image
    made earlier for a prefix of them), tag the result; returns the tag."""
    stage_tag = tag_of(settings, "stage", plan.start)
    client = None
    try:
        try:
            # (a stage to run steps in, never pushed: no attestations, which only an engine on
            # the containerd image store would keep)
            build.build_image(dataclasses.replace(settings, buildx_attestations=False),
                              target=plan.start, platform=settings.platform[0], tag=stage_tag,
                              out=out)
        except errors.BuildError as exc:
            if shell_on_failure and exc.stage in STAGES and exc.step:
                # The state before the start failed to build: open the shell where that failed.
                reproduce(settings, exc, out=out)
            raise
        except KeyboardInterrupt as exc:
            exc.args = ()  # (it named the stage's tag as built: the finally removes that)
            raise
        client = engine.client()
        start_id = str(client.images.get(stage_tag).id)
        declared = [a for a in buildplan.dockerfile_args() if a not in NOT_SETTINGS]
        start_config = client.images.get(start_id).attrs["Config"] or {}
        env = step_environment(settings, declared, start_config.get("Env") or [])
        candidates = {ref: image_label(client, ref) for ref in
                      (tag_of(settings, "after", s) for s in dict.fromkeys(
                          c[0] for c in plan.commands))}
        found, done = plan_resume(plan.commands, start_id, env, candidates,
                                  reuse_all=plan.reuse_all)
        if found:
            out.write(f"==> docker-ros: starting from {found}, which has run: "
                      + "; ".join(shown(c) for c in plan.commands[:done]) + "\n")
        with secrets_dir(settings) as secrets:
            session = Session(client, settings, plan, Path(settings.build_context).resolve(),
                              secrets, out, shell_on_failure,
                              start_config=start_config)
            session.run(found or start_id, done, env, start_id)
    finally:
        # The tag only named the stage's build; the image stays while our commits use it.
        if client is None:  # (Ctrl-C as buildx had just tagged it, or the build failed)
            with contextlib.suppress(engine.EngineError):
                engine.remove_quietly([stage_tag])
        else:
            with contextlib.suppress(engine.sdk().errors.APIError):
                client.images.remove(stage_tag)
            client.close()
    return plan.tag


def reproduce(settings: Settings, error: errors.BuildError, *, out: IO[str]) -> Optional[int]:
    """An image build failed in a step: run that stage's commands in a container of the state
    before it, up to the failed step, with a shell where it fails again. The step's exit code
    there (None: it did not fail again)."""
    plan = plan_step(settings, error.step, stage=error.stage)
    out.write(f"==> docker-ros: reproducing the failure of {error.step} in a container "
              f"(stage {error.stage})\n")
    try:
        run_plan(settings, plan, shell_on_failure=True, out=out)
    except StepError as failed:
        return failed.returncode
    out.write(f"==> docker-ros: {error.step} succeeded in the container (state {plan.tag}); "
              "the build failure did not repeat\n")
    return None
