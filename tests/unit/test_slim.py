"""Slim images: option parsing, plans, the functional comparison, ELF parsing, keep rules."""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import tarfile
import time
from pathlib import Path
from typing import Any, Callable, Iterator, List, Optional, Set, Tuple

import pytest

from docker_ros.core.loading import load_settings
from docker_ros.core.settings import SLIM_BUILD_ARGS_DEFAULT
from docker_ros.host import engine, slim, slimoptions, slimprobe
from docker_ros.host.push import plan_push, push_targets
from docker_ros.host.slim import (
    filter_tar,
    member_path,
    plan_changes,
    plan_trace_container,
    trace_report,
    tracer_spec,
)
from docker_ros.host.slimoptions import SlimError, SlimOptions, parse_slim_args
from docker_ros.host.slimprobe import (
    Probe,
    check_ending,
    check_report,
    compare_probes,
    exec_prefix,
    trace_ending,
    trouble_lines,
    watch,
)
from docker_ros.in_image import slimelf, slimtrace

# a shorter variant of docker-ros's default (SLIM_BUILD_ARGS_DEFAULT)
DOCKER_ROS_GITLAB_DEFAULT = (
    "--sensor-ipc-mode proxy --continue-after=30 --show-clogs --http-probe=false "
    "--env DOCKER_UID=23456 --env DOCKER_GID=23456 --env DOCKER_USER=dockerslimprobe "
    "--include-path /opt/ros --include-path /docker-ros/ws/install "
    "--include-path /etc/ld.so.cache --preserve-path /etc/passwd "
    "--exclude-pattern /home/dockerslimprobe --exclude-pattern /home/dockerslimprobe/**"
)


def test_default_args_parse_and_report_ignored_options_once() -> None:
    options = parse_slim_args(SLIM_BUILD_ARGS_DEFAULT + " --show-clogs")
    assert options.continue_after == 30
    assert options.include == ("/opt/ros", "/docker-ros/ws/install", "/etc/ld.so.cache",
                               "/etc/ld.so.conf", "/etc/ld.so.conf.d", "/etc/passwd",
                               "/etc/group", "/etc/shadow", "/etc/gshadow")
    assert options.ignored == ("--sensor-ipc-mode", "--show-clogs", "--http-probe")


def test_docker_ros_gitlab_default_parses() -> None:
    options = parse_slim_args(DOCKER_ROS_GITLAB_DEFAULT)
    assert options.continue_after == 30
    assert options.env == ("DOCKER_UID=23456", "DOCKER_GID=23456", "DOCKER_USER=dockerslimprobe")
    assert "/etc/passwd" in options.include and "/etc/ld.so.cache" in options.include
    assert options.exclude == ("/home/dockerslimprobe", "/home/dockerslimprobe/**")


def test_ours_exec_expect_and_include_exe() -> None:
    options = parse_slim_args("--exec 'rosnode list' --expect='I heard' --include-exe ls "
                              "--continue-after 2.5")
    assert options.execs == ("rosnode list",)
    assert options.expect == ("I heard",)
    assert options.executables == ("ls",)
    assert options.continue_after == 2.5
    assert options.settle == 3 and parse_slim_args("--settle=0.5").settle == 0.5


@pytest.mark.parametrize("text, message", [
    ("--frobnicate --include-path /x --bogus=1", "unknown option(s) --frobnicate, --bogus=1"),
    ("--continue-after=probe", "give a number of seconds"),
    ("--settle never", "--settle='never': give a number of seconds"),
    ("--env FOO", "use NAME=VALUE"),
    ("--include-path", "--include-path needs a value"),
    ("--tag x:y", "--tag is set by docker-ros"),
    ("--exec 'unterminated", "No closing quotation"),
])
def test_bad_args_are_errors_naming_them(text: str, message: str) -> None:
    with pytest.raises(SlimError, match=None) as raised:
        parse_slim_args(text)
    assert message in str(raised.value)


