#!/usr/bin/env python3
"""Benchmark docker-ros image builds (issue 5, "Fast rebuilds"): figures, never assertions.

Generates a workspace of N C++ packages (cmake build type, chains of dependent shared
libraries, one rosdep key), then in ONE run and strictly one after the other builds it with the
real CLI (`python -m docker_ros build`, TARGET=dev,run from the workspace's .env) and times:

  1   cold build (bench images removed; the workspace is new to the engine: a run id in its
      additional files and new cache mount ids. Nothing is pruned: the engine is shared, so
      the base image's prepared layer and the apt download cache may be warm)
  2   no-change rebuild
  3   one-file change in the LAST package (nothing depends on it)
  B   baseline: what the original docker-ros does after that change, a full `colcon build` of
      the workspace from scratch, in a fresh container of the dev image
  3b  one-file change in the FIRST package (others depend on it)
  F   BuildKit floor: a cached bake of two trivial targets (what building two images costs
      here whatever they hold; scenario 3 is also set against L plus F)
  4   one added apt dependency (a <depend> on another rosdep key)
  5   dev and run image sizes
  6   imports: a second workspace whose N packages come through .repos from a local git
      server (git daemon on the loopback, BUILD_NETWORK=host) plus one package of its own:
      cold build, then one .cpp changed in its own package (to set against 3: the same edit
      with every package in the repository), then the .repos file touched (re-import)
  7   lean run image (ENABLE_LEAN_RUN_IMAGE, run target, tag `lean`) after scenario 4: its
      size over the base against the default run image's, every node run in it; then 7b, one
      .cpp changed in the last package, rebuilt lean (against the physical limit too)

and checks while measuring that the run image runs the changed code. Prints one table;
--json writes the figures to a file. Timings are wall-clock and as noisy as the machine.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import tempfile
import textwrap
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

REPO = Path(__file__).resolve().parents[1]
if str(REPO / "src") not in sys.path:
    sys.path.insert(0, str(REPO / "src"))

import docker_ros.baseimage as baseimage  # noqa: E402
from docker_ros.settings import FIELDS, env_name  # noqa: E402

IMAGE = "docker-ros-bench/ws:latest"
DEV_IMAGE = "docker-ros-bench/ws:latest-dev"
IMPORTS_IMAGE = "docker-ros-bench/imports:latest"
SEPARATE_IMAGE = "docker-ros-bench/separate:latest"
WARM_IMAGE = "docker-ros-bench/warm-up:latest"
LEAN_IMAGE = "docker-ros-bench/ws:lean"
FLOOR_IMAGE = "docker-ros-bench/floor:latest"
LEAN = ("--target", "run", "--image-tag", "lean", "--set", "ENABLE_LEAN_RUN_IMAGE=true")
IMPORTS_REPO = "bench_upstream"
# bake puts the target before the stage: `#12 [dev upstream 2/2] RUN ...`
UPSTREAM_VERTEX = re.compile(r"^#(\d+) \[(?:\S+ )?upstream .*clone --imports-only")
DEPENDENCIES_RUN = re.compile(r"^\[(?:\S+ )?dependencies-(dev|run) .*\] RUN ")
DEFAULT_BASE_IMAGE = "docker-ros/ros1:bookworm"
WS = "/docker-ros/ws"
COMPILE_MARK = "docker-ros-bench compiles"
COMPILED = re.compile(re.escape(COMPILE_MARK) + r" (\S+?\.cpp)")
# the first vertex of every buildx invocation (vertex numbers restart there)
INVOCATION = re.compile(r"^#1 \[internal\] load (build|local bake) definition")
VERTEX = re.compile(r"^#(\d+) (\[.*)")
VERTEX_STATE = re.compile(r"^#(\d+) (CACHED|DONE)")
STAMPED = re.compile(r"colcon: (\d+) of (\d+) source files changed")
SUMMARY = re.compile(r"^(\S+)\s+(\S+)\s+\S+\s+(?:\d+ MB|-)\s+([\d.]+) s\s*$")

DESCRIBE_CPP = """\
// {name}: what the package is (the one-file changes edit kMark).
#include <algorithm>
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "{name}/{name}.hpp"
{upstream_include}
#pragma message("{mark} {name}/src/describe.cpp")

