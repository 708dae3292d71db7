"""Running docker-ros as a user would (the console script) and inspecting what it built."""

from __future__ import annotations

import io
import os
import queue
import re
import shutil
import subprocess
import sys
import tarfile
import textwrap
import threading
import time
import uuid
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import docker

from docker_ros.host.engine import image_exists  # noqa: F401  (re-exported for the tests)

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "example"


def docker_ros(project: Path, *args: str, env: Optional[Dict[str, str]] = None,
               timeout: int = 1800) -> subprocess.CompletedProcess:
    """`docker-ros ARGS` in project; output (stdout+stderr) in .stdout. ENABLE_SLIM is false
    unless env sets it: a local build's default, and for push and ci too, which would slim by
    default (a traced run; only the slim tests pay for it)."""
    return subprocess.run([sys.executable, "-m", "docker_ros", *args], cwd=project,
                          env=docker_ros_env(env), stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, timeout=timeout)


def docker_ros_started(project: Path, *args: str,
                       env: Optional[Dict[str, str]] = None) -> subprocess.Popen:
    """docker_ros started, not awaited: its output (stdout+stderr) as text on .stdout."""
    return subprocess.Popen([sys.executable, "-m", "docker_ros", *args], cwd=project,
                            env=docker_ros_env(env), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def docker_ros_env(env: Optional[Dict[str, str]]) -> Dict[str, str]:
    """docker_ros's environment: this process's without TARGET, COMMAND and IMAGE, with
    ENABLE_SLIM false, then env."""
    full_env = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    full_env["ENABLE_SLIM"] = "false"
    full_env.update(env or {})
    return full_env


def write_env(project: Path, **values: str) -> None:
    (project / ".env").write_text("".join(f"{k}={v}\n" for k, v in values.items()))


def write_files(root: Path, files: Dict[str, str]) -> List[Path]:
    """Write each text (dedented) to its path below root; returns the paths."""
    paths = []
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
        paths.append(path)
    return paths


def copy_example(destination: Path) -> Path:
    shutil.copytree(EXAMPLE, destination)
    return destination


def own_copy(project: Path, destination: Path, image: str) -> Path:
    """A copy of a module fixture's project for a test that edits it, its images tagged `image`:
    the module's other tests keep the project and images they expect, whatever the order."""
    shutil.copytree(project, destination, symlinks=True)
    env = destination / ".env"
    kept = [line for line in env.read_text().splitlines() if not line.startswith("IMAGE=")]
    env.write_text("\n".join([*kept, f"IMAGE={image}"]) + "\n")
    return destination


def import_one_file_image(client: docker.DockerClient, ref: str, content: str,
                          changes: Sequence[str] = ()) -> None:
    """Import an image of one file (hello.txt holding content) as ref, of this machine's
    architecture: something to push that needs no build. changes: Dockerfile instructions
    (`docker import --change`)."""
    repository, tag = ref.rsplit(":", 1)
    payload = io.BytesIO()
    with tarfile.open(fileobj=payload, mode="w") as tar:
        data = content.encode()
        info = tarfile.TarInfo("hello.txt")
        info.size = len(data)
        tar.addfile(info, io.BytesIO(data))
    client.api.import_image_from_data(payload.getvalue(), repository=repository, tag=tag,
                                      changes=list(changes) or None)


def remove_image(ref: str) -> None:
    subprocess.run(["docker", "image", "rm", "-f", ref], capture_output=True)


def sh(ref: str, script: str, *docker_args: str) -> subprocess.CompletedProcess:
    """Run a bash script in a container of ref, through the image's entrypoint."""
    return subprocess.run(["docker", "run", "--rm", *docker_args, ref, "bash", "-c", script],
                          capture_output=True, text=True, timeout=300)


def dpkg_versions(ref: str) -> Dict[str, str]:
    """name -> version of every package installed in ref (dpkg-query)."""
    listed = sh(ref, "dpkg-query -W -f '${Package} ${Version} ${db:Status-Abbrev}\\n'")
    assert listed.returncode == 0, listed.stderr
    return {p[0]: p[1] for p in (line.split() for line in listed.stdout.splitlines())
            if len(p) == 3 and p[2] == "ii"}


def run_until(ref: str, needle: str, seconds: float, *docker_args: str) -> str:
    """Run the image's default command until needle appears in its output (or time is up)."""
    name = f"docker-ros-test-{os.getpid()}-{int(time.time() * 1000)}"
    proc = subprocess.Popen(["docker", "run", "--rm", "--name", name, *docker_args, ref],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: queue.Queue[str] = queue.Queue()
    stdout = proc.stdout
    assert stdout is not None

    def pump() -> None:
        for line in stdout:
            lines.put(line)

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    seen: List[str] = []
    deadline = time.monotonic() + seconds
    try:
        while time.monotonic() < deadline:
            try:
                seen.append(lines.get(timeout=0.5))
            except queue.Empty:
                if proc.poll() is not None:
                    break
                continue
            if needle in seen[-1]:
                break
    finally:
        subprocess.run(["docker", "rm", "-f", name], capture_output=True)
        proc.wait(timeout=60)
    return "".join(seen)


def cached_vertices(log: str) -> Dict[str, bool]:
    """BuildKit plain log -> {vertex name: came from cache?}, e.g. '[run 2/3] RUN ...'
    (the bake target before the stage dropped: `[dev base 2/4]` is `[base 2/4]`). CANCELED
    counts as from the cache: in a build that succeeds, BuildKit cancels a step's loading from
    the cache when a later step's result is found first (measured on Engine 26: the engine's
    debug log shows the step's `load cache`, and no process was created in the whole build)."""
    names: Dict[str, str] = {}
    cached: Dict[str, bool] = {}
    for line in log.splitlines():
        match = re.match(r"#(\d+) (\[.*)", line)
        if match:
            name = re.sub(r"^\[[\w-]+ ([\w-]+ \d+/\d+\])", r"[\1", match.group(2))
            names[match.group(1)] = name
            cached.setdefault(name, False)
            continue
        match = re.match(r"#(\d+) (CACHED|CANCELED)", line)
        if match and match.group(1) in names:
            cached[names[match.group(1)]] = True
    return cached


# a step of a stage (not the context transfer or the build definition BuildKit always runs)
STAGE = re.compile(r"^\[[\w-]+ \d+/\d+\]")


def not_from_cache(log: str) -> List[str]:
    """The stage steps of a target's build that ran. A step BuildKit does not mark CACHED came
    from the cache all the same when a later step of its stage is CACHED (cache keys chain: a
    lower step is materialized, not run, when a step that is run needs its files). A FROM is
    resolved, never CACHED: its layers are the image's."""
    cached = {name: hit for name, hit in cached_vertices(log).items()
              if STAGE.match(name) and " FROM " not in name}
    steps = {name: re.match(r"\[([\w-]+) (\d+)/", name) for name in cached}
    hits = {(m.group(1), int(m.group(2))) for name, m in steps.items() if m and cached[name]}
    return sorted(name for name, m in steps.items() if m and not cached[name] and not any(
        stage == m.group(1) and step > int(m.group(2)) for stage, step in hits))


def run_unique(source: Path) -> None:
    """A comment only this run writes: the builds of a test are its own, not found in the
    builder's cache from an earlier run at the same temporary path (pytest numbers them
    afresh once its folder is removed), whose cache mounts they share."""
    source.write_text(f"// test run {uuid.uuid4().hex}\n{source.read_text()}")


def failure_message(stdout: str) -> str:
    """A failed task's message: its first line (`docker-ros <task>: ...`), then the failing
    tool's own lines, indented (host/faults.py)."""
    lines = stdout.strip().splitlines()
    first = max(i for i, line in enumerate(lines) if line.startswith("docker-ros "))
    return "\n".join(lines[first:])