@pytest.mark.parametrize("text, additional, message", [
    ("", "--continue-after abc", "ADDITIONAL_SLIM_BUILD_ARGS: --continue-after='abc': give a "
     "number of seconds"),
    ("--settle=1", "--settle=-1", "ADDITIONAL_SLIM_BUILD_ARGS: --settle='-1': give a number of "
     "seconds, 0 or more"),
    ("--settle -2", "", "SLIM_BUILD_ARGS: --settle='-2': give a number of seconds, 0 or more"),
    ("--continue-after=-5", "", "SLIM_BUILD_ARGS: --continue-after='-5': give a number"),
    ("--include-path /x", "--bogus", "ADDITIONAL_SLIM_BUILD_ARGS: unknown option(s) --bogus;"),
    ("--bogus", "--frob", "SLIM_BUILD_ARGS/ADDITIONAL_SLIM_BUILD_ARGS: unknown option(s) "
     "--bogus, --frob;"),
    ("", "--env FOO", "ADDITIONAL_SLIM_BUILD_ARGS: --env 'FOO': use NAME=VALUE"),
    ("", "--tag x", "ADDITIONAL_SLIM_BUILD_ARGS: --tag is set by docker-ros"),
    ("", "--exec 'x", "ADDITIONAL_SLIM_BUILD_ARGS: No closing quotation"),
])
def test_errors_name_the_variable_the_option_is_in(text: str, additional: str,
                                                   message: str) -> None:
    with pytest.raises(SlimError) as raised:
        parse_slim_args(text, additional)
    assert str(raised.value).startswith(message), str(raised.value)


def test_the_additional_args_come_after_the_others() -> None:
    options = parse_slim_args("--settle 1 --exec", "'ros2 node list' --settle=0")
    assert options.settle == 0 and options.execs == ("ros2 node list",)


def test_exec_prefix_drops_the_init() -> None:
    assert exec_prefix(["/usr/bin/tini", "--", "/docker-ros/entrypoint.sh"]) == [
        "/docker-ros/entrypoint.sh"]
    assert exec_prefix(["tini", "/e.sh"]) == ["/e.sh"]
    assert exec_prefix(["/e.sh", "x"]) == ["/e.sh", "x"]
    assert exec_prefix([]) == []


CONFIG = {
    "Env": ["PATH=/usr/bin:/bin", 'DEFAULT_CMD=roslaunch a "b" $HOME'],
    "Entrypoint": ["/usr/bin/tini", "--", "/docker-ros/entrypoint.sh"],
    "Cmd": ["bash", "-c", 'eval "$DEFAULT_CMD"'],
    "WorkingDir": "/docker-ros/ws",
    "Labels": {"org.example": "a b"},
}


def test_changes_carry_the_config_quoted() -> None:
    changes = plan_changes(CONFIG, {"org.docker-ros.slim.source": "sha256:1"})
    assert changes == [
        'ENV PATH="/usr/bin:/bin"',
        'ENV DEFAULT_CMD="roslaunch a \\"b\\" \\$HOME"',
        'ENTRYPOINT ["/usr/bin/tini", "--", "/docker-ros/entrypoint.sh"]',
        'CMD ["bash", "-c", "eval \\"$DEFAULT_CMD\\""]',
        "WORKDIR /docker-ros/ws",
        'LABEL "org.docker-ros.slim.source"="sha256:1"',
        'LABEL "org.example"="a b"',
    ]


def test_changes_refuse_a_multiline_env() -> None:
    with pytest.raises(SlimError, match="COMMAND_X"):
        plan_changes({"Env": ["COMMAND_X=a\nb"]}, {})


def test_trace_container_plan() -> None:
    options = SlimOptions(env=("A=1",))
    spec = plan_trace_container("sha256:abc", CONFIG, options, "docker-ros-slim-trace-1")
    assert spec == {
        "image": "sha256:abc", "name": "docker-ros-slim-trace-1", "cap_add": ["SYS_ADMIN"],
        "user": "0:0", "environment": ["A=1"], "entrypoint": ["python3"],
        "command": ["/docker-ros-slim/slimtrace.py", "--out", "/docker-ros-slim", "--",
                    *CONFIG["Entrypoint"], *CONFIG["Cmd"]]}
    with pytest.raises(SlimError, match="neither ENTRYPOINT nor CMD"):
        plan_trace_container("x", {}, options, "n")
    spec = tracer_spec(CONFIG, SlimOptions(include=("/opt/ros",), exclude=("/x/**",)))
    assert spec["path"] == "/usr/bin:/bin" and "/opt/ros" in spec["include"]
    assert "/etc/passwd" in spec["include"] and "setpriv" in spec["executables"]
    assert spec["exclude"] == ["/x/**"]


def test_compare_same_behaviour_passes() -> None:
    run = Probe(None, [("rosnode list", 0, "/talker\n")], (0, "23456"), "I heard: 1\n")
    slim = Probe(None, [("rosnode list", 0, "/talker\n")], (0, "23456"), "I heard: 2\n")
    assert compare_probes(run, slim, SlimOptions(expect=("I heard",))) == []


