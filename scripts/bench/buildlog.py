"""Running the real CLI and docker, and what their output says: timings, compiled units,
cached layers, dependency RUN overlap, image sizes. One Scenario per measured row."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

from bench import REPO, BenchError
from bench.workspace import COMPILE_MARK, DEV_IMAGE, IMAGE
from docker_ros.core.settings import FIELDS, env_name
from docker_ros.host.build import UP_TO_DATE
from docker_ros.host.buildlog import cached_steps

# bake puts the target before the stage: `#12 [dev upstream 2/2] RUN ...`
UPSTREAM_VERTEX = re.compile(r"^#(\d+) \[(?:\S+ )?upstream .*clone --imports-only")
DEPENDENCIES_RUN = re.compile(r"^\[(?:\S+ )?dependencies-(dev|run) .*\] RUN ")
COMPILED = re.compile(re.escape(COMPILE_MARK) + r" (\S+?\.cpp)")
# the first vertex of every buildx invocation (vertex numbers restart there)
INVOCATION = re.compile(r"^#1 \[internal\] load (build|local bake) definition")
VERTEX = re.compile(r"^#(\d+) (\[.*)")
VERTEX_STATE = re.compile(r"^#(\d+) (CACHED|DONE)")
STAGE_STEP = re.compile(r"^\[(?:\S+ )?[\w.-]+ \d+/\d+\] ")  # `[run build 1/1] RUN ...`
STAMPED = re.compile(r"colcon: (\d+) of (\d+) source files changed")
SUMMARY = re.compile(r"^(\S+)\s+(\S+)\s+\S+\s+(?:\d+ MB|-)\s+([\d.]+) s\s*$")


@dataclass
class Scenario:
    """One measured row of the table."""

    name: str
    seconds: float
    compiled: List[str] = field(default_factory=list)
    deps_layers: str = "-"  # reused | rebuilt | - (not an image build)
    imports: str = "-"  # the image's vcs import: cached | ran | - (not an image build)
    units: int = 0  # translation units of the workspace (0: the main workspace's)
    changed_sources: str = "-"  # what the colcon step took for changed ("3/140"), - if not run
    check: str = "-"  # OK | FAIL | -
    detail: str = ""
    ratio_cold: Optional[float] = None
    ratio_baseline: Optional[float] = None
    ratio_limit: Optional[float] = None
    deps_overlap: Optional[float] = None  # seconds both dependency RUNs ran at once
    image_seconds: Dict[str, float] = field(default_factory=dict)
    load1: float = 0.0
    steps: int = 0  # Dockerfile instructions BuildKit resolved (`[stage n/m]` vertices)
    ran: List[Tuple[str, float]] = field(default_factory=list)  # steps run, not cached: seconds



def clean_environ() -> Dict[str, str]:
    """The caller's environment without docker-ros settings (they would beat the .env)."""
    names = {env_name(n) for n in FIELDS}
    return {k: v for k, v in os.environ.items() if k not in names}


def docker(*args: str, timeout: int = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["docker", *args], capture_output=True, text=True, timeout=timeout)


def image_id(ref: str) -> str:
    return docker("image", "inspect", "--format", "{{.Id}}", ref).stdout.strip()


def image_mb(ref: str) -> float:
    out = docker("image", "inspect", "--format", "{{.Size}}", ref).stdout.strip()
    return int(out or 0) / 1e6


def resolve_keys(base_image: str, keys: Sequence[str]) -> Dict[str, List[str]]:
    """Resolve rosdep keys offline in a container of the base image: key -> apt packages."""
    found: Dict[str, List[str]] = {}
    for key in keys:
        argv = ["docker", "run", "--rm", "--network", "none", "--entrypoint", "sh", base_image,
                "-c", 'rosdep update >/dev/null 2>&1; exec rosdep resolve "$1"', "sh", key]
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=300)
        packages = [w for line in proc.stdout.splitlines() if not line.startswith("#")
                    for w in line.split()]
        if proc.returncode != 0 or not packages:
            raise BenchError(
                f"rosdep key '{key}' does not resolve offline in {base_image}: "
                f"{(proc.stderr or proc.stdout).strip()} (choose another key, see --help)"
            )
        found[key] = packages
    return found


