"""The bench's command line: options, the temporary folder, the run, the report, cleaning up."""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Optional, Sequence

import bench
from bench import BenchError
from bench.buildlog import docker
from bench.report import print_report, write_json
from bench.scenarios import run_all
from bench.workspace import DEFAULT_BASE_IMAGE, DEV_IMAGE, IMAGE, LEAN_IMAGE, SLIM_IMAGE
from docker_ros.host import engine
from tests import leftovers


def parse_args(argv: Optional[Sequence[str]]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=(bench.__doc__ or "").split("\n\n")[0],
        epilog="Nothing is pruned (the Docker engine is shared): the cold builds are cold for "
               "the workspace, not for the base image's prepared layer or the apt downloads. "
               "Timings are wall-clock; other builds on the engine make them noisy.",
    )
    parser.add_argument("-n", "--packages", type=int, default=10,
                        help="number of C++ packages in the workspace (default 10, at least 2)")
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
    parser.add_argument("--no-slim", dest="slim", action="store_false",
                        help="skip scenario 8 (the run image slimmed, then rebuilt unchanged)")
    parser.add_argument("--no-ci", dest="ci", action="store_false",
                        help="skip scenario 9 (CI jobs on empty runners, through a local "
                             "registry)")
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write the figures here")
    parser.add_argument("--keep", action="store_true",
                        help="keep the generated workspace, the build log (path printed) and "
                             "the workspace's dev and run images")
    parser.add_argument("-v", "--verbose", action="store_true", help="stream the build logs")
    args = parser.parse_args(argv)
    if args.packages < 2:
        parser.error("--packages must be at least 2: scenarios 3 and 5 change the last and the "
                     "first package, and the later checks tell them apart")
    if args.chain < 1 or args.depth < 1:
        parser.error("--chain and --depth must be at least 1")
    return args


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = parse_args(argv)
    if not shutil.which("docker"):
        print("bench: docker not found", file=sys.stderr)
        return 2
    tmp = Path(tempfile.mkdtemp(prefix="docker-ros-bench-"))
    before = leftovers.untagged(engine.client())
    try:
        rows, sizes = run_all(args, tmp)
    except BenchError as exc:
        print(f"bench: {exc}", file=sys.stderr)
        print(f"bench: workspace and log kept in {tmp}", file=sys.stderr)
        return 1
    failed = print_report(rows, sizes, args.packages)
    if args.json:
        write_json(args.json, args, rows, sizes)
    if args.keep:
        print(f"workspace, log and images ({IMAGE}, {DEV_IMAGE}, {LEAN_IMAGE}, {SLIM_IMAGE}) "
              f"kept in {tmp}")
    else:
        docker("image", "rm", "-f", IMAGE, DEV_IMAGE, LEAN_IMAGE, SLIM_IMAGE)
        # the imports images of its workspaces (in tmp) and the images its rebuilds untagged
        leftovers.remove_run_images(engine.client(), [tmp], before)
        shutil.rmtree(tmp, ignore_errors=True)
    return 1 if failed else 0