def test_compare_names_every_difference() -> None:
    run = Probe(0, [("rosnode list", 0, "/talker\n")], (0, "23456"), "ok\n")
    slim = Probe(127, [("rosnode list", 1, "ImportError: rosnode\n")], (1, "useradd: not found"),
                 "talker: error while loading shared libraries: libroscpp.so\n")
    run.watched, slim.watched = 4.25, 0.5
    diffs = compare_probes(run, slim, SlimOptions(continue_after=5, expect=("ok", "never")))
    text = "\n".join(diffs)
    assert "COMMAND exited with 0 in the run image but exited with 127 in the slim image" in text
    assert "--exec 'rosnode list' exited with 0 in the run image but 1" in text
    assert "DOCKER_UID=23456 user mapping" in text
    assert "--expect 'ok' is in the run image's output, not the slim one's" in text
    assert "--expect 'never' is not in the run image's output either" in text
    assert "error while loading shared libraries: libroscpp.so" in text


def test_compare_ignores_errors_the_run_image_printed_too() -> None:
    run = Probe(None, output="[ERROR] [1700000000.1]: cannot reach 0x7f12\n")
    slim = Probe(None, output="[ERROR] [1700000099.9]: cannot reach 0x7f99\n")
    assert compare_probes(run, slim, SlimOptions()) == []
    died = Probe(None, output="[talker-2] process has died [pid 51, exit code 127]\n")
    assert "process has died" in compare_probes(run, died, SlimOptions())[0]


def test_push_includes_slim_when_enabled() -> None:
    settings = load_settings(environ={"IMAGE": "reg/x:v1", "TARGET": "dev,run",
                                      "ENABLE_PUSH_AS_LATEST": "true", "PLATFORM": "amd64"},
                             command="push")
    assert push_targets(settings) == ["dev", "run", "slim"]
    slim_target = load_settings(environ={"IMAGE": "reg/x:v1", "TARGET": "slim,dev"})
    assert push_targets(slim_target) == ["run", "dev", "slim"]
    pushed = [argv[-1] for argv in plan_push(settings, push_targets(settings))
              if argv[1] == "push"]
    assert pushed == ["reg/x:v1-dev", "reg/x:latest-dev", "reg/x:v1", "reg/x:latest",
                      "reg/x:v1-slim", "reg/x:latest-slim"]
    off = load_settings(environ={"IMAGE": "reg/x:v1", "ENABLE_SLIM": "false"})
    assert push_targets(off) == ["run"]
    dev_only = load_settings(environ={"IMAGE": "reg/x:v1", "TARGET": "dev"})
    assert push_targets(dev_only) == ["dev"]


def test_member_path() -> None:
    assert member_path("usr/bin/bash") == "/usr/bin/bash"
    assert member_path("./etc/") == "/etc"
    assert member_path(".dockerenv") == "/.dockerenv"


def test_filter_tar_keeps_listed_members_and_their_hard_links() -> None:
    source = io.BytesIO()
    with tarfile.open(fileobj=source, mode="w") as tar:
        for name, data in (("etc/passwd", b"root\n"), ("usr/bin/ls", b"ELF")):
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
        for name, target in (("usr/bin/dir", "usr/bin/ls"), ("etc/passwd-", "etc/passwd")):
            link = tarfile.TarInfo(name)
            link.type, link.linkname = tarfile.LNKTYPE, target
            tar.addfile(link)
    source.seek(0)
    out = io.BytesIO()
    kept, total = filter_tar(source, out, {"/etc/passwd", "/usr/bin/dir", "/etc/passwd-"})
    assert (kept, total) == (2, 4)  # usr/bin/dir links to a dropped member
    out.seek(0)
    with tarfile.open(fileobj=out) as tar:
        assert tar.getnames() == ["etc/passwd", "etc/passwd-"]
        assert tar.extractfile("etc/passwd").read() == b"root\n"  # type: ignore[union-attr]


def test_the_trace_window_ends_when_the_traced_files_settle() -> None:
    started = "docker-ros slimtrace: mark\n[talker] hello\n"
    settled = started + "docker-ros slimtrace: traced files settled after 2.1 s (412 files)\n"
    assert trace_ending(started, True, 0, ()) is None
    assert trace_ending(settled, True, 0, ()) == ("settled", None)
    assert trace_ending(settled, True, 0, ("I heard",)) is None  # until every --expect text
    assert trace_ending(settled + "I heard: 1\n", True, 0, ("I heard",)) == ("settled", None)
    exited = started + "docker-ros slimtrace: command exited with status 3\n"
    assert trace_ending(exited, True, 0, ("never",)) == ("exited", 3)
    with pytest.raises(SlimError, match="the tracer stopped early \\(exit code 1\\)"):
        trace_ending(started, False, 1, ())


