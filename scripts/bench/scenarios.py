"""The scenarios (see the package docstring), measured one after the other."""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import socket
import subprocess
import time
import urllib.request
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import docker_ros.host.baseimage as baseimage
from bench import BenchError
from bench.buildlog import (
    Scenario,
    changed_sources,
    compiled_units,
    dependency_layers,
    dependency_overlap,
    docker,
    image_id,
    image_mb,
    image_seconds,
    imports_state,
    installed,
    load1,
    resolve_keys,
    run_cli,
    run_output,
    steps_resolved,
    steps_run,
)
from bench.workspace import (
    DEV_IMAGE,
    FLOOR_IMAGE,
    IMAGE,
    IMPORTS_IMAGE,
    IMPORTS_REPO,
    LEAN_IMAGE,
    SEPARATE_IMAGE,
    SLIM_IMAGE,
    WARM_IMAGE,
    WS,
    add_depend,
    chain_end,
    git_server,
    package_name,
    set_mark,
    write_workspace,
)
from docker_ros.core.loading import host_platform
from docker_ros.host import engine
from tests import leftovers

BUILD_STATE_PULLED = re.compile(r"build state: \S+ pulled in ([\d.]+) s \((\d+) MB\)")
LEAN = ("--target", "run", "--image-tag", "lean", "--set", "ENABLE_LEAN_RUN_IMAGE=true")
SLIM = ("--target", "run", "--set", "ENABLE_SLIM=true")


class Bench:
    def __init__(self, args: argparse.Namespace, root: Path, log: Path) -> None:
        self.args = args
        self.root = root
        self.log = log
        self.count: int = args.packages
        self.rows: List[Scenario] = []
        self.output = ""

    def say(self, text: str) -> None:
        print(f"[bench] {text}", flush=True)

    def build(self, name: str, root: Optional[Path] = None,
              invocations: Sequence[Sequence[str]] = ((),), task: str = "build",
              extra_env: Optional[Dict[str, str]] = None) -> Scenario:
        """One scenario: the CLI's build (or TASK), or several one after the other
        (invocations: their extra arguments), timed together. self.output: what they printed."""
        self.say(f"{name} ...")
        load = load1()
        seconds, output, timed = 0.0, "", []  # type: float, str, List[Tuple[float, str]]
        for args in invocations:
            took, out = run_cli(root or self.root, self.log, verbose=self.args.verbose,
                                args=args, timed=timed, task=task, extra_env=extra_env)
            seconds, output = seconds + took, output + out
        row = Scenario(name, seconds, compiled_units(output), dependency_layers(output),
                       changed_sources=changed_sources(output),
                       image_seconds=image_seconds(output), load1=load,
                       deps_overlap=dependency_overlap(timed))
        row.imports = imports_state(output)
        row.steps = steps_resolved(output)
        row.ran = steps_run(output)
        self.output = output
        self.say(f"{name}: {seconds:.1f} s, {len(row.compiled)} TUs compiled, "
                 f"dependency layers {row.deps_layers}, sources taken as changed "
                 f"{row.changed_sources}, {row.steps} BuildKit steps resolved")
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
        for ref in (IMAGE, DEV_IMAGE, SLIM_IMAGE):
            docker("image", "rm", "-f", ref)
        row = self.build("1  cold build")
        last = package_name(self.count - 1)
        self.check_run(row, f"{last}[original]")
        if image_id(SLIM_IMAGE):  # the defaults a user gets: a local build does not slim
            self.check(row, False, f"the default build made {SLIM_IMAGE}")

    def no_change(self, empty_cache: Path) -> None:
        """2: the default (the record of the last build: BuildKit not started); 2b: BuildKit's
        cache alone (an empty cache folder, no record: every step resolved, all cached)."""
        before = {ref: image_id(ref) for ref in (DEV_IMAGE, IMAGE)}
        for name, env in (("2  no-change rebuild", None),
                          ("2b no-change, no record (BuildKit)",
                           {"XDG_CACHE_HOME": str(empty_cache)})):
            row = self.build(name, extra_env=env)
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
            # in root: from buildx 0.20 on, bake reads only its working directory ungranted
            proc = subprocess.run(argv, capture_output=True, text=True, timeout=300, cwd=root)
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

    def slim(self) -> None:
        """The run image slimmed (ENABLE_SLIM; the run image first takes scenario 7b's edit),
        then the same build again: the slim image is up to date, nothing traced (the figure
        tests/docker/test_slim.py leaves to the bench)."""
        docker("image", "rm", "-f", SLIM_IMAGE)
        row = self.build("8  slim image (after 7b)", invocations=(SLIM,))
        self.check_run(row, f"{package_name(self.count - 1)}[changed-lean]", ref=SLIM_IMAGE)
        before = image_id(SLIM_IMAGE)
        row = self.build("8b slim: no-change rebuild", invocations=(SLIM,))
        after = image_id(SLIM_IMAGE)
        self.check(row, before == after, "slim image id unchanged" if before == after else
                   f"slim image id changed: {before} -> {after}")

    def ci_empty_runner(self, tmp: Path, registry: str) -> None:
        """9: CI jobs on empty runners, defaults as in CI (BUILD_STATE_FROM, CACHE_FROM): job 1
        pushes the run image and its build state to a local registry; each later job works in
        a checkout of its own (another path: a build/ cache that holds nothing of the
        project), its local images removed: 9b one .cpp changed in the last package (then
        pushed, untimed), 9c nothing changed since. The engine is shared and never pruned:
        BuildKit's layer cache is not emptied, the colcon build/ cache is."""
        ref = f"{registry}/docker-ros-bench/ci:latest"
        state = f"{ref}-build-state"
        args = ("--image", ref, "--target", "run", "--cache-from", ref,
                "--set", f"BUILD_STATE_FROM={state}")
        last = self.count - 1

        def job(name: str, number: int, task: str = "build") -> Scenario:
            root = tmp / f"ci-job{number}"
            shutil.copytree(self.root, root, symlinks=True)
            for each in (ref, f"{state}-{host_platform()}"):
                docker("image", "rm", "-f", each)
            return self.build(name, root, invocations=(args,), task=task)

        row = job("9  CI job on an empty runner: build, push", 1, task="push")
        self.check(row, len(row.compiled) == 3 * self.count,
                   f"{len(row.compiled)} TUs compiled (no build state yet: all expected)")
        set_mark(self.root, last, "changed-ci")
        row = job("9b CI: one .cpp changed, empty runner", 2)
        pulled = BUILD_STATE_PULLED.search(self.output)
        self.check_run(row, f"{package_name(last)}[changed-ci]", ref=ref)
        ok = len(row.compiled) == 1 and pulled is not None
        row.detail = (f"{len(row.compiled)} TU compiled, build state "
                      + (f"pulled in {pulled.group(1)} s ({pulled.group(2)} MB)" if pulled
                         else "NOT pulled") + "; " + row.detail)
        row.check = "OK" if ok and row.check == "OK" else "FAIL"
        # job 2 pushes too (not timed: all cached by then), as a CI job does: job 3 pulls its state
        run_cli(tmp / "ci-job2", self.log, verbose=self.args.verbose, args=args, task="push")
        row = job("9c CI: nothing changed, empty runner", 3)
        self.check(row, not row.compiled, f"{len(row.compiled)} TUs compiled (0 expected)")
        leftovers.remove_registry_images(engine.client(), registry)

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


