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
import tarfile
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import IO, Any, Dict, Iterator, List, Mapping, Sequence, Set, Tuple

from docker_ros.core.labels import ours, parse_labels
from docker_ros.core.loading import host_platform
from docker_ros.core.settings import Settings
from docker_ros.host.buildcontext import PACKAGE_DIR
from docker_ros.host.engine import (
    client,
    container,
    container_state,
    engine_errors,
    image_size,
    inspect_image,
    logs,
    remove_container,
    remove_quietly,
    signals_held,
    tag,
)
from docker_ros.host.labels import OCI, title
from docker_ros.host.lockpins import LOCK_LABEL, lock_labels, lock_path
from docker_ros.host.refs import target_ref
from docker_ros.host.slimoptions import (
    DEFAULT_IGNORED,
    DEFAULT_PATHS,
    ESSENTIAL_EXECUTABLES,
    ESSENTIAL_PATHS,
    SlimError,
    SlimOptions,
    slim_options,
)
from docker_ros.host.slimprobe import (
    Ending,
    Probe,
    check_ending,
    check_report,
    compare_probes,
    run_probes,
    trace_ending,
    watch,
    window_words,
)

TRACER = PACKAGE_DIR / "in_image" / "slimtrace.py"
# what the tracer imports, copied beside it (the run image has no docker_ros package)
TRACER_FILES = (TRACER, PACKAGE_DIR / "in_image" / "slimelf.py")
EXCHANGE = "/docker-ros-slim"  # the tracer and its results inside the trace container
LABEL_SOURCE = ours("slim.source")
LABEL_FINGERPRINT = ours("slim.fingerprint")
SNAPSHOT = re.compile(r"docker-ros slimtrace: keep set written, tracing on")


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
    key = json.dumps([run_id, repr(options), *(f.read_text() for f in TRACER_FILES)])
    return hashlib.sha256(key.encode()).hexdigest()[:24]


def member_path(name: str) -> str:
    """A tar member name of `docker export` as an absolute path."""
    name = name[2:] if name.startswith("./") else name.lstrip("/")
    return "/" + name.rstrip("/")


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
            for module in TRACER_FILES:
                tar.add(str(module), arcname=f"{EXCHANGE[1:]}/{module.name}")
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
    # the run image's labels (its OCI ones: the slim image is made of the same sources), with
    # the slim image's own title (labels.image_labels) and where it comes from
    own = {f"{OCI}.title": title(settings, "slim"), **parse_labels(settings.labels)}
    changes = plan_changes(config, {**own, LABEL_SOURCE: run["Id"], LABEL_FINGERPRINT: stamp})
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


def size_report(run_ref: str, slim_ref: str, kept: int, total: int, seconds: float) -> str:
    run_size = image_size(run_ref)
    slim_size = image_size(slim_ref)
    ratio = run_size / slim_size if slim_size else 0.0
    return (
        f"slim: {run_ref} {run_size / 1e6:.0f} MB -> {slim_ref} {slim_size / 1e6:.0f} MB "
        f"(ratio {ratio:.1f}x, {100 * (1 - slim_size / run_size) if run_size else 0:.0f} % "
        f"smaller); {kept} of {total} files kept (image made in {seconds:.1f} s)"
    )