def test_the_check_watches_as_long_as_the_trace_did() -> None:
    running = Probe(None, watched=4.0, ended="settled")
    assert check_ending(3.9, True, 0, running, lambda: "", ()) is None
    assert check_ending(4.0, True, 0, running, lambda: "", ()) == ("settled", None)
    assert check_ending(4.5, True, 0, running, lambda: "no", ("I heard",)) is None
    assert check_ending(4.5, True, 0, running, lambda: "I heard", ("I heard",)) == (
        "settled", None)
    assert check_ending(1.0, False, 127, running, lambda: "", ()) == ("exited", 127)
    exited = Probe(0, watched=1.0, ended="exited")  # waits for the slim image to exit too
    assert check_ending(9.0, True, 0, exited, lambda: "", ()) is None
    assert check_ending(9.0, False, 0, exited, lambda: "", ()) == ("exited", 0)


def test_watch_stops_at_the_first_ending_or_the_limit() -> None:
    assert watch(lambda elapsed: ("exited", 0), 10)[:2] == ("exited", 0)
    why, code, seconds = watch(lambda elapsed: None, 0.0)
    assert (why, code) == ("window", None) and seconds < 1


def test_trace_and_check_are_reported_one_line_each() -> None:
    options = SlimOptions(settle=3, execs=("rosnode list",), expect=("I heard",))
    settled = Probe(None, watched=5.04, ended="settled")
    figures = {"traced": 412, "kept": 2101, "keep_seconds": 2.46}
    assert trace_report(7.23, settled, figures, options) == (
        "slim: trace 7.2 s: COMMAND watched 5.0 s, until no new file was opened for 3 s and "
        "every --expect text was printed; 412 files opened (keep set 2.5 s)")
    assert check_report(6.01, settled, options) == (
        "slim: functional check 6.0 s passed (COMMAND still running after 5 s in both; "
        "1 exec(s), 1 expectation(s))")
    exited = Probe(0, watched=0.84, ended="exited")
    assert "COMMAND exited with 0 after 0.8 s;" in trace_report(2, exited, figures, options)
    whole = Probe(None, watched=10.2, ended="window")
    assert "COMMAND watched 10.2 s (--continue-after);" in trace_report(12, whole, {}, options)


# --------------------------------------------------------------------------- in-image code
def test_parse_elf_of_a_real_executable() -> None:
    python = Path("/proc/self/exe").resolve()
    elf = slimelf.read_elf(str(Path("/bin/ls").resolve()))
    assert elf is not None, python
    cls, _, interp, needed, _, _ = elf
    assert cls == 2 and interp and interp.startswith("/lib")
    assert "libc.so.6" in needed
    assert slimelf.read_elf(__file__) is None
    assert slimelf.parse_elf(b"\x7fELF" + b"\0" * 10) is None


def test_find_library_follows_ld_so_rules(tmp_path: Path) -> None:
    elf = slimelf.read_elf(str(Path("/bin/ls").resolve()))
    assert elf is not None
    system = slimelf.ld_so_conf_dirs() + list(slimelf.DEFAULT_LIB_DIRS)
    found = slimelf.find_library("libc.so.6", elf, "/bin/ls", [], system)
    assert found and Path(found).resolve().name.startswith("libc")
    assert slimelf.find_library("libnothere.so.9", elf, "/bin/ls", [str(tmp_path)],
                                  system) is None
    assert slimelf.expand_origin("$ORIGIN/../lib", "/opt/x/bin") == "/opt/x/bin/../lib"


def test_glob_regex_like_docker_slim() -> None:
    assert slimtrace.matches_any("/home/x/a/b", slimtrace.globs_regex(["/home/x/**"]))
    assert not slimtrace.matches_any("/usr/lib/sub/a.so", slimtrace.globs_regex(["/usr/lib/*.so"]))
    assert slimtrace.matches_any("/usr/lib/libfoo.so.1.2",
                                 slimtrace.globs_regex(["/usr/lib/libfoo.so*"]))
    one = slimtrace.globs_regex(["/usr/share/doc/"])
    assert slimtrace.matches_any("/usr/share/doc/bash/README", one)
    assert slimtrace.matches_any("/usr/share/doc", one)
    assert not slimtrace.matches_any("/usr/share/docs", one)
    assert not slimtrace.matches_any("/usr/share", one)
    several = slimtrace.globs_regex(["/opt/ros", "/usr/lib/*.so", "/home/**/x", "/"])
    assert slimtrace.matches_any("/opt/ros/lib/a.so", several)
    assert slimtrace.matches_any("/usr/lib/a.so/inside", several)  # below a match
    assert not slimtrace.matches_any("/usr/lib/sub/a.so", several)
    assert slimtrace.matches_any("/home/a/b/x/y", several)
    assert not slimtrace.matches_any("/usr", several) and not slimtrace.matches_any("/", several)
    assert not slimtrace.matches_any("/x", slimtrace.globs_regex([]))


