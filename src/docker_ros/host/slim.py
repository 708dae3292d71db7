"""Slim images: trace the run image's COMMAND, keep what it uses, prove the result still works.

No external binary: a stdlib tracer (docker_ros/in_image/slimtrace.py, fanotify) runs inside a
container of the run image and computes the keep set there; the run image's filesystem is exported,
filtered by that set and imported with the run image's config; then the slim image is run with
the same probe as the traced run, and only if it behaves the same is it tagged. A command still
running after the window goes on, traced, meanwhile: files it opens then make the image again.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import re
import shlex
import tarfile
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, Any, Callable, Dict, Iterator, List, Mapping, Optional, Sequence, Set, Tuple

from docker_ros.core.loading import host_platform
from docker_ros.core.settings import SLIM_BUILD_ARGS_DEFAULT, Settings
from docker_ros.host.build import image_size
from docker_ros.host.buildcontext import PACKAGE_DIR
from docker_ros.host.engine import (
    client,
    container,
    container_state,
    engine_errors,
    inspect_image,
    logs,
    remove_container,
    remove_quietly,
    run_once,
    signals_held,
    tag,
)
from docker_ros.host.lock import LOCK_LABEL, lock_labels, lock_path
from docker_ros.host.refs import target_ref

TRACER = PACKAGE_DIR / "in_image" / "slimtrace.py"
EXCHANGE = "/docker-ros-slim"  # the tracer and its results inside the trace container
LABEL_SOURCE = "io.docker-ros.slim.source"
LABEL_FINGERPRINT = "io.docker-ros.slim.fingerprint"
EXITED = re.compile(r"docker-ros slimtrace: command exited with status (-?\d+)")
SETTLED = re.compile(r"docker-ros slimtrace: traced files settled after ([\d.]+) s")
SNAPSHOT = re.compile(r"docker-ros slimtrace: keep set written, tracing on")
SETTLE_SECONDS = 3.0  # --settle's default
TRACER_LINE = re.compile(r"^docker-ros slimtrace: .*\n?", re.MULTILINE)
# A DOCKER_UID/GID probe of the docker-ros entrypoint (as docker-ros's own SLIM_BUILD_ARGS do).
PROBE_UID = "23456"
PROBE_USER = "dockerslimprobe"

# What every image keeps whatever the trace saw: user databases and what maps users, the
# dynamic linker's configuration, CA certificates, the shells and the entrypoint.
ESSENTIAL_PATHS = (
    "/etc/passwd", "/etc/group", "/etc/shadow", "/etc/gshadow", "/etc/subuid", "/etc/subgid",
    "/etc/nsswitch.conf", "/etc/login.defs", "/etc/default/useradd", "/etc/skel",
    "/etc/pam.d", "/etc/security", "/etc/ld.so.conf", "/etc/ld.so.conf.d", "/etc/ld.so.cache",
    "/etc/ssl/certs", "/etc/ca-certificates.conf", "/usr/share/ca-certificates",
    "/usr/local/share/ca-certificates", "/etc/os-release", "/usr/lib/os-release",
    "/etc/hosts", "/etc/hostname", "/etc/resolv.conf", "/etc/localtime", "/etc/environment",
    "/etc/profile", "/etc/bash.bashrc", "/root/.bashrc", "/root/.profile", "/.dockerenv",
    "/docker-ros/entrypoint.sh",
    # Python finds its prefix by the landmark os.py, which it never opens (frozen since 3.11)
    "/usr/lib/python3*/os.py", "/usr/local/lib/python3*/os.py",
)
ESSENTIAL_EXECUTABLES = (
    "sh", "bash", "env", "tini", "setpriv", "useradd", "groupadd", "getent", "chpasswd", "id",
    "cut",
)
INITS = ("tini", "tini-static", "docker-init", "dumb-init")
# Output lines that mean something went wrong; those in the slim run but not the run image's
# (digits, hex and UUIDs normalized) fail the check: a node may die while roslaunch runs on.
TROUBLE = re.compile(
    r"error|traceback|exception|not found|no such file|cannot |can't|could not|has died|"
    r"segmentation fault|core dumped|permission denied|fatal",
    re.IGNORECASE,
)

# docker-slim options: ours (value kind) and those that do not apply here.
OPTIONS = {
    "--include-path": "path", "--preserve-path": "path", "--exclude-pattern": "path",
    "--include-bin": "path", "--include-exe": "path", "--continue-after": "seconds",
    "--settle": "seconds", "--env": "env", "--exec": "text", "--expect": "text",
}
IGNORED_WITH_VALUE = frozenset({
    "--sensor-ipc-mode", "--sensor-ipc-endpoint", "--http-probe-cmd", "--http-probe-cmd-file",
    "--http-probe-ports", "--http-probe-retry-count", "--http-probe-retry-wait",
    "--http-probe-start-wait", "--http-probe-concurrency", "--http-probe-apispec",
    "--http-probe-apispec-file", "--http-probe-exec", "--http-probe-exec-file",
    "--publish-port", "--image-build-engine", "--image-build-arch", "--report",
    "--copy-meta-artifacts", "--state-path", "--new-label",
})
IGNORED_FLAGS = frozenset({
    "--show-clogs", "--show-blogs", "--http-probe", "--http-probe-off", "--http-probe-full",
    "--include-shell", "--include-cert-all", "--include-cert-bundles-only", "--keep-perms",
    "--include-new", "--remove-file-artifacts", "--keep-tmp-artifacts", "--obfuscate-metadata",
    "--include-oslibs-net", "--publish-exposed-ports", "--continue-after-signal",
})


class SlimError(Exception):
    """Slimming failed: what, which image or option, what to do."""


@dataclass(frozen=True)
class SlimOptions:
    include: Tuple[str, ...] = ()
    exclude: Tuple[str, ...] = ()
    executables: Tuple[str, ...] = ()
    binaries: Tuple[str, ...] = ()  # --include-bin (also in include)
    paths: Tuple[Tuple[str, str], ...] = ()  # (--include-path or --preserve-path, path)
    continue_after: float = 10.0  # the longest window
    settle: float = SETTLE_SECONDS  # the window ends this long after the last new file
    env: Tuple[str, ...] = ()
    execs: Tuple[str, ...] = ()
    expect: Tuple[str, ...] = ()
    ignored: Tuple[str, ...] = ()


def parse_slim_args(text: str, additional: str = "") -> SlimOptions:
    """SLIM_BUILD_ARGS (text) + ADDITIONAL_SLIM_BUILD_ARGS (additional), docker-slim syntax ->
    options; an error names the variable the bad option is in."""
    tokens: List[Tuple[str, str]] = []  # (variable, word)
    for variable, words in (("SLIM_BUILD_ARGS", text), ("ADDITIONAL_SLIM_BUILD_ARGS", additional)):
        try:
            tokens += [(variable, word) for word in shlex.split(words)]
        except ValueError as exc:
            raise SlimError(f"{variable}: {exc}") from None
    given: Dict[str, List[Tuple[str, str]]] = {name: [] for name in OPTIONS}
    ignored: List[str] = []
    unknown: List[Tuple[str, str]] = []
    after_unknown = -1
    index = 0
    while index < len(tokens):
        variable, token = tokens[index]
        index += 1
        name, equals, value = token.partition("=")
        if name in OPTIONS or name in IGNORED_WITH_VALUE:
            if not equals:
                if index >= len(tokens):
                    raise SlimError(f"{variable}: {name} needs a value")
                value = tokens[index][1]
                index += 1
            if name in OPTIONS:
                given[name].append((variable, value))
            elif name not in ignored:
                ignored.append(name)
        elif name in IGNORED_FLAGS:
            if name not in ignored:
                ignored.append(name)
        elif name in ("--target", "--tag"):
            raise SlimError(f"{variable}: {name} is set by docker-ros (IMAGE_NAME/IMAGE_TAG,"
                            " SLIM_IMAGE_NAME/SLIM_IMAGE_TAG); remove it")
        elif token.startswith("-") or after_unknown != index - 1:
            unknown.append((variable, token))
            after_unknown = index  # the next word, if no option, is the unknown option's value
    if unknown:
        raise SlimError(
            "/".join(dict.fromkeys(v for v, _ in unknown)) + ": unknown option(s) "
            + ", ".join(t for _, t in unknown) + "; supported: " + ", ".join(OPTIONS)
            + " (see the docs' guide, Slim images)")
    continue_after = seconds_option("--continue-after", given["--continue-after"], 10.0)
    settle = seconds_option("--settle", given["--settle"], SETTLE_SECONDS)
    for variable, pair in given["--env"]:
        if "=" not in pair:
            raise SlimError(f"{variable}: --env {pair!r}: use NAME=VALUE")
    values = {name: [value for _, value in pairs] for name, pairs in given.items()}
    return SlimOptions(
        include=tuple(values["--include-path"] + values["--preserve-path"]
                      + values["--include-bin"]),
        exclude=tuple(values["--exclude-pattern"]),
        executables=tuple(values["--include-exe"]),
        binaries=tuple(values["--include-bin"]),
        paths=tuple((option, value) for option in ("--include-path", "--preserve-path")
                    for value in values[option]),
        continue_after=continue_after,
        settle=settle,
        env=tuple(values["--env"]),
        execs=tuple(values["--exec"]),
        expect=tuple(values["--expect"]),
        ignored=tuple(ignored),
    )


def seconds_option(name: str, given: Sequence[Tuple[str, str]], default: float) -> float:
    """The last value of a seconds option (docker-slim: the last one wins); given: (variable,
    value) pairs."""
    seconds = default
    for variable, raw in given:
        try:
            seconds = float(raw)
        except ValueError:
            seconds = -1.0
        if not seconds >= 0:  # (negative, or not a number at all: NaN too)
            raise SlimError(f"{variable}: {name}={raw!r}: give a number of seconds, 0 or more"
                            " (docker-slim's enter/signal/probe modes do not apply)")
    return seconds


# The paths docker-ros's default SLIM_BUILD_ARGS keeps when they are there: its /opt/ros is
# missing from Debian's ROS images (ROS in /usr), and that must not stop the defaults.
DEFAULT_PATHS = frozenset(path for _, path in parse_slim_args(SLIM_BUILD_ARGS_DEFAULT).paths)
# docker-slim options of that default that do not apply here: not worth a line on every slim
DEFAULT_IGNORED = frozenset(parse_slim_args(SLIM_BUILD_ARGS_DEFAULT).ignored)


def slim_options(settings: Settings) -> SlimOptions:
    return parse_slim_args(settings.slim_build_args, settings.additional_slim_build_args)


# ------------------------------------------------------------------------------ pure plans
def exec_prefix(entrypoint: Sequence[str]) -> List[str]:
    """The entrypoint without its init (a `docker exec` process is not PID 1)."""
    items = list(entrypoint)
    if items and os.path.basename(items[0]) in INITS:
        items = items[items.index("--") + 1:] if "--" in items else items[1:]
    return items


def maps_users(entrypoint: Sequence[str]) -> bool:
    return any(item.endswith("docker-ros/entrypoint.sh") for item in entrypoint)


def plan_trace_container(run_id: str, config: Mapping, options: SlimOptions,
                         name: str) -> Dict[str, object]:
    """The trace container (arguments of the SDK's containers.create): the tracer (PID 1,
    root, CAP_SYS_ADMIN for fanotify) starts the image's entrypoint and command."""
    command = list(config.get("Entrypoint") or []) + list(config.get("Cmd") or [])
    if not command:
        raise SlimError("the run image has neither ENTRYPOINT nor CMD: nothing to trace")
    return {"image": run_id, "name": name, "cap_add": ["SYS_ADMIN"], "user": "0:0",
            "environment": list(options.env), "entrypoint": ["python3"],
            "command": [f"{EXCHANGE}/slimtrace.py", "--out", EXCHANGE, "--", *command]}


