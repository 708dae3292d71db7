"""Pure planning of steps in containers: the Dockerfile's step commands stage by stage, where
a step starts, --until, composites, resuming, the failed step of a BuildKit log."""

import dataclasses
import io
import os
import re
import signal
import threading
import time
import types
from pathlib import Path

import docker
import pytest

from docker_ros.core.loading import load_settings
from docker_ros.host import build, buildcontext, buildlog, buildplan, container
from docker_ros.in_image.steps import BY_NAME, OPTIONS, STEPS, step_options

STEP_CALL = r"python3 -m docker_ros\.in_image\.steps ([-a-z ]+?)\s*(?:&&|$)"


def settings(**environ):
    return load_settings(environ={"BASE_IMAGE": "base:1", "COMMAND": "run me", "IMAGE": "r/i:v1",
                                  **environ}, project_dir=Path("/tmp/My_Robot"))


def one_per_step(words):
    """`a b --opt x --flag` (several steps in one call) as the calls of each step alone, each
    with its own options (its declaration's) and the common ones (--phase)."""
    steps = [w for w in words if not w.startswith("-") and w in STEPS]
    rest = words[len(steps):]
    options, index = [], 0
    while index < len(rest):
        takes_value = index + 1 < len(rest) and not rest[index + 1].startswith("-")
        options.append(tuple(rest[index:index + 1 + takes_value]))
        index += 1 + takes_value
    names = {o: o[0][2:].replace("-", "_") for o in options}
    per_step = {names[o]: o for o in options if names[o] in {x.name for x in OPTIONS}}
    return [(step, *[w for o in options
                     if names[o] not in per_step or names[o] in step_options(step, per_step)
                     for w in o]) for step in steps]


def dockerfile_stages():
    """{stage: (parent, [step commands of its RUNs, in order])} read from the Dockerfile."""
    text = buildcontext.DOCKERFILE.read_text().replace("\\\n", " ")
    stages = {}
    current = None
    for line in text.splitlines():
        start = re.match(r"FROM (\S+) AS (\S+)$", line)
        if start:
            current = start.group(2)
            stages[current] = (start.group(1), [])
            continue
        for args in re.findall(STEP_CALL, line):
            if current and not args.startswith("prepare"):
                stages[current][1].extend(one_per_step(args.split()))
    return stages


def test_stages_are_the_dockerfiles_step_commands():
    stages = dockerfile_stages()
    for name, stage in container.STAGES.items():
        if name == "run":  # the default command; the build only checks what it names, in
            # command-check: the run image's dependencies and a view of its install space
            assert stages["run"] == ("dependencies-run", [])
            assert stages["command-check"] == ("dependencies-run", [("command", "--check")])
            assert stage.commands == (("command",),)
            continue
        parent, commands = stages[name]
        # dependencies-run mounts the resolution instead of copying it: it starts from base
        # (or its copy base-run), and in a container from resolved-run (base + the same files)
        expected = "${DOCKER_ROS_RUN_BASE}" if name == "dependencies-run" else stage.start
        # source starts from checkout, or from the skeleton of it (the files it reads)
        expected = "source-start" if name == "source" else expected
        assert parent == expected, name
        assert commands == list(stage.commands), name
    # every stage with step commands is known
    # upstream imports the .repos files alone: BuildKit only, inside the state clone starts from
    with_steps = {n for n, (_, c) in stages.items() if c} - {"upstream", "command-check"}
    assert with_steps | {"run"} == set(container.STAGES)


def test_the_dockerfile_calls_each_step_where_its_declaration_says():
    """A step's declaration (docker_ros.in_image.steps) names its stage and options: the
    Dockerfile's step calls run it there (the resolve stage collects the phased ones), with no
    option of another step's."""
    stages = dockerfile_stages()
    for step in STEPS:
        declared = BY_NAME[step]
        calls = [c for _, commands in stages.values() for c in commands if c[0] == step]
        assert calls, f"the Dockerfile never runs {step}"
        home = "command-check" if declared.stage == "run" else declared.stage
        assert any(c for c in stages[home][1] if c[0] == step), step
        for call in calls:
            options = {w[2:].replace("-", "_") for w in call if w.startswith("--")}
            assert options - {"phase"} <= set(declared.options), (step, call)
        if declared.phases:
            assert (step, "--phase", "collect") in stages["resolve"][1], step