def test_link_chain_and_python_companions(tmp_path: Path) -> None:
    real = tmp_path / "usr" / "lib"
    (real / "__pycache__").mkdir(parents=True)
    (real / "libx.so.1.2").write_text("x")
    (real / "libx.so.1").symlink_to("libx.so.1.2")
    (tmp_path / "lib").symlink_to("usr/lib")
    chain = slimtrace.link_chain(str(tmp_path / "lib" / "libx.so.1"))
    assert str(tmp_path / "lib") in chain
    assert str(real / "libx.so.1") in chain and str(real / "libx.so.1.2") in chain
    (real / "mod.py").write_text("")
    (real / "__pycache__" / "mod.cpython-311.pyc").write_text("")
    assert slimtrace.python_companions(str(real / "__pycache__" / "mod.cpython-311.pyc")) == [
        str(real / "mod.py")]
    assert slimtrace.python_companions(str(real / "mod.py")) == [
        str(real / "__pycache__" / "mod.cpython-311.pyc")]


def test_the_keep_set_names_each_file_once(tmp_path: Path) -> None:
    """A file reached through a symlinked folder keeps its real name only (the size report
    and the export count the same files)."""
    root = tmp_path.resolve()
    (root / "usr" / "lib").mkdir(parents=True)
    (root / "usr" / "lib" / "libc.so.6").write_text("c")
    (root / "lib").symlink_to("usr/lib")
    named = {str(root / "lib" / "libc.so.6"), str(root / "usr" / "lib" / "libc.so.6"),
             str(root / "lib"), str(root / "usr" / "lib")}
    assert slimtrace.without_aliases(named) == {
        str(root / "lib"), str(root / "usr" / "lib"), str(root / "usr" / "lib" / "libc.so.6")}


def test_ld_so_conf_includes(tmp_path: Path) -> None:
    (tmp_path / "conf.d").mkdir()
    (tmp_path / "conf.d" / "a.conf").write_text("# comment\n/opt/a/lib\n")
    (tmp_path / "ld.so.conf").write_text("include conf.d/*.conf\n/opt/b/lib # b\n")
    assert slimelf.ld_so_conf_dirs(str(tmp_path / "ld.so.conf")) == ["/opt/a/lib", "/opt/b/lib"]


def test_tracer_usage_error() -> None:
    assert slimtrace.main(["--bad"]) == 2
    assert json.dumps(tracer_spec({}, SlimOptions()))  # serializable for the container


def test_lines_logged_at_info_are_no_errors_but_errors_still_are():
    """roslaunch's race for ~/.ros/log/latest, logged at INFO, appears by chance in either
    image and must not fail the slim check; the same words as an error still do."""
    race = ("INFO: cannot create a symlink to latest log directory: [Errno 17] File exists: "
            "'/home/dockerslimprobe/.ros/log/latest'")
    assert trouble_lines(race) == set()
    assert trouble_lines("[INFO] [1.2]: could not find a thing, retrying") == set()
    assert trouble_lines("ERROR: cannot create a symlink to latest log directory") != set()
    assert trouble_lines("[ERROR] [1.2]: listener has died") != set()


def test_an_unknown_options_value_is_not_listed_as_an_option() -> None:
    with pytest.raises(SlimError) as err:
        parse_slim_args("", "--include-exe ls --foo 1 --bar")
    assert "unknown option(s) --foo, --bar;" in str(err.value)
    with pytest.raises(SlimError, match=r"unknown option\(s\) stray;"):
        parse_slim_args("stray --include-exe ls")


class EngineAnsweringDuringCtrlC:
    """containers.run/create of a docker client: the engine makes the container (and the
    slim check's runs COMMAND) while Ctrl-C arrives, before the call returns."""

    def __init__(self):
        self.made = {}
        self.removed = []
        self.containers = self

    def _make(self, name):
        made = self.made[name] = FakeContainer(name, self.removed)
        os.kill(os.getpid(), signal.SIGINT)
        return made

    def run(self, image, detach=False, name=None, environment=()):
        return self._make(name)

    def create(self, *args, name=None, **kwargs):
        return self._make(name or f"unnamed-{len(self.made)}")

    def get(self, name):
        return self.made[name]


class FakeContainer:
    def __init__(self, name, removed):
        self.name, self.removed = name, removed

    def remove(self, force=False):
        self.removed.append(self.name)