def tracer_spec(config: Mapping, options: SlimOptions) -> Dict[str, object]:
    path = next((e.split("=", 1)[1] for e in config.get("Env") or [] if e.startswith("PATH=")),
                "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin")
    return {
        "include": list(ESSENTIAL_PATHS) + list(options.include),
        "exclude": list(options.exclude),
        "executables": list(ESSENTIAL_EXECUTABLES) + list(options.executables),
        "path": path,
        # what the options ask for by name: the tracer reports those the image lacks (a path
        # of the default SLIM_BUILD_ARGS is kept when it is there, and never asked for)
        "requested": [["--include-exe", name] for name in options.executables]
        + [["--include-bin", name] for name in options.binaries]
        + [[option, path] for option, path in options.paths if path not in DEFAULT_PATHS],
        # the host stops the trace; this only bounds a trace whose host went away
        "max_seconds": options.continue_after + 900,
        "settle_seconds": options.settle,
    }


def dockerfile_quote(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("$", "\\$") + '"'


def plan_changes(config: Mapping, labels: Mapping[str, str]) -> List[str]:
    """The import's change instructions (`docker import --change`) that give the slim image
    the run image's config."""
    changes = []
    for entry in config.get("Env") or []:
        name, _, value = entry.partition("=")
        if "\n" in value:
            raise SlimError(f"ENV {name} of the run image holds a newline, which `docker import` "
                            "cannot carry; keep COMMAND and ENV values on one line")
        changes.append(f"ENV {name}={dockerfile_quote(value)}")
    for key in ("Entrypoint", "Cmd"):
        if config.get(key):
            changes.append(f"{key.upper()} {json.dumps(config[key])}")
    if config.get("WorkingDir"):
        changes.append(f"WORKDIR {config['WorkingDir']}")
    if config.get("User"):
        changes.append(f"USER {config['User']}")
    for port in sorted(config.get("ExposedPorts") or {}):
        changes.append(f"EXPOSE {port}")
    if config.get("Volumes"):
        changes.append(f"VOLUME {json.dumps(sorted(config['Volumes']))}")
    for key, value in sorted({**(config.get("Labels") or {}), **labels}.items()):
        changes.append(f"LABEL {dockerfile_quote(key)}={dockerfile_quote(value)}")
    return changes


def fingerprint(run_id: str, options: SlimOptions) -> str:
    """Same run image, same options, same tracer: the existing slim image is still right."""
    key = json.dumps([run_id, repr(options), TRACER.read_bytes().decode()])
    return hashlib.sha256(key.encode()).hexdigest()[:24]


def member_path(name: str) -> str:
    """A tar member name of `docker export` as an absolute path."""
    name = name[2:] if name.startswith("./") else name.lstrip("/")
    return "/" + name.rstrip("/")


# ------------------------------------------------------------------------------ the check
@dataclass
class Probe:
    """How an image behaved: COMMAND's exit status (None: still running at the end of the
    window), the execs' exit status and output, the DOCKER_UID probe's, and the output; how
    long the window lasted and why it ended ("exited", "settled" or "window")."""

    exit_code: Optional[int] = None
    execs: List[Tuple[str, int, str]] = field(default_factory=list)
    user: Optional[Tuple[int, str]] = None
    output: str = ""
    watched: float = 0.0
    ended: str = "window"

    def all_output(self) -> str:
        return self.output + "".join(out for _, _, out in self.execs)


# a line a program logged at level INFO or DEBUG is no error, whatever it says (roslaunch's
# processes race to make ~/.ros/log/latest: "INFO: cannot create a symlink to latest log
# directory: [Errno 17] File exists", in either image, by chance)
INFORMATIONAL = re.compile(r"^\s*\[?\s*(INFO|DEBUG)\b")
# terminal colours and titles (roslaunch prints its errors in red): not part of the message
ANSI = re.compile(r"\x1b(?:\[[0-9;?]*[A-Za-z]|\][^\x07]*\x07)")


def trouble_lines(output: str) -> Set[str]:
    lines = set()
    for line in ANSI.sub("", output).splitlines():
        if TROUBLE.search(line) and not INFORMATIONAL.match(line):
            line = re.sub(r"[0-9a-f]{8}(-[0-9a-f]{4}){3}-[0-9a-f]{12}", "<uuid>", line.strip())
            lines.add(re.sub(r"0x[0-9a-fA-F]+|\d+", "N", line))
    return lines


def describe_exit(code: Optional[int], seconds: float) -> str:
    return f"still running after {seconds:g} s" if code is None else f"exited with {code}"


def compare_probes(reference: Probe, slim: Probe, options: SlimOptions) -> List[str]:
    """What the slim image did differently from the run image (empty: it passed)."""
    diffs = []
    if reference.exit_code != slim.exit_code:
        diffs.append(f"COMMAND {describe_exit(reference.exit_code, reference.watched)} in the "
                     f"run image but {describe_exit(slim.exit_code, slim.watched)} in the slim "
                     "image")
    for (command, code, _), (_, slim_code, slim_out) in zip(reference.execs, slim.execs):
        if code != slim_code:
            last = slim_out.strip().splitlines()[-1:] or ["no output"]
            diffs.append(f"--exec {command!r} exited with {code} in the run image but "
                         f"{slim_code} in the slim image ({last[0]})")
    if reference.user != slim.user and slim.user is not None:
        diffs.append(f"DOCKER_UID={PROBE_UID} user mapping: run image gave {reference.user}, "
                     f"slim image {slim.user}")
    for text in options.expect:
        if text not in reference.all_output():
            diffs.append(f"--expect {text!r} is not in the run image's output either: "
                         "check the expectation or --continue-after")
        elif text not in slim.all_output():
            diffs.append(f"--expect {text!r} is in the run image's output, not the slim one's")
    new = sorted(trouble_lines(slim.all_output()) - trouble_lines(reference.all_output()))
    if new:
        diffs.append("the slim image printed errors the run image did not: "
                     + " | ".join(new[:5]))
    return diffs


Ending = Optional[Tuple[str, Optional[int]]]  # why a window ends, COMMAND's exit status


def expected_seen(expect: Sequence[str], output: str) -> bool:
    return all(text in output for text in expect)


def trace_ending(log: str, running: bool, code: int, expect: Sequence[str]) -> Ending:
    """Why the trace window ends now (None: it goes on): COMMAND exited, or the traced files
    settled (the tracer's SETTLED line) with every --expect text printed."""
    found = EXITED.search(log)
    if found:
        return ("exited", int(found.group(1)))
    if not running:
        raise SlimError(f"the tracer stopped early (exit code {code}): " + log.strip()[-500:])
    if SETTLED.search(log) and expected_seen(expect, log):
        return ("settled", None)
    return None


def check_ending(elapsed: float, running: bool, code: int, reference: Probe,
                 output: Callable[[], str], expect: Sequence[str]) -> Ending:
    """Why the check window ends now: COMMAND exited, or the slim image ran as long as the
    run image was watched (and printed every --expect text)."""
    if not running:
        return ("exited", code)
    if reference.ended != "exited" and elapsed >= reference.watched and (
            not expect or expected_seen(expect, output())):
        return (reference.ended, None)
    return None


def watch(poll: Callable[[float], Ending], limit: float) -> Tuple[str, Optional[int], float]:
    """Poll with the seconds since the start until it says why the window ends, at most limit
    seconds: (why, COMMAND's exit status or None, seconds watched)."""
    began = time.monotonic()
    while True:
        elapsed = time.monotonic() - began
        ended = poll(elapsed)
        if ended is not None:
            return ended[0], ended[1], elapsed
        if elapsed >= limit:
            return "window", None, elapsed
        time.sleep(0.3)


def run_probes(name: str, image: str, config: Mapping, options: SlimOptions,
               poll: Callable[[float], Ending], limit: float, alive: Callable[[], bool]) -> Probe:
    """Watch a started container for the window, then run the execs and the user probe:
    in it while it runs, else in a fresh container of the image."""
    probe = Probe()
    probe.ended, probe.exit_code, probe.watched = watch(poll, limit)
    prefix = exec_prefix(config.get("Entrypoint") or [])

    def in_image(env: Sequence[str], argv: Sequence[str]) -> Tuple[int, str]:
        if not alive():
            return run_once(image, argv, env)
        with engine_errors(f"running {shlex.join(argv)[:100]} in {name}"):
            code, out = container(name).exec_run([*prefix, *argv], environment=list(env))
        return int(code), bytes(out).decode(errors="replace")

    for command in options.execs:
        code, out = in_image(options.env, ["bash", "-c", command])
        probe.execs.append((command, code, out))
    if maps_users(config.get("Entrypoint") or []):
        user_env = [f"DOCKER_UID={PROBE_UID}", f"DOCKER_GID={PROBE_UID}",
                    f"DOCKER_USER={PROBE_USER}"]
        code, out = in_image(user_env, ["id", "-u"])
        probe.user = (code, out.strip().splitlines()[-1] if out.strip() else "")
    probe.output = TRACER_LINE.sub("", logs(name))
    return probe


class Trace:
    """The traced run image: its probe (the reference) and, at the end of the window, the keep
    set and the tracer's figures. A command still running then goes on, traced, while the slim
    image is made and checked; finish() stops it and gives the keep set with all it opened."""

    def __init__(self, name: str, workdir: Path) -> None:
        self.name, self.workdir = name, workdir
        self.probe = Probe()
        self.keep: Set[str] = set()
        self.figures: dict = {}
        self.running = False
        self.window_ended = 0.0  # (monotonic) the trace went on from there

    def results(self) -> Tuple[Set[str], dict]:
        """The tracer's keep set and figures, from its exchange folder."""
        with engine_errors("reading the tracer's results"):
            stream, _ = container(self.name).get_archive(EXCHANGE)
            result = b"".join(stream)
        with tarfile.open(fileobj=io.BytesIO(result)) as tar:
            tar.extractall(self.workdir)
        folder = self.workdir / EXCHANGE.lstrip("/")
        if (folder / "error").is_file() or not (folder / "done").is_file():
            reason = (folder / "error").read_text().strip() if (folder / "error").is_file() \
                else "no result"
            raise SlimError(f"tracing the run image failed: {reason}")
        keep = set((folder / "keep.txt").read_text().splitlines())
        return keep, json.loads((folder / "done").read_text())

    def snapshot(self) -> None:
        """The keep set so far (the tracer goes on), or the final one if the command exited."""
        if self.probe.ended == "exited":
            self.keep, self.figures = self.finish()
            return
        with engine_errors("asking the tracer for its keep set"):
            container(self.name).kill(signal="SIGUSR1")

        def poll(elapsed: float) -> Ending:
            if SNAPSHOT.search(logs(self.name)):
                return ("written", None)
            if not container_state(self.name)[0]:
                raise SlimError("the tracer stopped early: " + logs(self.name).strip()[-500:])
            return None

        if watch(poll, 300)[0] != "written":
            raise SlimError("the tracer wrote no keep set within 300 s")
        self.keep, self.figures = self.results()
        self.running, self.window_ended = True, time.monotonic()

    def finish(self) -> Tuple[Set[str], dict]:
        """Stop the command (if it still runs) and the tracer: the final keep set, figures. A
        tracer that ended on its own (its max_seconds, while a big image was made and checked;
        an error) has written its results or its error: no kill, which would fail."""
        with engine_errors("stopping the trace container"):
            traced = container(self.name)
            if traced.attrs["State"]["Running"]:
                traced.kill(signal="SIGTERM")
            traced.wait(timeout=300)
        self.running = False
        return self.results()


@contextlib.contextmanager
def tracing(run_id: str, config: Mapping, options: SlimOptions, workdir: Path
            ) -> Iterator[Trace]:
    """Trace the run image for the window (see Trace); its container is gone afterwards."""
    traced = Trace(f"docker-ros-slim-trace-{os.getpid()}-{int(time.time() * 1000)}", workdir)
    try:
        with engine_errors("creating the trace container"), signals_held():
            made = client().containers.create(**plan_trace_container(run_id, config, options,
                                                                     traced.name))
        exchange = io.BytesIO()
        with tarfile.open(fileobj=exchange, mode="w") as tar:
            tar.add(str(TRACER), arcname=f"{EXCHANGE[1:]}/slimtrace.py")
            spec = json.dumps(tracer_spec(config, options)).encode()
            info = tarfile.TarInfo(f"{EXCHANGE[1:]}/spec.json")
            info.size = len(spec)
            tar.addfile(info, io.BytesIO(spec))
        with engine_errors("starting the trace container"):
            made.put_archive("/", exchange.getvalue())
            made.start()

        def poll(elapsed: float) -> Ending:
            log = logs(traced.name)
            return trace_ending(log, *container_state(traced.name), options.expect)

        traced.probe = run_probes(traced.name, run_id, config, options, poll,
                                  options.continue_after,
                                  lambda: container_state(traced.name)[0])
        traced.snapshot()
        yield traced
    finally:
        remove_container(traced.name)


def filter_tar(source: IO[bytes], destination: IO[bytes], keep: Set[str]) -> Tuple[int, int]:
    """Copy the members of a `docker export` stream that are in keep; (kept, total)."""
    kept = total = 0
    written: Set[str] = set()
    with tarfile.open(fileobj=source, mode="r|") as src, \
            tarfile.open(fileobj=destination, mode="w|", format=tarfile.PAX_FORMAT) as dst:
        for member in src:
            total += 1
            path = member_path(member.name)
            if path not in keep:
                continue
            if member.islnk() and member_path(member.linkname) not in written:
                continue  # its first name was dropped: nothing to link to
            dst.addfile(member, src.extractfile(member) if member.isfile() else None)
            written.add(path)
            kept += 1
    return kept, total


class ChunkReader(io.RawIOBase):
    """A readable stream over an iterator of byte chunks (the SDK's container export)."""

    def __init__(self, chunks: Iterator[bytes]) -> None:
        self.chunks, self.rest = chunks, b""

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        while not self.rest:
            self.rest = next(self.chunks, b"")
            if not self.rest:
                return 0
        size = min(len(buffer), len(self.rest))
        buffer[:size], self.rest = self.rest[:size], self.rest[size:]
        return size


def imported_id(output: str) -> str:
    """The image ID in the Engine API's answer to an import (JSON lines, the last one's
    status)."""
    for line in reversed(output.strip().splitlines()):
        status = str(json.loads(line).get("status", ""))
        if status.startswith("sha256:"):
            return status
    raise SlimError(f"importing the slim image gave no image ID: {output.strip()[-300:]}")


def export_filtered(run_id: str, keep: Set[str], changes: Sequence[str]) -> Tuple[str, int, int]:
    """The export of a container of the run image, keep-filtered into a file, imported as an
    image with the run image's config (`changes`)."""
    with engine_errors("exporting the run image's files"), \
            tempfile.NamedTemporaryFile(prefix="docker-ros-slim-", suffix=".tar") as filtered:
        created = None
        try:
            with signals_held():
                created = client().containers.create(run_id)
            kept, total = filter_tar(io.BufferedReader(ChunkReader(created.export())),
                                     filtered, keep)
        finally:
            if created is not None:
                created.remove(force=True)
        filtered.flush()
        answer = client().api.import_image(src=filtered.name, changes=list(changes))
    return imported_id(str(answer)), kept, total


def apart(config: Mapping, options: SlimOptions) -> SlimOptions:
    """The options of the slim image's check: the traced run image's ROS_DOMAIN_ID (--env,
    else the image's, else 0) plus one. The traced container goes on meanwhile, and ROS 2
    discovery across the two would let a slim listener hear the traced talker and pass a slim
    image whose talker is broken; ROS 1 (a roscore in each container) does not care."""
    given = [e.split("=", 1)[1] for e in [*(config.get("Env") or []), *options.env]
             if e.startswith("ROS_DOMAIN_ID=")]
    traced = int(given[-1]) if given and given[-1].strip().isdigit() else 0
    env = [e for e in options.env if not e.startswith("ROS_DOMAIN_ID=")]
    return replace(options, env=(*env, f"ROS_DOMAIN_ID={(traced + 1) % 102}"))


def check(slim_id: str, config: Mapping, options: SlimOptions, reference: Probe) -> Probe:
    """Run the slim image as the run image was run (same command, env and window, in a ROS 2
    domain of its own: apart)."""
    name = f"docker-ros-slim-check-{os.getpid()}-{int(time.time() * 1000)}"
    options = apart(config, options)
    try:
        with engine_errors("starting the slim image"), signals_held():
            client().containers.run(slim_id, detach=True, name=name,
                                    environment=list(options.env))

        def poll(elapsed: float) -> Ending:
            return check_ending(elapsed, *container_state(name), reference,
                                lambda: logs(name), options.expect)

        return run_probes(name, slim_id, config, options, poll,
                          max(options.continue_after, reference.watched),
                          lambda: container_state(name)[0])
    finally:
        remove_container(name)


def made_and_checked(run_id: str, keep: Set[str], changes: Sequence[str], config: Mapping,
                     options: SlimOptions, reference: Probe
                     ) -> Tuple[str, int, int, float, float, List[str]]:
    """The slim image of keep, checked against the reference: its ID, files kept and in all,
    seconds to make and to check it, what differed (the image is removed on an exception)."""
    made_at = time.monotonic()
    slim_id, kept, total = export_filtered(run_id, keep, changes)
    checked_at = time.monotonic()
    try:
        diffs = compare_probes(reference, check(slim_id, config, options, reference), options)
    except BaseException:
        remove_quietly([slim_id], force=True)
        raise
    return slim_id, kept, total, checked_at - made_at, time.monotonic() - checked_at, diffs


def made_with_later_files(run_id: str, traced: Trace, changes: Sequence[str], config: Mapping,
                          options: SlimOptions) -> Tuple[str, int, int, float, float, List[str]]:
    """made_and_checked from the window's keep set; made again with the files a command still
    running opened meanwhile, if it opened any (the first image is removed then)."""
    made = made_and_checked(run_id, traced.keep, changes, config, options, traced.probe)
    if not traced.running:
        return made
    went_on = time.monotonic() - traced.window_ended
    try:
        keep, _ = traced.finish()
    except BaseException:
        remove_quietly([made[0]], force=True)
        raise
    if not keep - traced.keep:
        return made
    print(later_report(went_on, keep - traced.keep), flush=True)
    remove_quietly([made[0]], force=True)
    return made_and_checked(run_id, keep, changes, config, options, traced.probe)


@dataclass(frozen=True)
class SlimResult:
    ref: str
    platform: str
    seconds: float
    reused: bool


def slim_image(settings: Settings, platform: str, *, dry_run: bool = False) -> SlimResult:
    """Slim IMAGE_NAME:IMAGE_TAG (of one platform) into SLIM_IMAGE_NAME:SLIM_IMAGE_TAG."""
    began = time.monotonic()
    run_ref = target_ref(settings, "run", platform)
    slim_ref = target_ref(settings, "slim", platform)
    options = slim_options(settings)
    ignored = [option for option in options.ignored if option not in DEFAULT_IGNORED]
    if ignored:
        print("docker-ros slim: ignoring options that do not apply here: "
              + ", ".join(ignored), flush=True)
    if dry_run:
        print(f"[dry-run] slim: trace {run_ref} for at most {options.continue_after:g} s (until "
              f"no new file for {options.settle:g} s), keep what it uses, check and tag "
              f"{slim_ref}")
        return SlimResult(slim_ref, platform, 0.0, False)
    if platform != host_platform():
        raise SlimError(f"slimming a {platform} image on this {host_platform()} machine is not "
                        f"supported: run `docker-ros slim` on a {platform} runner")
    run = inspect_image(run_ref)
    if run is None:
        raise SlimError(f"run image {run_ref} not found: build it first (`docker-ros build`)")
    config = run["Config"]
    if settings.locked and not lock_path(settings).is_file():
        raise SlimError("LOCKED: docker-ros.lock not found: run `inv lock` first")
    wanted = lock_labels(settings, "run").get(LOCK_LABEL)
    if wanted and (config.get("Labels") or {}).get(LOCK_LABEL) != wanted:
        raise SlimError(f"LOCKED: run image {run_ref} was not built from this docker-ros.lock "
                        f"({wanted[:19]}...): build it with `--locked true` first")
    stamp = fingerprint(run["Id"], options)
    existing = inspect_image(slim_ref)
    if existing and (existing["Config"].get("Labels") or {}).get(LABEL_FINGERPRINT) == stamp:
        print(f"slim: {slim_ref} is up to date (made from {run_ref}, {run['Id'][7:19]})")
        return SlimResult(slim_ref, platform, time.monotonic() - began, True)
    print(f"==> docker-ros slim {run_ref} -> {slim_ref}", flush=True)
    changes = plan_changes(config, {LABEL_SOURCE: run["Id"], LABEL_FINGERPRINT: stamp})
    traced_at = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="docker-ros-slim-") as tmp, \
            tracing(run["Id"], config, options, Path(tmp)) as traced:
        reference, figures = traced.probe, traced.figures
        print(trace_report(time.monotonic() - traced_at, reference, figures, options),
              flush=True)
        if figures.get("missing"):
            raise SlimError(f"{run_ref} has no " + ", ".join(figures["missing"])
                            + ": fix or remove the option in SLIM_BUILD_ARGS or "
                            "ADDITIONAL_SLIM_BUILD_ARGS (nothing tagged)")
        if figures.get("overflow"):
            print("docker-ros slim: warning: the trace lost events (queue overflow); the check "
                  "below decides", flush=True)
        slim_id, kept, total, made_seconds, check_seconds, diffs = made_with_later_files(
            run["Id"], traced, changes, config, options)
    if diffs:
        remove_quietly([slim_id], force=True)
        stale = " (removed the stale " + slim_ref + ")" if existing else ""
        if existing:
            remove_quietly([slim_ref])
        raise SlimError(f"the slim image of {run_ref} does not behave like it, not tagged"
                        f"{stale}: " + "; ".join(diffs)
                        + ". Keep what is missing with --include-path in "
                        "ADDITIONAL_SLIM_BUILD_ARGS, or set ENABLE_SLIM=false")
    print(check_report(check_seconds, reference, options), flush=True)
    tag(slim_id, slim_ref)
    if existing and existing["Id"] != slim_id:
        # the slim image the tag left (a layer of its own, nothing shares it): gone unless
        # another tag or a container still uses it
        remove_quietly([existing["Id"]])
    print(size_report(run_ref, slim_ref, kept, total, made_seconds), flush=True)
    return SlimResult(slim_ref, platform, time.monotonic() - began, False)


