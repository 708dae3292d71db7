"""Slim's probe: run COMMAND in the run image and in the slim image, and compare what each did."""

from __future__ import annotations

import os
import re
import shlex
import time
from dataclasses import dataclass, field
from typing import Callable, List, Mapping, Optional, Sequence, Set, Tuple

from docker_ros.host.engine import (
    container,
    engine_errors,
    logs,
    run_once,
)
from docker_ros.host.slimoptions import SlimError, SlimOptions

EXITED = re.compile(r"docker-ros slimtrace: command exited with status (-?\d+)")
SETTLED = re.compile(r"docker-ros slimtrace: traced files settled after ([\d.]+) s")
TRACER_LINE = re.compile(r"^docker-ros slimtrace: .*\n?", re.MULTILINE)
# A DOCKER_UID/GID probe of the docker-ros entrypoint (as docker-ros's own SLIM_BUILD_ARGS do).
PROBE_UID = "23456"
PROBE_USER = "dockerslimprobe"
INITS = ("tini", "tini-static", "docker-init", "dumb-init")
# Output lines that mean something went wrong; those in the slim run but not the run image's
# (digits, hex and UUIDs normalized) fail the check: a node may die while roslaunch runs on.
TROUBLE = re.compile(
    r"error|traceback|exception|not found|no such file|cannot |can't|could not|has died|"
    r"segmentation fault|core dumped|permission denied|fatal",
    re.IGNORECASE,
)


# ------------------------------------------------------------------------------ pure plans
def exec_prefix(entrypoint: Sequence[str]) -> List[str]:
    """The entrypoint without its init (a `docker exec` process is not PID 1)."""
    items = list(entrypoint)
    if items and os.path.basename(items[0]) in INITS:
        items = items[items.index("--") + 1:] if "--" in items else items[1:]
    return items


def maps_users(entrypoint: Sequence[str]) -> bool:
    return any(item.endswith("docker-ros/entrypoint.sh") for item in entrypoint)


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


def window_words(probe: Probe, options: SlimOptions) -> str:
    """How long COMMAND was watched, and why not longer."""
    if probe.ended == "exited":
        return f"COMMAND exited with {probe.exit_code} after {probe.watched:.1f} s"
    if probe.ended == "settled":
        expected = " and every --expect text was printed" if options.expect else ""
        return (f"COMMAND watched {probe.watched:.1f} s, until no new file was opened for "
                f"{options.settle:g} s{expected}")
    return f"COMMAND watched {probe.watched:.1f} s (--continue-after)"


def check_report(seconds: float, reference: Probe, options: SlimOptions) -> str:
    """The functional check in one line."""
    behaviour = describe_exit(reference.exit_code, round(reference.watched, 1))
    return (f"slim: functional check {seconds:.1f} s passed (COMMAND {behaviour} in both; "
            f"{len(options.execs)} exec(s), {len(options.expect)} expectation(s))")