def traced_as(figures: Optional[dict] = None, keep: Set[str] = frozenset(),
              later: Optional[Set[str]] = None) -> Callable[..., Any]:
    """A stand-in for slim.tracing (the engine's side is tested in tests/docker/test_slim.py):
    the window's keep set and figures, and, if later is given, a command still running whose
    finish() gives that keep set."""

    @contextlib.contextmanager
    def tracing(*args: object) -> Iterator[slim.Trace]:
        traced = slim.Trace("fake", Path("."))
        traced.keep, traced.figures = set(keep), dict(figures or {})
        if later is not None:
            traced.running = True
            traced.finish = lambda: (set(later), {})  # type: ignore[method-assign]
        yield traced

    return tracing


def slimmed_on(monkeypatch: pytest.MonkeyPatch, images: dict,
               export: Callable[..., Tuple[str, int, int]]) -> List[Tuple[object, ...]]:
    """An engine with these images whose slim images export() makes and that pass the check:
    the list of tags and image removals slim_image then asks for."""
    monkeypatch.setattr(slim, "inspect_image", images.get)
    monkeypatch.setattr(slim, "export_filtered", export)
    monkeypatch.setattr(slim, "check", lambda *a: slimprobe.Probe())
    monkeypatch.setattr(slim, "image_size", lambda ref: 1)
    calls: List[Tuple[object, ...]] = []
    monkeypatch.setattr(slim, "tag", lambda image, ref: calls.append(("tag", image, ref)))
    monkeypatch.setattr(slim, "remove_quietly",
                        lambda refs, force=False: calls.extend(("rmi", r, force) for r in refs))
    return calls


@pytest.mark.parametrize("call", ["trace", "check", "run_once", "export_filtered"])
def test_ctrl_c_while_the_engine_starts_a_container_leaves_no_container(monkeypatch, tmp_path,
                                                                        call):
    # Ctrl-C right after the engine started the slim check's container left it running
    # COMMAND for good (`docker ps`: docker-ros-slim-check-...); export's and run_once's
    # containers stayed too.
    fake = EngineAnsweringDuringCtrlC()
    monkeypatch.setattr(slim, "client", lambda: fake)
    monkeypatch.setattr(engine, "client", lambda: fake)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            if call == "trace":
                options = slimoptions.SlimOptions()
                with slim.tracing("sha256:run", {"Cmd": ["x"]}, options, tmp_path):
                    pass
            elif call == "check":
                slim.check("sha256:slim", {}, slimoptions.SlimOptions(), slimprobe.Probe())
            elif call == "run_once":
                engine.run_once("sha256:run", ["true"], [])
            else:
                slim.export_filtered("sha256:run", set(), [])
    finally:
        signal.signal(signal.SIGINT, previous)
    assert list(fake.made) == fake.removed and len(fake.removed) == 1


def test_include_exe_and_include_bin_the_image_lacks_are_named(tmp_path: Path) -> None:
    """`--include-exe nosuchtool` or `--include-bin /usr/bin/nosuch` kept nothing and said
    nothing: the slim image was tagged without the tool the option asked for."""
    (tmp_path / "bin").mkdir()
    tool = tmp_path / "bin" / "tool"
    tool.write_text("#!/bin/sh\n")
    tool.chmod(0o755)
    options = parse_slim_args(f"--include-exe tool --include-exe nosuchtool "
                              f"--include-bin {tool} --include-bin {tmp_path}/nosuch")
    spec = tracer_spec({"Env": [f"PATH={tmp_path / 'bin'}"]}, options)
    assert slimtrace.missing_requests(json.loads(json.dumps(spec))) == [
        "--include-exe nosuchtool", f"--include-bin {tmp_path}/nosuch"]
    assert str(tool) in options.include  # --include-bin still keeps the file


def test_a_slim_run_whose_requested_executable_is_missing_tags_nothing(monkeypatch) -> None:
    settings = load_settings(environ={"IMAGE": "reg/x:v1", "PLATFORM": slim.host_platform(),
                                      "ADDITIONAL_SLIM_BUILD_ARGS": "--include-exe nosuchtool"})
    images = {"reg/x:v1": {"Id": "sha256:run", "Config": {"Cmd": ["x"]}}}
    monkeypatch.setattr(slim, "inspect_image", images.get)
    monkeypatch.setattr(slim, "tracing",
                        traced_as(figures={"missing": ["--include-exe nosuchtool"]}))

    def no_export(*args: object) -> None:
        raise AssertionError("the slim image was made")

    monkeypatch.setattr(slim, "export_filtered", no_export)
    with pytest.raises(SlimError, match="reg/x:v1 has no --include-exe nosuchtool: fix or remove"):
        slim.slim_image(settings, slim.host_platform())