def window_words(probe: Probe, options: SlimOptions) -> str:
    """How long COMMAND was watched, and why not longer."""
    if probe.ended == "exited":
        return f"COMMAND exited with {probe.exit_code} after {probe.watched:.1f} s"
    if probe.ended == "settled":
        expected = " and every --expect text was printed" if options.expect else ""
        return (f"COMMAND watched {probe.watched:.1f} s, until no new file was opened for "
                f"{options.settle:g} s{expected}")
    return f"COMMAND watched {probe.watched:.1f} s (--continue-after)"


def trace_report(seconds: float, reference: Probe, figures: Mapping, options: SlimOptions
                 ) -> str:
    """The trace in one line: its time, the window, what the tracer saw."""
    return (f"slim: trace {seconds:.1f} s: {window_words(reference, options)}; "
            f"{figures.get('traced', 0)} files opened (keep set "
            f"{figures.get('keep_seconds', 0):.1f} s)")


def later_report(seconds: float, added: Set[str]) -> str:
    """What COMMAND opened after the window, while the slim image was made and checked."""
    files = sorted(added)
    example = ", ".join(files[:3]) + (", ..." if len(files) > 3 else "")
    more = f"{len(files)} more file{'s' if len(files) > 1 else ''}"
    return (f"slim: COMMAND went on for {seconds:.1f} s after the window (while the slim image "
            f"was made and checked) and used {more} ({example}): made and checked again with "
            "them")


def check_report(seconds: float, reference: Probe, options: SlimOptions) -> str:
    """The functional check in one line."""
    behaviour = describe_exit(reference.exit_code, round(reference.watched, 1))
    return (f"slim: functional check {seconds:.1f} s passed (COMMAND {behaviour} in both; "
            f"{len(options.execs)} exec(s), {len(options.expect)} expectation(s))")


def size_report(run_ref: str, slim_ref: str, kept: int, total: int, seconds: float) -> str:
    run_size = image_size(run_ref)
    slim_size = image_size(slim_ref)
    ratio = run_size / slim_size if slim_size else 0.0
    return (
        f"slim: {run_ref} {run_size / 1e6:.0f} MB -> {slim_ref} {slim_size / 1e6:.0f} MB "
        f"(ratio {ratio:.1f}x, {100 * (1 - slim_size / run_size) if run_size else 0:.0f} % "
        f"smaller); {kept} of {total} files kept (image made in {seconds:.1f} s)"
    )