def test_every_step_has_a_home_and_a_start_stage():
    stages = dockerfile_stages()
    assert list(container.STEP_STAGE) == list(STEPS)
    for step in STEPS:
        assert container.plan_step(settings(), step).start in stages
        assert container.plan_until(settings(), step).start in stages


def test_a_step_alone_starts_where_its_stage_does_and_runs_the_earlier_commands():
    plan = container.plan_step(settings(), "rosdep")
    assert plan.start == "resolved-dev" and not plan.sources and not plan.reuse_all
    assert plan.commands == (("scripts", "--phase", "apply"),
                             ("rosdep", "--phase", "apply", "--dependency-types", "all"))
    assert plan.tag == "r/i:v1-after-rosdep"
    clone = container.plan_step(settings(), "clone")
    assert (clone.start, clone.commands, clone.sources) == ("checkout", (("clone",),), True)
    # the repository is mounted: colcon must not touch the times of the user's files
    assert container.plan_step(settings(), "colcon").commands == (("colcon",),)
    assert container.plan_step(settings(), "command").start == "run"
    failed = container.plan_step(settings(), "debs", stage="resolve")
    assert failed.start == "resolve-inputs"
    assert failed.commands[-1] == ("debs", "--phase", "collect")


def test_until_is_the_build_state_right_after_the_step():
    mid = container.plan_until(settings(), "debs")
    assert mid.start == "resolved-dev" and mid.commands[-1] == ("debs", "--phase", "apply")
    assert mid.tag == "r/i:v1-until-debs" and mid.reuse_all and not mid.sources
    assert container.plan_until(settings(), "custom") == container.Plan(
        "dev", (), False, "r/i:v1-until-custom", reuse_all=True)
    assert container.plan_until(settings(), "colcon").start == "build"


def test_next_step_by_hand():
    assert container.next_command("clone") == ("blacklist", "--mark-ignored")
    assert container.next_command("blacklist") == ("scripts",)
    assert container.next_command("rosdep") == ("debs", "--phase", "apply")
    assert container.next_command("custom") == ("colcon", "--stamp-changed")
    assert container.next_command("colcon") == ("command",)
    assert container.next_command("command") is None


def test_composites_run_the_dev_recipe_in_one_container():
    dev = container.plan_composite(settings(), "dev")
    assert dev.start == "checkout" and dev.sources and dev.tag == "r/i:v1-after-dev"
    names = [c[0] for c in dev.commands]
    assert names[:2] == ["clone", "blacklist"] and names[-1] == "custom"
    assert ("prepare", "--dependency-types", "all") in dev.commands
    run = container.plan_composite(settings(), "run")
    assert run.commands[: len(dev.commands)] == dev.commands
    assert run.commands[len(dev.commands):] == (("colcon",), ("command",))


def test_resume_takes_the_longest_matching_prefix():
    commands = (("a",), ("b",), ("c",))
    env = {"X": "1"}
    label = container.state_label
    candidates = {"after-a": label("s1", commands[:1], env), "after-b": label("s1", commands[:2],
                                                                            env),
                  "other": label("s2", commands[:2], env), "none": None}
    assert container.plan_resume(commands, "s1", env, candidates) == ("after-b", 2)
    assert container.plan_resume(commands, "s1", {"X": "2"}, candidates) == (None, 0)
    assert container.plan_resume(commands, "s3", env, candidates) == (None, 0)
    done = {"after-c": label("s1", commands, env)}
    # a step asked for runs again; --until may take an image of exactly that state
    assert container.plan_resume(commands, "s1", env, done) == (None, 0)
    assert container.plan_resume(commands, "s1", env, done, reuse_all=True) == ("after-c", 3)


def test_environment_has_the_declared_settings_and_never_a_secret():
    s = settings(GIT_HTTPS_PASSWORD="hunter2", ROS_DISTRO="noetic")
    env = container.step_environment(s, buildplan.dockerfile_args())
    assert env["ROS_DISTRO"] == "noetic" and env["PYTHONPATH"] == "/docker-ros/lib"
    assert "hunter2" not in repr(env) and "GIT_HTTPS_PASSWORD" not in env
    assert not set(env) & set(container.NOT_SETTINGS)


def test_step_modules_come_before_the_start_images_pythonpath():
    """As the Dockerfile's RUNs (PYTHONPATH=/docker-ros/lib${PYTHONPATH:+:$PYTHONPATH}): a
    container's -e would replace the base image's entries, which hooks and colcon need."""
    s = settings(ROS_DISTRO="noetic")
    env = container.step_environment(
        s, buildplan.dockerfile_args(), ["PATH=/usr/bin", "PYTHONPATH=/opt/ros/noetic/lib/py"])
    assert env["PYTHONPATH"] == "/docker-ros/lib:/opt/ros/noetic/lib/py"
    empty = container.step_environment(s, buildplan.dockerfile_args(), ["PYTHONPATH="])
    assert empty["PYTHONPATH"] == "/docker-ros/lib"