def run_cli(project: Path, log: Path, *, verbose: bool, args: Sequence[str] = (),
            timed: Optional[List[Tuple[float, str]]] = None,
            task: str = "build", extra_env: Optional[Dict[str, str]] = None
            ) -> tuple[float, str]:
    """`python -m docker_ros TASK ARGS` in project, as a user runs it; (seconds, output).
    timed: receives each output line with the wall time it arrived."""
    argv = [sys.executable, "-m", "docker_ros", task, *args]
    env = {**clean_environ(), **(extra_env or {})}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO / "src"), env.get("PYTHONPATH")]))
    began = time.monotonic()
    proc = subprocess.Popen(argv, cwd=project, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, bufsize=1)
    assert proc.stdout is not None
    lines: List[str] = []
    with log.open("a") as out:
        out.write(f"\n===== {shlex.join(argv)} (cwd {project})\n")
        for line in proc.stdout:
            lines.append(line)
            if timed is not None:
                timed.append((time.monotonic(), line))
            out.write(line)
            if verbose:
                sys.stdout.write(line)
    code = proc.wait()
    seconds = time.monotonic() - began
    if code != 0:
        tail = "".join(lines[-25:])
        raise BenchError(f"docker-ros {task} failed (exit code {code}); log: {log}\n{tail}")
    return seconds, "".join(lines)


def steps_resolved(output: str) -> int:
    """The stage steps BuildKit resolved (cached or run) in the builds of output, counted per
    buildx invocation by the tool's own reading of a build log (buildlog.cached_steps): what a
    rebuild walks through however little it does, so that growth of the Dockerfile shows up as
    a number."""
    runs: List[List[str]] = [[]]
    for line in output.splitlines():
        if INVOCATION.match(line) and runs[-1]:
            runs.append([])
        runs[-1].append(line)
    return sum(cached_steps(run)[1] for run in runs)


VERTEX_DONE = re.compile(r"^#(\d+) DONE ([\d.]+)s")


def steps_run(output: str) -> List[Tuple[str, float]]:
    """The stage steps BuildKit ran (not cached) in the builds of output, with the seconds its
    log gives each (`#42 DONE 5.5s`), named `[target stage n/m] INSTRUCTION` (its keyword)."""
    ran: List[Tuple[str, float]] = []
    names: Dict[str, str] = {}
    for line in output.splitlines():
        if INVOCATION.match(line):
            names = {}
        vertex = VERTEX.match(line)
        if vertex and STAGE_STEP.match(vertex.group(2)):
            names[vertex.group(1)] = vertex.group(2)
        done = VERTEX_DONE.match(line)
        if done and done.group(1) in names:
            head, _, rest = names.pop(done.group(1)).partition("] ")
            if rest.split()[0] != "FROM":  # (an image's metadata, no work)
                ran.append((f"{head}] {rest.split()[0]}", float(done.group(2))))
    return ran


FROM_LINE = re.compile(r"^FROM\s", re.MULTILINE | re.IGNORECASE)


def stage_count(dockerfile: Path) -> int:
    """The stages of a Dockerfile (its FROM lines)."""
    return len(FROM_LINE.findall(dockerfile.read_text()))


def startup_seconds(*argv: str, runs: int = 5) -> float:
    """The best of runs wall times of a command that only starts and answers (`--help`)."""
    best = float("inf")
    for _ in range(runs):
        began = time.monotonic()
        subprocess.run(argv, capture_output=True, check=True, env=clean_environ())
        best = min(best, time.monotonic() - began)
    return best


def compiled_units(output: str) -> List[str]:
    """Translation units the build compiled (each source prints a #pragma message)."""
    return sorted(set(COMPILED.findall(output)))


