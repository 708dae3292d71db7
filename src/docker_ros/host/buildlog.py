"""BuildKit's plain log: each docker-ros step folded for the CI we run in, and what a failed
build's log says (the step that failed, a lost engine, an interruption, a network it could not
reach, an image a builder could not see). Pure functions of the log's lines."""

from __future__ import annotations

import re
import time
from typing import IO, Dict, Iterator, List, Mapping, Sequence, Tuple

from docker_ros.core.display import ref_host
from docker_ros.in_image.steps import IMAGE_STEPS, STEPS

STEP_ERROR = re.compile(r"docker-ros (\w+): (.*)")
# our steps' Starting/Finished lines (colcon's own, `Starting >>> <package>`, look the same:
# folded too, they opened a group per package and closed the step's early)
_FOLDED = "|".join((*STEPS, *IMAGE_STEPS))
STEP_START = re.compile(rf"Starting >>> ({_FOLDED})$")
STEP_END = re.compile(rf"(Finished|Failed  ) <<< ({_FOLDED}) \[")
# buildx's own lines (not a build step's output, `#N ...`) when the engine went away mid-build
ENGINE_LOST = re.compile(
    r"code = Unavailable|error reading from server: EOF|transport is closing|"
    r"Cannot connect to the Docker daemon|docker\.sock: connect: |connection reset by peer",
)
# a build step of a stage; bake puts the target first: `#7 [run build 1/1]`
VERTEX = re.compile(r"#(\d+) \[(?:[\w-]+ )?([\w-]+) \d+/\d+\]")
# A build step's words for a network it cannot reach (apt, pip/urllib, git/curl).
NO_NETWORK = re.compile(
    r"Temporary failure (?:resolving '[^']*'|in name resolution)|Could not resolve host:? \S+|"
    r"Network is unreachable|Failed to establish a new connection|Could not connect to \S+")


def fold_markers(environ: Mapping[str, str]) -> Tuple[str, str]:
    """Start/end templates for collapsible log sections of the CI we run in ({id}, {title})."""
    if environ.get("GITHUB_ACTIONS"):
        return "::group::{title}", "::endgroup::"
    if environ.get("GITLAB_CI"):
        return (
            "\x1b[0Ksection_start:{time}:{id}[collapsed=true]\r\x1b[0K{title}",
            "\x1b[0Ksection_end:{time}:{id}\r\x1b[0K",
        )
    return "", ""  # plain log: the step's own Starting/Finished lines are the markers


def fold(template: str, title: str) -> str:
    ident = re.sub(r"[^a-z0-9_]", "_", title.lower())
    return template.format(title=title, id=ident, time=int(time.time()))


def stream_build(lines: Iterator[str], out: IO[str], environ: Mapping[str, str]) -> List[str]:
    """Copy the build log to out, each docker-ros step folded; return the step error lines."""
    start, end = fold_markers(environ)
    errors: List[str] = []
    opened: Dict[str, str] = {}  # build step (`#N`) -> our step running in it
    for line in lines:
        vertex = line.split(" ", 1)[0] if line.startswith("#") else ""
        begun = STEP_START.search(line)
        if begun and vertex not in opened:  # (in our step: colcon's package of that name)
            opened[vertex] = begun.group(1)
            if start:
                out.write(fold(start, begun.group(1)) + "\n")
        out.write(line)
        ended = STEP_END.search(line)
        if ended and opened.get(vertex) == ended.group(2):
            del opened[vertex]
            if end:
                out.write(fold(end, ended.group(2)) + "\n")
        failed = STEP_ERROR.search(line)
        if failed and "docker-ros" in line:
            errors.append(f"{failed.group(1)}: {failed.group(2).strip()}")
        out.flush()
    return errors


def failed_step(lines: Sequence[str]) -> Tuple[str, str]:
    """(stage, step) of the last docker-ros step error in a BuildKit plain log, or ("", "")."""
    stages: Dict[str, str] = {}
    found = ("", "")
    for line in lines:
        vertex = VERTEX.match(line)
        if vertex:
            stages[vertex.group(1)] = vertex.group(2)
        failed = STEP_ERROR.search(line)
        number = re.match(r"#(\d+) ", line)
        if failed and number and number.group(1) in stages:
            found = (stages[number.group(1)], failed.group(1))
    return found


def engine_lost(lines: Sequence[str]) -> str:
    """buildx's line saying that the connection to the Docker engine was lost (the daemon
    stopped or restarted mid-build), '' when the log shows none. A build step's own output
    (`#N ...`, e.g. a refused git connection) never counts."""
    for line in reversed(lines):
        if not line.startswith("#") and ENGINE_LOST.search(line):
            return line.strip()
    return ""