namespace {name} {{
namespace {{
const char* const kMark = "original";

template <typename T, int K>
struct Stage {{
  static std::string render(const std::vector<T>& values) {{
    std::map<T, int> counts;
    for (const T& value : values) counts[value] += K;
    std::vector<std::pair<T, int>> sorted(counts.begin(), counts.end());
    std::sort(sorted.begin(), sorted.end(),
              [](const std::pair<T, int>& a, const std::pair<T, int>& b) {{
                return a.second > b.second;
              }});
    std::ostringstream out;
    for (const auto& entry : sorted) out << entry.first << ':' << entry.second << ' ';
    return out.str() + Stage<T, K - 1>::render(values);
  }}
}};
template <typename T>
struct Stage<T, 0> {{
  static std::string render(const std::vector<T>&) {{ return std::string(); }}
}};
}}  // namespace

std::string describe() {{
  std::string own = std::string("{name}[") + kMark + "]";
  std::regex pattern("([a-z_]+)_([0-9]+)\\\\[([a-z-]+)\\\\]");
  std::smatch match;
  if (!std::regex_search(own, match, pattern)) own += "?";
  const std::string noise = Stage<int, {depth}>::render({{1, 2, 3}}) +
                            Stage<std::string, {depth}>::render({{"a", "b"}});
  own += noise.empty() ? "!" : "";
  return own{upstream_call};
}}

}}  // namespace {name}
"""

CHECKSUM_CPP = """\
// {name}: a checksum over template instantiations (compile-time weight).
#include <algorithm>
#include <iostream>
#include <map>
#include <numeric>
#include <sstream>
#include <string>
#include <vector>

#include "{name}/{name}.hpp"

#pragma message("{mark} {name}/src/checksum.cpp")

namespace {name} {{
namespace {{
template <typename T, int K>
struct Fold {{
  static T apply(std::vector<T> values) {{
    std::sort(values.begin(), values.end());
    std::map<int, T> buckets;
    for (std::size_t i = 0; i < values.size(); ++i) buckets[static_cast<int>(i) % K] += values[i];
    std::ostringstream out;
    for (const auto& bucket : buckets) out << bucket.first << '=' << bucket.second << ';';
    values.push_back(static_cast<T>(out.str().size()));
    return std::accumulate(values.begin(), values.end(), T()) + Fold<T, K - 1>::apply(values);
  }}
}};
template <typename T>
struct Fold<T, 0> {{
  static T apply(const std::vector<T>&) {{ return T(); }}
}};
}}  // namespace

long checksum() {{
  const double d = Fold<double, {depth}>::apply({{1.5, 2.5}});
  const long l = Fold<long, {depth}>::apply({{3, 4, 5}});
  const float f = Fold<float, {depth}>::apply({{0.5f}});
  if (d < 0) std::cerr << "negative checksum" << std::endl;
  return l + static_cast<long>(d) + static_cast<long>(f);
}}

}}  // namespace {name}
"""

MAIN_CPP = """\
#include <iostream>

#include "{name}/{name}.hpp"

#pragma message("{mark} {name}/src/main.cpp")

int main() {{
  std::cout << {name}::describe() << " checksum " << {name}::checksum() << std::endl;
  return 0;
}}
"""

HEADER = """\
#pragma once
#include <string>

