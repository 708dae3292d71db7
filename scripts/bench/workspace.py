"""The generated workspace: C++ packages in chains of shared libraries with one rosdep key, its
.env, the edits the scenarios make, and a git server for the imports workspace."""

from __future__ import annotations

import os
import re
import socket
import subprocess
import textwrap
import time
from pathlib import Path
from typing import Dict, Optional, Sequence, Tuple

from bench import BenchError

IMAGE = "docker-ros-bench/ws:latest"
DEV_IMAGE = "docker-ros-bench/ws:latest-dev"
IMPORTS_IMAGE = "docker-ros-bench/imports:latest"
SEPARATE_IMAGE = "docker-ros-bench/separate:latest"
WARM_IMAGE = "docker-ros-bench/warm-up:latest"
LEAN_IMAGE = "docker-ros-bench/ws:lean"
SLIM_IMAGE = "docker-ros-bench/ws:latest-slim"
FLOOR_IMAGE = "docker-ros-bench/floor:latest"
IMPORTS_REPO = "bench_upstream"
DEFAULT_BASE_IMAGE = "docker-ros/ros1:bookworm"
WS = "/docker-ros/ws"
COMPILE_MARK = "docker-ros-bench compiles"

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
        # nothing else: the figures are those of the defaults a user gets (a local build does
        # not slim; scenario 8 asks for it)
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