def dependency_layers(output: str) -> str:
    """'rebuilt' when a dependencies-{dev,run} RUN executed, 'reused' when all came from cache,
    'kept' when the images were up to date (BuildKit not started: host/unchanged.py).
    Vertex numbers restart with every buildx invocation."""
    names: Dict[str, str] = {}
    cached: Dict[str, bool] = {}
    ran = False
    seen = False
    for line in output.splitlines():
        if INVOCATION.match(line):
            names, cached = {}, {}
            continue
        match = VERTEX.match(line)
        if match:
            names[match.group(1)] = match.group(2)
            continue
        match = VERTEX_STATE.match(line)
        if not match or match.group(1) not in names:
            continue
        name = names[match.group(1)]
        if not DEPENDENCIES_RUN.match(name):
            continue
        seen = True
        if match.group(2) == "CACHED":
            cached[match.group(1)] = True
        elif not cached.get(match.group(1)):
            ran = True
    if not seen:
        return "kept" if UP_TO_DATE in output else "?"
    return "rebuilt" if ran else "reused"


def dependency_overlap(timed: Sequence[Tuple[float, str]]) -> Optional[float]:
    """Seconds during which the dependencies-dev and dependencies-run RUNs both ran, or None
    when either came from cache. Each RUN's span ends when its `DONE <s>` line arrived and
    began that many seconds earlier: buildx's plain output holds back the log lines of a vertex
    while another one prints, so their arrival times do not tell when it started. (With bake a
    stage both targets use is one vertex per target: the one that ran counts.)"""
    names: Dict[str, str] = {}
    spans: Dict[str, Tuple[float, float]] = {}  # flavour -> (start, end)
    for at, line in timed:
        if INVOCATION.match(line):
            names = {}
        match = VERTEX.match(line)
        if match:
            flavour = DEPENDENCIES_RUN.match(match.group(2))
            if flavour:
                names[match.group(1)] = flavour.group(1)
            continue
        done = re.match(r"^#(\d+) DONE ([\d.]+)s", line)
        if done and done.group(1) in names:
            spans[names[done.group(1)]] = (at - float(done.group(2)), at)
    if set(spans) != {"dev", "run"}:
        return None
    return max(0.0, min(spans["dev"][1], spans["run"][1]) - max(spans["dev"][0], spans["run"][0]))


def imports_state(output: str) -> str:
    """'ran' when the image's vcs import (upstream stage) ran in any buildx invocation of the
    build (dev and run share it: the second finds the first's), else 'cached'."""
    seen: Dict[str, bool] = {}  # vertex -> cached, per invocation
    ran = False
    for line in output.splitlines():
        if INVOCATION.match(line):
            ran = ran or any(not cached for cached in seen.values())
            seen = {}
            continue
        match = UPSTREAM_VERTEX.match(line)
        if match:
            seen.setdefault(match.group(1), False)
        state = VERTEX_STATE.match(line)
        if state and state.group(1) in seen and state.group(2) == "CACHED":
            seen[state.group(1)] = True
    ran = ran or any(not cached for cached in seen.values())
    return "ran" if ran else "cached"


def changed_sources(output: str) -> str:
    """The colcon step's own count of changed source files (it re-stamps those)."""
    found = STAMPED.findall(output)
    return "/".join(found[-1]) if found else "-"


def image_seconds(output: str) -> Dict[str, float]:
    """Per-image build times from the CLI's summary table."""
    found: Dict[str, float] = {}
    for line in output.splitlines():
        match = SUMMARY.match(line.strip())
        if match and f"{match.group(1)}:{match.group(2)}" in (IMAGE, DEV_IMAGE):
            target = "dev" if f"{match.group(1)}:{match.group(2)}" == DEV_IMAGE else "run"
            found[target] = float(match.group(3))
    return found


def run_output(ref: str, *command: str) -> str:
    """Run ref (its default command, or command) through its entrypoint; stdout+stderr."""
    proc = subprocess.run(["docker", "run", "--rm", ref, *command], capture_output=True,
                          text=True, timeout=300)
    return (proc.stdout + proc.stderr).strip()


def installed(ref: str, packages: Sequence[str]) -> List[str]:
    """Which of packages are installed in ref."""
    argv = ["docker", "run", "--rm", "--entrypoint", "dpkg-query", ref, "-W",
            "-f=${Package} ${db:Status-Status}\n", *packages]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    return [line.split()[0] for line in proc.stdout.splitlines() if line.endswith(" installed")]


def load1() -> float:
    return os.getloadavg()[0]