def test_a_new_slim_image_removes_the_one_its_tag_left(monkeypatch) -> None:
    """Each re-slim (another run image or other options) left the previous slim image
    untagged on the engine, a layer of its own (87 MB for the example) per run."""
    settings = load_settings(environ={"IMAGE": "reg/x:v1", "PLATFORM": slim.host_platform()})
    images = {"reg/x:v1": {"Id": "sha256:run", "Config": {"Cmd": ["x"]}},
              "reg/x:v1-slim": {"Id": "sha256:oldslim", "Config": {"Labels": {}}}}
    monkeypatch.setattr(slim, "tracing", traced_as())
    calls = slimmed_on(monkeypatch, images, lambda *a: ("sha256:newslim", 1, 2))
    slim.slim_image(settings, slim.host_platform())
    assert calls == [("tag", "sha256:newslim", "reg/x:v1-slim"),
                     ("rmi", "sha256:oldslim", False)]  # (not forced: kept if still used)


def test_error_lines_are_named_without_terminal_colours() -> None:
    """roslaunch's red error lines were named as `[NmERROR: cannot launch node ...[Nm`."""
    red = "\x1b[31mERROR: cannot launch node of type [pkg/talker]\x1b[0m"
    assert trouble_lines(red) == {"ERROR: cannot launch node of type [pkg/talker]"}


def test_a_locked_slim_refuses_a_run_image_of_another_lock(monkeypatch, tmp_path: Path) -> None:
    """`inv slim --locked true` slimmed whatever run image was there: one built unlocked or
    from an older docker-ros.lock became the slim image without a word."""
    (tmp_path / "docker-ros.lock").write_text('{"format": 1, "targets": {}}\n')
    settings = load_settings(environ={"IMAGE": "reg/x:v1", "PLATFORM": slim.host_platform(),
                                      "LOCKED": "true", "BUILD_CONTEXT": str(tmp_path)})
    images = {"reg/x:v1": {"Id": "sha256:run", "Config": {
        "Cmd": ["x"], "Labels": {"org.docker-ros.lock": "sha256:older"}}}}
    monkeypatch.setattr(slim, "inspect_image", images.get)

    def no_trace(*args: object) -> None:
        raise AssertionError("traced")

    monkeypatch.setattr(slim, "tracing", no_trace)
    with pytest.raises(SlimError, match="run image reg/x:v1 was not built from this docker-ros"):
        slim.slim_image(settings, slim.host_platform())
    (tmp_path / "docker-ros.lock").unlink()
    with pytest.raises(SlimError, match="docker-ros.lock not found"):
        slim.slim_image(settings, slim.host_platform())


@pytest.mark.parametrize("later", [{"/bin/sh", "/usr/bin/tar"}, {"/bin/sh"}])
def test_files_the_command_opens_after_the_window_are_kept(monkeypatch, capsys, later) -> None:
    """A node that opened a file only after a pause longer than --settle lost it in the slim
    image, which passed its check (as long as the window) and was tagged: the trace now goes
    on while the image is made and checked, and what it adds makes the image again."""
    settings = load_settings(environ={"IMAGE": "reg/x:v1", "PLATFORM": slim.host_platform()})
    monkeypatch.setattr(slim, "tracing", traced_as(keep={"/bin/sh"}, later=later))
    made = []

    def export(run_id: str, keep: Set[str], changes: object) -> Tuple[str, int, int]:
        made.append(sorted(keep))
        return f"sha256:slim{len(made)}", len(keep), 9

    calls = slimmed_on(monkeypatch, {"reg/x:v1": {"Id": "sha256:run", "Config": {"Cmd": ["x"]}}},
                       export)
    stamp = slim.fingerprint
    monkeypatch.setattr(slim, "fingerprint", lambda *a: (time.sleep(0.3), stamp(*a))[1])
    slim.slim_image(settings, slim.host_platform())
    out = capsys.readouterr().out
    assert "slim: trace 0.0 s" in out  # the trace's own time, not also what came before it
    if len(later) == 1:
        assert made == [["/bin/sh"]] and "after the window" not in out
        assert calls == [("tag", "sha256:slim1", "reg/x:v1-slim")]
    else:
        assert made == [["/bin/sh"], ["/bin/sh", "/usr/bin/tar"]]
        assert calls == [("rmi", "sha256:slim1", True), ("tag", "sha256:slim2", "reg/x:v1-slim")]
        assert "and used 1 more file (/usr/bin/tar): made and checked again with them" in out