def cancelled(lines: Sequence[str]) -> bool:
    """Whether buildx stopped because it was interrupted (SIGINT reached it, maybe only it):
    its last error is the cancellation itself (`ERROR: failed to solve: Canceled: context
    canceled`); when one target of several fails, buildx names that failure instead."""
    own = [line for line in lines if line.startswith(("ERROR", "error:"))]
    return bool(own) and "context canceled" in own[-1]


def tagged_in_log(lines: Sequence[str], ref: str) -> bool:
    """Whether BuildKit's log says it named an image ref (`naming to docker.io/library/x:1
    done`: a name without registry as BuildKit writes it), e.g. the target of a bake run that
    finished before another failed."""
    full = ref if ref_host(ref) else f"docker.io/{ref if '/' in ref else 'library/' + ref}"
    return any(f"naming to {name} done" in line for line in lines for name in (full, ref))


def failure_reason(lines: Sequence[str], errors: Sequence[str], network: str = "",
                   unseen: Sequence[str] = ()) -> str:
    """How a failed buildx run ended, for the one-line message (network: BUILD_NETWORK;
    unseen: see unseen_hint)."""
    lost = engine_lost(lines)
    if lost:
        return (f"failed: the connection to the Docker engine was lost ({lost}); nothing was "
                "tagged, so rerunning is safe once `docker info` answers")
    reason = f"failed in step {errors[-1]}" if errors else "failed (see the BuildKit error above)"
    return reason + network_hint(lines, network) + unseen_hint(lines, unseen)


def unseen_hint(lines: Sequence[str], unseen: Sequence[str]) -> str:
    """What to do when BuildKit could not resolve an image that only the local engine holds
    (unseen: such images, given for a builder with a BuildKit of its own, which sees no
    engine's images and looked for it in a registry): '' for any other failure."""
    failed = [line for line in lines if "failed to resolve source metadata for" in line]
    ref = next((r for r in unseen if any(f"{r}: failed to resolve" in line or f"/{r}:" in line
                                         for line in failed)), "")
    if not ref:
        return ""
    return (f"; {ref} is an image of the local engine, which a builder with a BuildKit of its "
            "own (docker-container, remote) does not see: push it to a registry that builder "
            "reaches (`--driver-opt network=host` for one on 127.0.0.1) and name it there, or "
            "build with the engine's own builder (BUILDER unset or a docker context)")


def failed_output(lines: Sequence[str]) -> List[str]:
    """The output of the build steps that failed: every `#N ...` line of a vertex N that
    ended with `#N ERROR` (bake: one per failed target)."""
    failed = {line.split(" ", 1)[0] for line in lines if re.match(r"#\d+ ERROR", line)}
    return [line for line in lines if line.split(" ", 1)[0] in failed]


def network_hint(lines: Sequence[str], network: str) -> str:
    """What to do when a failed build step could not reach the network (its output says so:
    apt, pip, git, curl, rosdep): '' when it did not say so, or the build has the host's
    network. On an engine whose containers have no outbound NAT (the Engine 26 of
    scripts/setup.sh: dockerd --iptables=false) apt only warns that it could not fetch its
    lists, then finds no package, so the step's own words may name another cause."""
    if network == "host":
        return ""
    seen = next((m.group(0) for m in map(NO_NETWORK.search, failed_output(lines)) if m), "")
    if not seen:
        return ""
    if network == "none":
        return f"; the step could not reach the network ({seen}): BUILD_NETWORK is none"
    return (f"; the step could not reach the network ({seen}): on an engine without outbound "
            "NAT (dockerd --iptables=false, e.g. the Engine 26 of scripts/setup.sh) set "
            "BUILD_NETWORK=host")


# a RUN, COPY or ADD of a stage (bake: the target first), not the context or a FROM
STAGE_STEP = re.compile(r"^#(\d+) \[(?:[\w-]+ )?[\w-]+ \d+/\d+\] (?:RUN|COPY|ADD) ")


def cached_steps(lines: Sequence[str]) -> Tuple[int, int]:
    """(from the cache, in all) of the stage steps of a buildx run's plain log. A step BuildKit
    CANCELED in a build that succeeded counts as cached: it cancels a step's cache load when a
    later step's result is found first."""
    steps = {m.group(1) for m in map(STAGE_STEP.match, lines) if m}
    cached = {line.split(" ", 1)[0][1:] for line in lines
              if re.match(r"#\d+ (CACHED|CANCELED)", line)}
    return len(steps & cached), len(steps)