def local_registry(tmp: Path) -> Tuple[subprocess.Popen, str]:
    """A throw-away `docker-registry` (Debian's, installed by scripts/setup.sh) on a free
    loopback port, for the CI scenario; (process, address)."""
    executable = shutil.which("docker-registry")
    if executable is None:
        raise BenchError("docker-registry is not installed: run `bash scripts/setup.sh` first")
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{probe.getsockname()[1]}"
    work = tmp / "registry"
    work.mkdir()
    (work / "config.yml").write_text(
        f"version: 0.1\nlog: {{level: warn}}\nhttp: {{addr: '{address}'}}\n"
        f"storage: {{filesystem: {{rootdirectory: '{work / 'storage'}'}}}}\n")
    server = subprocess.Popen([executable, "serve", str(work / "config.yml")],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for _ in range(100):
        try:
            urllib.request.urlopen(f"http://{address}/v2/", timeout=1)
            return server, address
        except OSError:
            time.sleep(0.1)
    server.terminate()
    raise BenchError(f"the bench's registry did not start on {address}")


def run_all(args: argparse.Namespace, tmp: Path) -> Tuple[List[Scenario], Dict[str, float]]:
    """Every scenario, one after the other, in workspaces below tmp; the rows and image sizes."""
    root = tmp / "ws"
    log = tmp / "build.log"
    print(f"[bench] {docker('buildx', 'version').stdout.strip()}", flush=True)
    baseimage.bootstrap("ros1", tag=args.base_image)
    resolved = resolve_keys(args.base_image, [args.key, args.add_key])
    print(f"[bench] rosdep keys (offline, in {args.base_image}): {resolved}", flush=True)
    run_id = f"{os.getpid()}-{time.time_ns()}"
    # (the records of builds, host/unchanged.py, go with the bench's folder)
    os.environ["XDG_CACHE_HOME"] = str(tmp / "cache")
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
    bench.no_change(tmp / "cache-empty")
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
    if args.slim:
        bench.slim()
        sizes["run (slim)"] = image_mb(SLIM_IMAGE)
    if args.ci:
        registry, address = local_registry(tmp)
        try:
            bench.ci_empty_runner(tmp, address)
        finally:
            registry.terminate()
            registry.wait()
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
    return bench.rows, sizes