def test_include_paths_the_image_lacks_are_named_but_not_the_defaults(tmp_path: Path) -> None:
    """`--include-path /opt/mylib` that the run image lacks kept nothing and said nothing,
    while --include-exe stopped: a typo shipped a slim image without what was asked for. The
    paths of docker-ros's default SLIM_BUILD_ARGS (its /opt/ros is not in Debian's ROS images)
    are kept when there and never asked for, also when SLIM_BUILD_ARGS repeats them (the GitLab
    template and the Action set it to the default)."""
    (tmp_path / "lib" / "sub").mkdir(parents=True)
    (tmp_path / "lib" / "sub" / "libx.so.1").write_text("")
    options = parse_slim_args(
        SLIM_BUILD_ARGS_DEFAULT,
        f"--include-path {tmp_path}/lib --preserve-path {tmp_path}/etc/my.conf "
        f"--include-path {tmp_path}/lib/**/libx.so* --include-path {tmp_path}/lib/*/liby* "
        "--include-path /opt/ros")
    spec = json.loads(json.dumps(tracer_spec({}, options)))
    assert slimtrace.missing_requests(spec) == [
        f"--include-path {tmp_path}/lib/*/liby*", f"--preserve-path {tmp_path}/etc/my.conf"]
    assert f"{tmp_path}/etc/my.conf" in options.include  # still kept where it is there


def test_only_ignored_options_of_the_users_are_told(monkeypatch, capsys) -> None:
    """Every slim printed `ignoring options that do not apply here: --sensor-ipc-mode,
    --show-clogs, --http-probe`: options of docker-ros's default SLIM_BUILD_ARGS, which the user
    never chose. Only other ignored options are told now."""
    for additional, told in (("", ""), ("--http-probe-cmd /x --show-clogs", "--http-probe-cmd")):
        settings = load_settings(environ={"IMAGE": "reg/x:v1", "PLATFORM": slim.host_platform(),
                                          "ADDITIONAL_SLIM_BUILD_ARGS": additional})
        slim.slim_image(settings, slim.host_platform(), dry_run=True)
        lines = [line for line in capsys.readouterr().out.splitlines() if "ignoring" in line]
        assert lines == ([f"docker-ros slim: ignoring options that do not apply here: {told}"]
                         if told else [])


def test_a_tracer_that_ended_on_its_own_gives_its_results(monkeypatch, tmp_path) -> None:
    """The trace goes on while the slim image is made and checked; a tracer that stopped by
    then (its max_seconds bound, or an error it wrote) was killed anyway, and the engine's
    `container ... is not running` became the slim's error instead of the tracer's results."""
    import docker.errors

    exchange = io.BytesIO()
    with tarfile.open(fileobj=exchange, mode="w") as tar:
        for name, text in (("keep.txt", "/bin/sh\n"), ("done", '{"kept": 1}')):
            info = tarfile.TarInfo(f"docker-ros-slim/{name}")
            info.size = len(text)
            tar.addfile(info, io.BytesIO(text.encode()))

    class Stopped:
        attrs = {"State": {"Running": False, "ExitCode": 0}}

        def kill(self, signal: str) -> None:
            raise docker.errors.APIError("409 Client Error: container is not running")

        def wait(self, timeout: int) -> dict:
            return {"StatusCode": 0}

        def get_archive(self, path: str) -> Tuple[List[bytes], dict]:
            return [exchange.getvalue()], {}

    monkeypatch.setattr(slim, "container", lambda name: Stopped())
    traced = slim.Trace("docker-ros-slim-trace-x", tmp_path)
    traced.running = True
    assert traced.finish() == ({"/bin/sh"}, {"kept": 1}) and not traced.running


def test_the_check_runs_in_a_ros_domain_apart_from_the_traced_run() -> None:
    """The traced run image goes on while its slim image is checked: on one ROS 2 domain a
    slim listener heard the traced talker, and a slim image whose talker was broken passed."""
    options = parse_slim_args("--env A=1")
    assert slim.apart({}, options).env == ("A=1", "ROS_DOMAIN_ID=1")
    image = {"Env": ["PATH=/bin", "ROS_DOMAIN_ID=7"]}
    assert slim.apart(image, options).env[-1] == "ROS_DOMAIN_ID=8"
    assert slim.apart(image, parse_slim_args("--env ROS_DOMAIN_ID=101 --env B=2")).env == (
        "B=2", "ROS_DOMAIN_ID=0")
    assert slim.apart({"Env": ["ROS_DOMAIN_ID="]}, options).env[-1] == "ROS_DOMAIN_ID=1"