namespace {name} {{
std::string describe();
long checksum();
}}  // namespace {name}
"""


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


class BenchError(Exception):
    pass


# ----------------------------------------------------------------------------------------------
# the workspace


def package_name(index: int) -> str:
    return f"bench_pkg_{index:02d}"


def upstream(index: int, chain: int) -> Optional[int]:
    """Package i depends on package i-1 unless it starts a chain (i % chain == 0)."""
    return index - 1 if index % chain else None


def chain_end(index: int, count: int, chain: int) -> int:
    """The last package of the dependency chain that index belongs to."""
    end = index
    while end + 1 < count and upstream(end + 1, chain) == end:
        end += 1
    return end


def write_package(root: Path, index: int, *, chain: int, depth: int, keys: Sequence[str]) -> None:
    name = package_name(index)
    up = upstream(index, chain)
    up_name = package_name(up) if up is not None else None
    path = root / name
    (path / "src").mkdir(parents=True)
    (path / "include" / name).mkdir(parents=True)
    depends = ([up_name] if up_name else []) + list(keys)
    (path / "package.xml").write_text(
        '<?xml version="1.0"?>\n<package format="3">\n'
        f"  <name>{name}</name>\n  <version>0.1.0</version>\n"
        f"  <description>{name}: docker-ros benchmark package</description>\n"
        '  <maintainer email="bench@docker-ros.invalid">docker-ros bench</maintainer>\n'
        "  <license>MIT</license>\n"
        + "".join(f"  <depend>{d}</depend>\n" for d in depends)
        + "  <export><build_type>cmake</build_type></export>\n</package>\n"
    )
    find = f"find_package({up_name} REQUIRED)\n" if up_name else ""
    link = f"target_link_libraries({name} PUBLIC {up_name}::{up_name})\n" if up_name else ""
    (path / "CMakeLists.txt").write_text(
        textwrap.dedent(
            f"""\
            cmake_minimum_required(VERSION 3.10)
            project({name} CXX)
            set(CMAKE_CXX_STANDARD 17)
            set(CMAKE_INSTALL_RPATH "${{CMAKE_INSTALL_PREFIX}}/lib")
            set(CMAKE_INSTALL_RPATH_USE_LINK_PATH TRUE)
            """
        )
        + find
        + textwrap.dedent(
            f"""\
            add_library({name} SHARED src/describe.cpp src/checksum.cpp)
            target_include_directories({name} PUBLIC
              $<BUILD_INTERFACE:${{CMAKE_CURRENT_SOURCE_DIR}}/include>
              $<INSTALL_INTERFACE:include>)
            """
        )
        + link
        + textwrap.dedent(
            f"""\
            add_executable({name}_node src/main.cpp)
            target_link_libraries({name}_node {name})
            install(TARGETS {name} EXPORT {name}Targets
              LIBRARY DESTINATION lib ARCHIVE DESTINATION lib RUNTIME DESTINATION bin)
            install(TARGETS {name}_node RUNTIME DESTINATION bin)
            install(DIRECTORY include/ DESTINATION include)
            install(EXPORT {name}Targets NAMESPACE {name}:: DESTINATION share/{name}/cmake)
            install(FILES {name}Config.cmake DESTINATION share/{name}/cmake)
            """
        )
    )
    (path / f"{name}Config.cmake").write_text(
        "include(CMakeFindDependencyMacro)\n"
        + (f"find_dependency({up_name})\n" if up_name else "")
        + f'include("${{CMAKE_CURRENT_LIST_DIR}}/{name}Targets.cmake")\n'
    )
    (path / "include" / name / f"{name}.hpp").write_text(HEADER.format(name=name))
    (path / "src" / "describe.cpp").write_text(
        DESCRIBE_CPP.format(
            name=name,
            mark=COMPILE_MARK,
            depth=depth,
            upstream_include=f'#include "{up_name}/{up_name}.hpp"' if up_name else "",
            upstream_call=f' + " <- " + {up_name}::describe()' if up_name else "",
        )
    )
    (path / "src" / "checksum.cpp").write_text(
        CHECKSUM_CPP.format(name=name, mark=COMPILE_MARK, depth=depth)
    )
    (path / "src" / "main.cpp").write_text(MAIN_CPP.format(name=name, mark=COMPILE_MARK))


def write_workspace(
    root: Path, *, count: int, chain: int, depth: int, key: str, base_image: str,
    cmake_args: str, run_id: str, first: int = 0, image: str = IMAGE,
    extra_env: Optional[Dict[str, str]] = None,
) -> None:
    """Packages first..count-1 in root, with a .env, and a run id among the additional files:
    it changes what the resolve stage hands on, so no earlier run's dependency layers serve
    the cold build (the apt download cache may)."""
    root.mkdir(parents=True)
    for index in range(first, count):
        write_package(root, index, chain=chain, depth=depth, keys=[key] if index == 0 else [])
    (root / "docker" / "additional-files").mkdir(parents=True)
    (root / "docker" / "additional-files" / "bench-run-id.txt").write_text(run_id + "\n")
    env = {
        "BASE_IMAGE": base_image,
        "COMMAND": f"{package_name(count - 1)}_node",
        "IMAGE": image,
        "TARGET": "dev,run",
        "CMAKE_ARGS": cmake_args,
        # the figures are dev/run rebuilds; slimming (ENABLE_SLIM's default) would add a trace
        "ENABLE_SLIM": "false",
        **(extra_env or {}),
    }
    # python-dotenv reads a double-quoted value literally (no shell involved).
    (root / ".env").write_text("".join(f'{k}="{v}"\n' for k, v in env.items()))


def git(args: Sequence[str], cwd: Path) -> None:
    env = {**os.environ, "GIT_AUTHOR_NAME": "bench", "GIT_AUTHOR_EMAIL": "bench@invalid",
           "GIT_COMMITTER_NAME": "bench", "GIT_COMMITTER_EMAIL": "bench@invalid"}
    proc = subprocess.run(["git", *args], cwd=cwd, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BenchError(f"git {' '.join(args)} failed: {proc.stderr.strip()}")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def git_server(base: Path, upstream_count: int, *, chain: int, depth: int, key: str,
               run_id: str) -> Tuple[subprocess.Popen, str]:
    """A bare repository of packages 0..upstream_count-1 served by `git daemon` on a free
    loopback port; returns (the daemon, the repository's git:// URL)."""
    work = base / "upstream-work"
    for index in range(upstream_count):
        write_package(work, index, chain=chain, depth=depth, keys=[key] if index == 0 else [])
    (work / "bench-run-id.txt").write_text(run_id + "\n")
    git(["init", "-q", "-b", "main"], work)
    git(["add", "-A"], work)
    git(["commit", "-q", "-m", "bench upstream"], work)
    served = base / "git"
    served.mkdir()
    git(["clone", "-q", "--bare", str(work), str(served / f"{IMPORTS_REPO}.git")], base)
    port = free_port()
    daemon = subprocess.Popen(
        ["git", "daemon", "--export-all", "--reuseaddr", "--listen=127.0.0.1", f"--port={port}",
         f"--base-path={served}", str(served)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", port)) == 0:
                return daemon, f"git://127.0.0.1:{port}/{IMPORTS_REPO}.git"
        time.sleep(0.1)
    daemon.terminate()
    raise BenchError("git daemon did not start")


def set_mark(root: Path, index: int, mark: str) -> None:
    """The one-file change: a new kMark in describe.cpp of package index."""
    source = root / package_name(index) / "src" / "describe.cpp"
    text, count = re.subn(r'kMark = "[^"]*"', f'kMark = "{mark}"', source.read_text())
    if count != 1:
        raise BenchError(f"{source}: kMark not found")
    source.write_text(text)


def add_depend(root: Path, index: int, key: str) -> None:
    package_xml = root / package_name(index) / "package.xml"
    text = package_xml.read_text()
    package_xml.write_text(text.replace("  <export>", f"  <depend>{key}</depend>\n  <export>"))


# ----------------------------------------------------------------------------------------------
# docker and the CLI


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
            timed: Optional[List[Tuple[float, str]]] = None) -> tuple[float, str]:
    """`python -m docker_ros build ARGS` in project, as a user runs it; (seconds, output).
    timed: receives each output line with the wall time it arrived."""
    argv = [sys.executable, "-m", "docker_ros", "build", *args]
    env = clean_environ()
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
        raise BenchError(f"docker-ros build failed (exit code {code}); log: {log}\n{tail}")
    return seconds, "".join(lines)


def compiled_units(output: str) -> List[str]:
    """Translation units the build compiled (each source prints a #pragma message)."""
    return sorted(set(COMPILED.findall(output)))


def dependency_layers(output: str) -> str:
    """'rebuilt' when a dependencies-{dev,run} RUN executed, 'reused' when all came from cache.
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
        return "?"
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


# ----------------------------------------------------------------------------------------------
# the scenarios


class Bench:
    def __init__(self, args: argparse.Namespace, root: Path, log: Path) -> None:
        self.args = args
        self.root = root
        self.log = log
        self.count: int = args.packages
        self.rows: List[Scenario] = []

    def say(self, text: str) -> None:
        print(f"[bench] {text}", flush=True)

    def build(self, name: str, root: Optional[Path] = None,
              invocations: Sequence[Sequence[str]] = ((),)) -> Scenario:
        """One scenario: the CLI's build, or several builds one after the other (invocations:
        their extra arguments), timed together."""
        self.say(f"{name} ...")
        load = load1()
        seconds, output, timed = 0.0, "", []  # type: float, str, List[Tuple[float, str]]
        for args in invocations:
            took, out = run_cli(root or self.root, self.log, verbose=self.args.verbose,
                                args=args, timed=timed)
            seconds, output = seconds + took, output + out
        row = Scenario(name, seconds, compiled_units(output), dependency_layers(output),
                       changed_sources=changed_sources(output),
                       image_seconds=image_seconds(output), load1=load,
                       deps_overlap=dependency_overlap(timed))
        row.imports = imports_state(output)
        self.say(f"{name}: {seconds:.1f} s, {len(row.compiled)} TUs compiled, "
                 f"dependency layers {row.deps_layers}, sources taken as changed "
                 f"{row.changed_sources}")
        self.rows.append(row)
        return row

    def check(self, row: Scenario, ok: bool, detail: str) -> None:
        row.check = "OK" if ok else "FAIL"
        row.detail = detail
        if not ok:
            self.say(f"{row.name}: CHECK FAILED: {detail}")

    def check_run(self, row: Scenario, expected: str, *command: str, ref: str = IMAGE) -> None:
        output = run_output(ref, *command)
        ok = expected in output
        self.check(row, ok, f"run image, `{shlex.join(command) or 'default command'}` printed "
                   f"{output[-300:]!r}" + ("" if ok else f", expected {expected!r}"))

    def warm_up(self, root: Path) -> None:
        """Not measured: a one-package workspace on the same base, so that the layers every
        workspace shares (the base image prepared by this version of the tools) are built
        before the cold builds, and neither of them pays for them."""
        self.say("0  warm-up (not measured) ...")
        run_cli(root, self.log, verbose=self.args.verbose)
        docker("image", "rm", "-f", WARM_IMAGE, WARM_IMAGE + "-dev")

    def cold(self) -> None:
        # Never `docker builder prune`: the engine is shared, and the new workspace (run id,
        # cache mount ids from its path) finds no cache of an earlier run anyway.
        for ref in (IMAGE, DEV_IMAGE):
            docker("image", "rm", "-f", ref)
        row = self.build("1  cold build")
        last = package_name(self.count - 1)
        self.check_run(row, f"{last}[original]")

    def no_change(self) -> None:
        before = {ref: image_id(ref) for ref in (DEV_IMAGE, IMAGE)}
        row = self.build("2  no-change rebuild")
        after = {ref: image_id(ref) for ref in (DEV_IMAGE, IMAGE)}
        same = before == after
        self.check(row, same, "dev and run image ids unchanged" if same else
                   f"image ids changed: {before} -> {after}")

    def change_last(self) -> None:
        last = self.count - 1
        set_mark(self.root, last, "changed-last")
        row = self.build("3  one .cpp changed, last pkg")
        self.check_run(row, f"{package_name(last)}[changed-last]")

    def baseline(self) -> None:
        """docker-ros (the original) after a one-file change: colcon builds everything anew."""
        self.say("B  baseline: full colcon build in the dev image ...")
        cmake = shlex.split(self.args.cmake_args)
        script = f"cd {WS} && rm -rf build install log && colcon build --base-paths src"
        if cmake:
            script += " --cmake-args " + shlex.join(cmake)
        argv = ["docker", "run", "--rm", DEV_IMAGE, "bash", "-c", script]
        load = load1()
        began = time.monotonic()
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=3600)
        seconds = time.monotonic() - began
        with self.log.open("a") as out:
            out.write(f"\n===== {shlex.join(argv)}\n{proc.stdout}{proc.stderr}")
        if proc.returncode != 0:
            raise BenchError(f"baseline colcon build failed ({proc.returncode}); log: {self.log}")
        row = Scenario("B  baseline: full colcon build", seconds,
                       compiled_units(proc.stdout + proc.stderr), load1=load)
        total = 3 * self.count
        self.check(row, len(row.compiled) == total,
                   f"{len(row.compiled)} of {total} TUs compiled")
        self.say(f"baseline: {seconds:.1f} s, {len(row.compiled)} TUs compiled")
        self.rows.append(row)

    def limit(self) -> None:
        """The physical limit of scenario 3's edit: in a container of the dev image, a full
        colcon build (not timed: the warm build tree), the same kind of edit in the same file,
        then timed: `colcon build` of that package alone plus writing the install space as a
        layer would be (tar, sha256)."""
        self.say("L  physical limit ...")
        name = package_name(self.count - 1)
        cmake = shlex.split(self.args.cmake_args)
        colcon = "colcon build --base-paths src" + (
            " --cmake-args " + shlex.join(cmake) if cmake else "")
        source = f"src/target/{name}/src/describe.cpp"
        script = "\n".join([
            "set -e", f"cd {WS}", f"{colcon} >/dev/null 2>&1",
            f"sed -i 's/kMark = \"[^\"]*\"/kMark = \"limit-edit\"/' {source}",
            "t0=$(date +%s.%N)", f"{colcon} --packages-select {name}",
            "t1=$(date +%s.%N)", "tar -cf - install | sha256sum >/dev/null",
            "t2=$(date +%s.%N)", 'echo "LIMIT $t0 $t1 $t2"',
        ])
        argv = ["docker", "run", "--rm", DEV_IMAGE, "bash", "-c", script]
        load = load1()
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=3600)
        with self.log.open("a") as out:
            out.write(f"\n===== {shlex.join(argv)}\n{proc.stdout}{proc.stderr}")
        found = re.search(r"LIMIT ([\d.]+) ([\d.]+) ([\d.]+)", proc.stdout)
        if proc.returncode != 0 or not found:
            raise BenchError(f"physical limit measurement failed ({proc.returncode}); log: "
                             f"{self.log}")
        start, built, exported = (float(v) for v in found.groups())
        row = Scenario("L  physical limit of 3", exported - start,
                       compiled_units(proc.stdout + proc.stderr), load1=load)
        self.check(row, len(row.compiled) == 1,
                   f"colcon {built - start:.1f} s + install layer {exported - built:.1f} s, "
                   f"{len(row.compiled)} TU compiled")
        self.say(f"limit: {row.seconds:.1f} s ({row.detail})")
        self.rows.append(row)

    def floor(self, root: Path) -> None:
        """What any build of two images through BuildKit costs here, whatever they hold: a
        `docker buildx bake` of two targets of one trivial COPY each, all cached (the median
        of three, after one that fills the cache). Not part of the physical limit L: it says
        how much of the rest of scenario 3 no Dockerfile can save."""
        self.say("F  BuildKit floor ...")
        root.mkdir()
        (root / "x").write_text("x\n")
        (root / "Dockerfile").write_text("FROM scratch AS dev\nCOPY x /x\n"
                                         "FROM scratch AS run\nCOPY x /y\n")
        targets = {t: {"context": str(root), "dockerfile": str(root / "Dockerfile"),
                       "target": t, "tags": [f"{FLOOR_IMAGE}-{t}"], "output": ["type=docker"]}
                   for t in ("dev", "run")}
        (root / "bake.json").write_text(json.dumps({"target": targets}))
        argv = ["docker", "buildx", "bake", "--progress=plain", "--file",
                str(root / "bake.json"), "dev", "run"]
        load = load1()
        times = []
        for _ in range(4):
            began = time.monotonic()
            proc = subprocess.run(argv, capture_output=True, text=True, timeout=300)
            times.append(time.monotonic() - began)
            if proc.returncode != 0:
                raise BenchError(f"floor bake failed: {proc.stderr[-2000:]}")
        docker("image", "rm", "-f", f"{FLOOR_IMAGE}-dev", f"{FLOOR_IMAGE}-run")
        row = Scenario("F  BuildKit floor (2 cached targets)", sorted(times[1:])[1], load1=load,
                       detail="runs: " + ", ".join(f"{s:.2f} s" for s in times))
        self.say(f"floor: {row.seconds:.2f} s ({row.detail})")
        self.rows.append(row)

    def separate_cold(self, root: Path) -> None:
        """Cold as docker-ros builds: dev, then run, each its own build of a workspace new to
        the engine (same packages, another run id and path: no cache of scenario 1 applies)."""
        row = self.build("D  cold, dev then run separately", root,
                         invocations=(("--target", "dev"), ("--target", "run")))
        self.check_run(row, f"{package_name(self.count - 1)}[original]", ref=SEPARATE_IMAGE)
        docker("image", "rm", "-f", SEPARATE_IMAGE, SEPARATE_IMAGE + "-dev")

    def change_first(self) -> None:
        set_mark(self.root, 0, "changed-first")
        row = self.build("3b one .cpp changed, first pkg")
        end = chain_end(0, self.count, self.args.chain)
        self.check_run(row, f"{package_name(0)}[changed-first]", f"{package_name(end)}_node")

    def add_dependency(self, packages: Sequence[str]) -> None:
        add_depend(self.root, self.count - 1, self.args.add_key)
        row = self.build(f"4  +1 apt dependency ({self.args.add_key})")
        missing = {ref: sorted(set(packages) - set(installed(ref, packages)))
                   for ref in (DEV_IMAGE, IMAGE)}
        ok = not any(missing.values())
        self.check(row, ok, f"{', '.join(packages)} installed in dev and run" if ok else
                   f"not installed: {missing}")

    def lean(self) -> None:
        """The lean run image of the workspace as scenario 4 left it: every node must run."""
        docker("image", "rm", "-f", LEAN_IMAGE)
        row = self.build("7  lean run image (after 4)", invocations=(LEAN,))
        self.check_lean(row, "changed-last")
        set_mark(self.root, self.count - 1, "changed-lean")
        row = self.build("7b lean: one .cpp changed, last pkg", invocations=(LEAN,))
        self.check_lean(row, "changed-lean")

    def check_lean(self, row: Scenario, mark: str) -> None:
        nodes = " && ".join(f"{package_name(i)}_node" for i in range(self.count))
        output = run_output(LEAN_IMAGE, "bash", "-c", nodes)
        last = f"{package_name(self.count - 1)}[{mark}]"
        ok = last in output and all(package_name(i) in output for i in range(self.count))
        self.check(row, ok, f"lean run image, all {self.count} nodes ran"
                   if ok else f"lean run image: {output[-300:]!r}, expected {last!r}")

    def imports(self, root: Path) -> None:
        """The workspace importing packages 0..N-1 through .repos; its own package is N."""
        own = self.count
        for ref in (IMPORTS_IMAGE, IMPORTS_IMAGE + "-dev"):
            docker("image", "rm", "-f", ref)
        row = self.build("6  imports: cold build", root)
        row.units = 3 * (own + 1)
        self.check_run(row, f"{package_name(own)}[original]", ref=IMPORTS_IMAGE)
        set_mark(root, own, "changed-own")
        row = self.build("6b imports: one .cpp changed, own pkg", root)
        row.units = 3 * (own + 1)
        self.check(row, row.imports == "cached" and len(row.compiled) == 1,
                   f"vcs import {row.imports}, {len(row.compiled)} TUs compiled (expected the "
                   "import cached and the changed .cpp alone compiled)")
        with (root / ".repos").open("a") as repos:
            repos.write("# touched by the bench\n")
        row = self.build("6c imports: .repos touched, re-import", root)
        row.units = 3 * (own + 1)
        self.check(row, row.imports == "ran" and not row.compiled,
                   f"vcs import {row.imports}, {len(row.compiled)} TUs compiled (expected a "
                   "fresh import and nothing compiled: same content)")
        docker("image", "rm", "-f", IMPORTS_IMAGE, IMPORTS_IMAGE + "-dev")


def ratio(value: float, reference: Optional[float]) -> Optional[float]:
    return value / reference if reference else None


def table(rows: Sequence[Scenario], sizes: Dict[str, float], total_units: int) -> str:
    head = ("scenario", "seconds", "x cold", "x baseline", "x limit", "TUs compiled",
            "src changed", "dep layers", "deps parallel", "import", "load1", "check")
    lines: List[Tuple[str, ...]] = [head]
    for row in rows:
        lines.append((
            row.name,
            f"{row.seconds:.1f}",
            f"{row.ratio_cold:.2f}" if row.ratio_cold is not None else "-",
            f"{row.ratio_baseline:.2f}" if row.ratio_baseline is not None else "-",
            f"{row.ratio_limit:.2f}" if row.ratio_limit is not None else "-",
            f"{len(row.compiled)}/{row.units or total_units}",
            row.changed_sources,
            row.deps_layers,
            f"{row.deps_overlap:.1f} s" if row.deps_overlap is not None else "-",
            row.imports,
            f"{row.load1:.1f}",
            row.check,
        ))
    for target, mb in sizes.items():
        lines.append((f"5  {target} image size", f"{mb:.0f} MB") + ("",) * (len(head) - 2))
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    rendered = ["  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in lines]
    rendered.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(rendered)


def parse_args(argv: Optional[Sequence[str]]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0] if __doc__ else None,
        epilog="Nothing is pruned (the Docker engine is shared): the cold builds are cold for "
               "the workspace, not for the base image's prepared layer or the apt downloads. "
               "Timings are wall-clock; other builds on the engine make them noisy.",
    )
    parser.add_argument("-n", "--packages", type=int, default=10,
                        help="number of C++ packages in the workspace (default 10)")
    parser.add_argument("--chain", type=int, default=4,
                        help="package i depends on package i-1 except when i %% CHAIN == 0 "
                             "(default 4: chains 0<-1<-2<-3, 4<-5<-6<-7, ...)")
    parser.add_argument("--depth", type=int, default=4,
                        help="template recursion depth: compile weight of each .cpp (default 4)")
    parser.add_argument("--base-image", default=DEFAULT_BASE_IMAGE,
                        help=f"BASE_IMAGE; bootstrapped (ROS 1 on Debian bookworm) when missing "
                             f"(default {DEFAULT_BASE_IMAGE})")
    parser.add_argument("--key", default="std_msgs",
                        help="rosdep key the first package depends on (default std_msgs; must "
                             "resolve offline in the base image: Debian's rules in bookworm only "
                             "know ROS package keys)")
    parser.add_argument("--add-key", default="angles",
                        help="rosdep key added to the last package in scenario 4 (default angles)")
    parser.add_argument("--cmake-args", default="-DCMAKE_BUILD_TYPE=Release",
                        help="CMAKE_ARGS of the workspace (default -DCMAKE_BUILD_TYPE=Release)")
    parser.add_argument("--no-imports", dest="imports", action="store_false",
                        help="skip scenario 6 (the workspace importing its packages via .repos)")
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write the figures here")
    parser.add_argument("--keep", action="store_true",
                        help="keep the generated workspace, the build log (path printed) and "
                             "the workspace's dev and run images")
    parser.add_argument("-v", "--verbose", action="store_true", help="stream the build logs")
    args = parser.parse_args(argv)
    if args.packages < 1 or args.chain < 1 or args.depth < 1:
        parser.error("--packages, --chain and --depth must be at least 1")
    return args


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = parse_args(argv)
    if not shutil.which("docker"):
        print("bench: docker not found", file=sys.stderr)
        return 2
    tmp = Path(tempfile.mkdtemp(prefix="docker-ros-bench-"))
    root = tmp / "ws"
    log = tmp / "build.log"
    failed = False
    try:
        baseimage.bootstrap("ros1", tag=args.base_image)
        resolved = resolve_keys(args.base_image, [args.key, args.add_key])
        print(f"[bench] rosdep keys (offline, in {args.base_image}): {resolved}", flush=True)
        run_id = f"{os.getpid()}-{time.time_ns()}"
        write_workspace(root, count=args.packages, chain=args.chain, depth=args.depth,
                        key=args.key, base_image=args.base_image, cmake_args=args.cmake_args,
                        run_id=run_id)
        print(f"[bench] workspace of {args.packages} packages in {root}; log {log}", flush=True)
        bench = Bench(args, root, log)
        warm = tmp / "ws-warm-up"
        write_workspace(warm, count=1, chain=args.chain, depth=1, key=args.key,
                        base_image=args.base_image, cmake_args=args.cmake_args,
                        run_id=run_id + "-warm-up", image=WARM_IMAGE)
        bench.warm_up(warm)
        bench.cold()
        separate = tmp / "ws-separate"
        write_workspace(separate, count=args.packages, chain=args.chain, depth=args.depth,
                        key=args.key, base_image=args.base_image, cmake_args=args.cmake_args,
                        run_id=run_id + "-separate", image=SEPARATE_IMAGE)
        bench.separate_cold(separate)
        bench.no_change()
        bench.change_last()
        bench.limit()
        bench.floor(tmp / "floor")
        bench.baseline()
        bench.change_first()
        bench.add_dependency(resolved[args.add_key])
        sizes = {"base": image_mb(args.base_image), "dev": image_mb(DEV_IMAGE),
                 "run": image_mb(IMAGE)}
        bench.lean()
        sizes["run (lean)"] = image_mb(LEAN_IMAGE)
        if args.imports:
            daemon, url = git_server(tmp, args.packages, chain=args.chain, depth=args.depth,
                                     key=args.key, run_id=run_id)
            try:
                imports_root = tmp / "ws-imports"
                write_workspace(imports_root, count=args.packages + 1, first=args.packages,
                                chain=args.chain, depth=args.depth, key=args.key,
                                base_image=args.base_image, cmake_args=args.cmake_args,
                                run_id=run_id, image=IMPORTS_IMAGE,
                                extra_env={"BUILD_NETWORK": "host"})
                (imports_root / ".repos").write_text(
                    f"repositories:\n  {IMPORTS_REPO}:\n    type: git\n    url: {url}\n"
                    "    version: main\n")
                bench.imports(imports_root)
            finally:
                daemon.terminate()
                daemon.wait()
    except BenchError as exc:
        print(f"bench: {exc}", file=sys.stderr)
        print(f"bench: workspace and log kept in {tmp}", file=sys.stderr)
        return 1
    rows = bench.rows
    cold = rows[0].seconds
    baseline = next(r.seconds for r in rows if r.name.startswith("B "))
    limit = next(r.seconds for r in rows if r.name.startswith("L "))
    floor = next(r.seconds for r in rows if r.name.startswith("F "))
    apart = next(r.seconds for r in rows if r.name.startswith("D "))
    edit = next(r for r in rows if r.name.startswith("3 "))
    for row in rows:
        row.ratio_cold = ratio(row.seconds, cold)
        if row.name.startswith(("3", "6b")):
            row.ratio_baseline = ratio(row.seconds, baseline)
        if row.name.startswith(("3 ", "7b")):
            row.ratio_limit = ratio(row.seconds, limit)
    total_units = 3 * args.packages
    print()
    print(table(rows, sizes, total_units))
    print(f"\nTUs: translation units compiled of {total_units} (3 .cpp per package); "
          "src changed: source files the colcon step took for changed (and re-stamped); "
          "dep layers: the dependencies-{dev,run} RUN layers; deps parallel: seconds both "
          "dependency RUNs ran at once; x limit: against L, the physical limit (a warm colcon "
          "build of that package alone plus writing the install space as a layer); "
          "x baseline: our whole `docker-ros build` (dev+run images) against a bare "
          "colcon build from scratch; load1: load average when the scenario started.")
    print(f"cold build: ours {cold:.1f} s, dev then run separately (docker-ros) {apart:.1f} s: "
          f"{cold / apart:.2f}x; one-file edit (3): {edit.seconds:.1f} s against the "
          f"physical limit {limit:.1f} s: {edit.ratio_limit or 0:.2f}x; against the limit plus "
          f"the BuildKit floor ({limit:.1f} + {floor:.2f} s): "
          f"{edit.seconds / (limit + floor):.2f}x")
    print(f"run image over the base: {sizes['run'] - sizes['base']:.0f} MB, lean "
          f"{sizes['run (lean)'] - sizes['base']:.0f} MB")
    failed = any(r.check == "FAIL" for r in rows)
    for row in rows:
        if row.check == "FAIL":
            print(f"FAIL {row.name}: {row.detail}")
    if args.json:
        args.json.write_text(json.dumps({
            "packages": args.packages, "chain": args.chain, "depth": args.depth,
            "base_image": args.base_image, "cpus": os.cpu_count(),
            "scenarios": [asdict(r) for r in rows],
            "sizes_mb": sizes,
        }, indent=2) + "\n")
        print(f"figures written to {args.json}")
    if args.keep:
        print(f"workspace, log and images ({IMAGE}, {DEV_IMAGE}, {LEAN_IMAGE}) kept in {tmp}")
    else:
        shutil.rmtree(tmp, ignore_errors=True)
        docker("image", "rm", "-f", IMAGE, DEV_IMAGE, LEAN_IMAGE)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