def test_failed_step_and_stage_from_a_buildkit_log():
    log = [
        "#12 [resolve 1/1] RUN --mount=... python3 -m docker_ros.in_image.steps rosdep\n",
        "#16 [dependencies-dev 1/1] RUN --mount=...\n",
        "#12 0.5 Starting >>> rosdep\n",
        "#16 3.1 docker-ros custom: bash -e hooks/custom/01-custom.sh failed with exit code 3\n",
        "#16 ERROR: process did not complete successfully\n",
    ]
    assert buildlog.failed_step(log) == ("dependencies-dev", "custom")
    assert buildlog.failed_step(log[:3]) == ("", "")


def test_printed_docker_run_lines_quote_what_needs_it():
    line = container.docker_run_line("r/i:v1-failed-x", ["/a b:/docker-ros/ws/src/target"],
                                     ["python3", "-m", "docker_ros.in_image.steps", "x"], tty=True)
    assert line == ("docker run --rm -it -v '/a b:/docker-ros/ws/src/target' r/i:v1-failed-x "
                    "python3 -m docker_ros.in_image.steps x")


def test_every_declared_step_has_its_module_with_main():
    from docker_ros.in_image.steps import step_main

    for name in BY_NAME:
        assert callable(step_main(name)), name
        assert step_main(name).__module__ == BY_NAME[name].module


class InterruptedCreate:
    """A docker client whose containers.create is answered by the engine (the container
    exists) while Ctrl-C arrives: the signal comes before create returns."""

    def __init__(self):
        self.removed = []
        self.containers = self

    def create(self, *args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)  # (the engine's answer takes a moment: the signal is delivered in it)
        return FakeContainer(self.removed)


class FakeContainer:
    def __init__(self, removed):
        self.removed = removed

    def start(self):
        pass

    def put_archive(self, *args):
        raise AssertionError("the interrupt should have come first")

    def remove(self, force=False):
        self.removed.append(self)


def test_ctrl_c_while_the_engine_creates_the_container_leaves_no_container():
    # Ctrl-C right after the engine created the step container left it running
    # `sleep infinity` (and `docker ps` full of them): it was never in the variable that
    # the `finally` removes. With another thread running (the tool's log readers, the
    # suite's warm-up), the kernel hands the signal to that thread: holding it by the main
    # thread's signal mask let it through.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    fake = InterruptedCreate()
    plan = container.plan_step(settings(), "rosdep")
    session = container.Session(fake, settings(), plan, Path("/tmp/My_Robot"), None,
                                io.StringIO(), False)
    other_thread_done = threading.Event()
    other_thread = threading.Thread(target=other_thread_done.wait)
    other_thread.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            session.run("image", 0, {}, "sha256:start")
    finally:
        other_thread_done.set()
        other_thread.join()
        signal.signal(signal.SIGINT, previous)
    assert len(fake.removed) == 1


def test_ctrl_c_as_the_start_stage_is_tagged_leaves_no_stage_tag(monkeypatch):
    # Ctrl-C right after buildx tagged <IMAGE>-stage-<stage> (before the code that removes
    # that tag again began) left the tag in `docker images`.
    tags = set()

    def build_image(settings, *, target, platform, tag, out):
        tags.add(tag)
        raise KeyboardInterrupt

    monkeypatch.setattr(container.build, "build_image", build_image)
    monkeypatch.setattr(container.engine, "remove_quietly", tags.difference_update)
    with pytest.raises(KeyboardInterrupt):
        container.run_plan(settings(), container.plan_step(settings(), "rosdep"),
                           out=io.StringIO())
    assert tags == set()


