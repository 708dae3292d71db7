"""Docker engines beside the shared one: Engine 26 with the containerd image store (the daemon
scripts/setup.sh starts) and private, empty engines of either generation (a fresh CI runner)."""

from __future__ import annotations

import contextlib
import os
import subprocess
import time
import uuid
from pathlib import Path
from typing import Dict, Iterator, Optional, Sequence

# Where scripts/setup.sh puts Engine 26 (see the README's "Two engine generations").
ENGINE26_HOST = "unix:///run/docker-ros-engine26/docker.sock"
ENGINE26_ROOT = Path(os.environ.get("ENGINE26_ROOT", "/opt/docker-ros-engine26"))
CONTAINERD_STORE = '{"features": {"containerd-snapshotter": true}}\n'


class EngineFailed(Exception):
    """A private engine did not start: its log."""


def env_for(host: str) -> Dict[str, str]:
    """This process's environment with DOCKER_HOST naming host."""
    return {**os.environ, "DOCKER_HOST": host}


def answers(host: str) -> bool:
    return subprocess.run(["docker", "info"], env=env_for(host), capture_output=True,
                          timeout=60).returncode == 0


def image_content(host: Optional[str], ref: str) -> str:
    """What makes ref the image it is on the engine at host (None: the shared engine): its
    creation time and layers, the same on either image store ("" when there is no such image).
    The image id is no measure: the containerd store's is a manifest digest."""
    shown = subprocess.run(["docker", "image", "inspect", "--format",
                            "{{.Created}} {{.RootFS.Layers}}", ref],
                           env=env_for(host) if host else None, capture_output=True, text=True)
    return shown.stdout.strip() if shown.returncode == 0 else ""


def has_image(host: str, ref: str) -> bool:
    """Whether the engine at host holds the shared engine's image ref, not merely an image of
    that name: a base image bootstrapped again (its recipe changed) must be copied again, or
    the engine's builds start from the old one (measured: a stale copy on Engine 26 made every
    registry cache lookup of another engine's job miss)."""
    return image_content(host, ref) == image_content(None, ref) != ""


def copy_image(ref: str, host: str) -> None:
    """Move a local image of the shared engine into the engine at host (docker save | load)."""
    save = subprocess.Popen(["docker", "save", ref], stdout=subprocess.PIPE)
    subprocess.run(["docker", "load", "-q"], stdin=save.stdout, env=env_for(host), check=True,
                   capture_output=True)
    assert save.wait() == 0, f"docker save {ref} failed"


def engine26_dockerd() -> Path:
    return ENGINE26_ROOT / "usr" / "sbin" / "dockerd"


@contextlib.contextmanager
def private_engine(images: Sequence[str] = (), *, modern: bool = False) -> Iterator[str]:
    """A private Docker daemon with an empty image store and build cache holding only images
    (copied from the shared engine); yields its DOCKER_HOST. modern: Engine 26 of setup.sh on
    the containerd image store, else the distribution's dockerd. The daemon gets a bridge of its
    own (one started with --bridge=none deletes the host's docker0) and no outbound NAT: builds
    in it that need the network use BUILD_NETWORK=host."""
    work = Path(f"/tmp/docker-ros-test-engine-{uuid.uuid4().hex[:8]}")
    bridge = f"drt{work.name[-8:]}"[:15]
    subnet = f"172.30.{(os.getpid() + (1 if modern else 0)) % 250}.1/24"
    subprocess.run(["ip", "link", "add", bridge, "type", "bridge"], check=True)
    subprocess.run(["ip", "addr", "add", subnet, "dev", bridge], check=True)
    subprocess.run(["ip", "link", "set", bridge, "up"], check=True)
    work.mkdir()
    host = f"unix://{work}/docker.sock"
    argv = ["dockerd", "--data-root", str(work / "data"), "--exec-root", str(work / "exec"),
            "--pidfile", str(work / "pid"), "-H", host, "-b", bridge, "--iptables=false",
            "--ip-masq=false"]
    env: Optional[Dict[str, str]] = None
    if modern:
        (work / "daemon.json").write_text(CONTAINERD_STORE)
        argv = [str(engine26_dockerd()), "--config-file", str(work / "daemon.json"), *argv[1:]]
        # dockerd starts the containerd first on PATH: Engine 26's own
        path = f"{ENGINE26_ROOT}/usr/bin:{ENGINE26_ROOT}/usr/sbin:{os.environ.get('PATH', '')}"
        env = {**os.environ, "PATH": path}
    with (work / "dockerd.log").open("wb") as log:
        daemon = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env=env)
    try:
        deadline = time.monotonic() + 60
        while not answers(host):
            if daemon.poll() is not None or time.monotonic() > deadline:
                raise EngineFailed(f"private dockerd did not start:\n"
                                   f"{(work / 'dockerd.log').read_text()}")
            time.sleep(0.5)
        for ref in images:
            copy_image(ref, host)
        yield host
    finally:
        daemon.terminate()
        try:
            daemon.wait(timeout=30)
        except subprocess.TimeoutExpired:
            daemon.kill()
            daemon.wait()
        subprocess.run(["ip", "link", "del", bridge], capture_output=True)
        subprocess.run(["rm", "-rf", "--one-file-system", str(work)], capture_output=True)
