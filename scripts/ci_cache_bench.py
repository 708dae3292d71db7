#!/usr/bin/env python3
"""CI jobs on empty runners with a registry cache, per engine generation (issue 21).

For Engine 20.10 (classic store) and Engine 26 (containerd store, from scripts/setup.sh): a
local registry, a fresh private engine running the example's CI job (`docker-ros push`, GitLab
environment on the default branch, so CACHE_TO/CACHE_FROM/BUILD_STATE_FROM take their CI
defaults), then another fresh engine running the same job with nothing changed. Prints per job
its wall time, the cache choice line and how many stages of dev and run came from the cache.
Needs root (private daemons, bridges). Removes what it made; prunes nothing.

    python3 scripts/ci_cache_bench.py [--engines 20.10,26] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Dict, Optional, Sequence, Tuple

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.docker.buildhelp import cached_vertices, not_from_cache  # noqa: E402
from tests.engines import private_engine  # noqa: E402

BASE_IMAGE = "docker-ros-test/ros1:bookworm"
COMMAND = "roslaunch docker_ros_example talker_listener.launch"
HEADER = re.compile(r"^==> docker-ros build \(\w+\) ([\w-]+) -> .*$", re.MULTILINE)


def stage_counts(log: str) -> Dict[str, object]:
    """target -> stage steps, how many came from the cache, and the ones that ran (FROMs
    left out: BuildKit resolves them, it never marks them CACHED)."""
    counts: Dict[str, object] = {}
    parts = HEADER.split(log)
    for target, section in zip(parts[1::2], parts[2::2]):
        steps = [n for n in cached_vertices(section) if re.match(r"^\[[\w-]+ \d+/\d+\]", n)
                 and " FROM " not in n]
        ran = not_from_cache(section)
        counts[target] = {"steps": len(steps), "from cache": len(steps) - len(ran),
                          "ran": [name[:60] for name in ran]}
    return counts


def start_registry(work: Path) -> Tuple[subprocess.Popen[bytes], str]:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{probe.getsockname()[1]}"
    (work / "registry.yml").write_text(
        f"version: 0.1\nlog: {{level: warn}}\nstorage: {{filesystem: {{rootdirectory: "
        f"{work / 'registry'}}}, delete: {{enabled: true}}}}\nhttp: {{addr: {address}}}\n")
    server = subprocess.Popen(["docker-registry", "serve", str(work / "registry.yml")],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1)
    return server, address


def ci_job(project: Path, host: str, registry: str, log: Path) -> Dict[str, object]:
    env = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    env.update({"DOCKER_HOST": host, "GITLAB_CI": "true", "CI_COMMIT_BRANCH": "main",
                "CI_DEFAULT_BRANCH": "main", "CI_REGISTRY_IMAGE": f"{registry}/bench/example",
                "BUILD_NETWORK": "host", "ENABLE_SLIM": "false",
                "PYTHONPATH": str(ROOT / "src")})
    start = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "docker_ros", "push"], cwd=project, env=env,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seconds = time.monotonic() - start
    log.write_text(proc.stdout)
    choice = next((line for line in proc.stdout.splitlines() if line.startswith("builder: ")),
                  "")
    build = proc.stdout.split("\npush: ", 1)[0]  # the build, before the pushes
    return {"seconds": round(seconds, 1), "ok": proc.returncode == 0, "builder": choice,
            "stages": stage_counts(build), "compiled": build.count("Building CXX object"),
            "log": str(log)}


def bench_engine(modern: bool, work: Path, jobs: int) -> Dict[str, object]:
    server, registry = start_registry(work)
    project = work / "example"
    shutil.copytree(ROOT / "example", project)
    (project / ".env").write_text(f"BASE_IMAGE={BASE_IMAGE}\nCOMMAND={COMMAND}\n"
                                  "TARGET=dev,run\n")
    results: Dict[str, object] = {}
    try:
        for job in ["first"] + [f"no change {n}" for n in range(1, jobs)]:
            start = time.monotonic()
            with private_engine([BASE_IMAGE], modern=modern) as host:
                ready = time.monotonic() - start
                result = ci_job(project, host, registry, work / f"{job.replace(' ', '-')}.log")
                result["engine ready (base image loaded)"] = round(ready, 1)
                results[job] = result
                print(f"  {job}: {json.dumps(result)}", flush=True)
    finally:
        server.terminate()
        server.wait()
    return results


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--engines", default="20.10,26")
    parser.add_argument("--jobs", type=int, default=2, help="CI jobs per engine (the first"
                        " builds everything, the others change nothing)")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--keep", action="store_true", help="keep the logs' folder")
    args = parser.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="docker-ros-ci-cache-bench-"))
    report: Dict[str, object] = {}
    for name in args.engines.split(","):
        print(f"Engine {name}:", flush=True)
        (work / name).mkdir()
        report[name] = bench_engine(name == "26", work / name, args.jobs)
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    else:
        print(f"logs in {work}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