class EngineOfOneRun:
    """A docker client for run_plan: the start stage's image, one container; the container's
    removal takes a moment, and Ctrl-C comes during it (the engine then finishes it alone)."""

    def __init__(self):
        self.containers = self.images = self
        self.removing = False
        self.tags = {"r/i:v1-stage-resolved-dev"}

    def get(self, ref):
        return types.SimpleNamespace(id="sha256:start", attrs={"Config": {}}, labels={})

    def create(self, *args, **kwargs):
        return types.SimpleNamespace(start=lambda: None, put_archive=lambda *a: None,
                                     commit=lambda **k: types.SimpleNamespace(id="sha256:after"),
                                     remove=self.remove_container)

    def remove_container(self, force=False):
        self.removing = True
        os.kill(os.getpid(), signal.SIGINT)
        self.removing = False  # the engine's answer

    def remove(self, ref, **kwargs):
        if self.removing:
            raise docker.errors.APIError(f"conflict: unable to remove {ref}: a container uses it")
        self.tags.discard(ref)

    def close(self):
        pass


def test_ctrl_c_while_the_step_container_is_removed_still_removes_the_stage_tag(monkeypatch):
    # Ctrl-C as the container was being removed cut that call short; the engine was still
    # removing the container when the stage tag's removal came, refused it ("a container is
    # using its referenced image"), and <IMAGE>-stage-resolved-dev stayed.
    fake = EngineOfOneRun()
    monkeypatch.setattr(container.build, "build_image", lambda *a, **k: None)
    monkeypatch.setattr(container.engine, "client", lambda: fake)
    plan = dataclasses.replace(container.plan_step(settings(), "rosdep"), commands=())
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            container.run_plan(settings(), plan, out=io.StringIO())
    finally:
        signal.signal(signal.SIGINT, previous)
    assert fake.tags == set()


def test_hints_name_the_engine_of_a_docker_context_builder(monkeypatch, capsys):
    """BUILDER=e26, a docker context of another engine, keeps the after-/until-/failed- images
    there: the printed `docker run`s (and the shell a failure opens) reached the local engine,
    which has no such image. They name the context now; a local build's stay `docker run`."""
    from docker_ros.host import builder, pipeline

    e26 = builder.Builder("e26", "docker", "e26", "unix:///e26.sock", True)
    monkeypatch.setenv("DOCKER_HOST", "unix:///local.sock")
    monkeypatch.setattr(build, "selected_builder", lambda settings: e26)
    monkeypatch.setattr(build, "check_engine", lambda settings: None)
    monkeypatch.setattr(container, "run_plan", lambda settings, plan, **kw: plan.tag)
    pipeline.build_until(settings(BUILDER="e26"), "rosdep", dry_run=False,
                         shell_on_failure=False)
    shown = capsys.readouterr().out
    assert "enter it: docker --context e26 run --rm -it r/i:v1-until-rosdep bash" in shown
    assert ("next step: docker --context e26 run --rm r/i:v1-until-rosdep python3 -m "
            "docker_ros.in_image.steps debs --phase apply") in shown

    # no terminal: the failed state's lines; with one, the shell's own docker run
    tagged = types.SimpleNamespace(tag=lambda *a: None)
    client = types.SimpleNamespace(images=types.SimpleNamespace(get=lambda ref: tagged))
    out = io.StringIO()
    session = container.Session(client, settings(BUILDER="e26"),
                                container.plan_step(settings(), "custom"), Path("/tmp/My_Robot"),
                                None, out, True)
    monkeypatch.setattr(container.sys.stdin, "isatty", lambda: False, raising=False)
    session.on_failure("sha256:snap", ("custom", "--phase", "apply"), 3)
    assert "enter it:  docker --context e26 run --rm -it r/i:v1-failed-custom bash" in (
        out.getvalue())
    assert "re-run it: docker --context e26 run --rm r/i:v1-failed-custom python3" in (
        out.getvalue())
    calls = []
    monkeypatch.setattr(container.sys, "stdin", types.SimpleNamespace(isatty=lambda: True))
    monkeypatch.setattr(container.sys, "stdout", types.SimpleNamespace(isatty=lambda: True))
    monkeypatch.setattr(container.subprocess, "call", calls.append)
    session.on_failure("sha256:snap", ("custom", "--phase", "apply"), 3)
    assert calls[0][:4] == ["docker", "--context", "e26", "run"]

    assert builder.images_cli(e26, "unix:///local.sock") == ["docker", "--context", "e26"]
    assert builder.images_cli(e26, "unix:///e26.sock") == ["docker"]  # (DOCKER_CONTEXT=e26)
    local = builder.Builder("default", "docker", "default", "unix:///local.sock", False)
    assert builder.images_cli(local, "unix:///local.sock") == ["docker"]
    own = builder.Builder("bk", "docker-container", "unix:///bk.sock", "", False)
    assert builder.images_cli(own, "unix:///local.sock") == ["docker"]  # --load copies them
