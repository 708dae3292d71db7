"""Docker engines beside the shared one: Engine 26 with the containerd image store (the daemon
scripts/setup.sh starts) and private, empty engines of either generation (a fresh CI runner)."""

from __future__ import annotations

import contextlib
import hashlib
import lzma
import os
import re
import subprocess
import tempfile
import time
import urllib.error
import urllib.request
import uuid
from pathlib import Path
from typing import Any, Dict, Iterator, Mapping, Optional, Sequence

from tests import suitelock
from tests.processes import stop

# Where scripts/setup.sh puts Engine 26 (see CONTRIBUTING.md, "Setting up a machine").
ENGINE26_HOST = "unix:///run/docker-ros-engine26/docker.sock"
ENGINE26_ROOT = Path(os.environ.get("ENGINE26_ROOT", "/opt/docker-ros-engine26"))
CONTAINERD_STORE = '{"features": {"containerd-snapshotter": true}}\n'


class EngineFailed(Exception):
    """A private engine did not start: its log."""


# The two buildx generations scripts/setup.sh installs beside the machine's own: a current one
# (Debian sid's), which the whole suite uses (conftest.py), and Debian stable's 0.13.
BUILDX_DIRS = {
    "current": Path(os.environ.get("MODERN_BUILDX_DIR", "/opt/docker-ros-buildx-modern")),
    "debian": Path(os.environ.get("DEBIAN_BUILDX_DIR", "/opt/docker-ros-buildx-debian")),
}


def buildx_plugin(which: str) -> Path:
    """The docker-buildx plugin of one of BUILDX_DIRS."""
    return BUILDX_DIRS[which] / "cli-plugins" / "docker-buildx"


def buildx_config(folder: Path, which: str) -> Dict[str, str]:
    """A DOCKER_CONFIG in folder whose buildx plugin is buildx_plugin(which) (the docker CLI
    looks in $DOCKER_CONFIG/cli-plugins first); the environment naming it."""
    (folder / "cli-plugins").mkdir(parents=True, exist_ok=True)
    (folder / "cli-plugins" / "docker-buildx").symlink_to(buildx_plugin(which))
    return {"DOCKER_CONFIG": str(folder)}


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


def copy_once(ref: str, host: str) -> None:
    """copy_image, unless the engine at host holds ref already (has_image); once per run
    (suitelock.once: another process of the run copying into an engine waits, then finds it)."""
    with suitelock.once("engine-copy"):
        if not has_image(host, ref):
            copy_image(ref, host)


def engine26_dockerd() -> Path:
    return ENGINE26_ROOT / "usr" / "sbin" / "dockerd"


class Daemon:
    """A private dockerd (made by private_daemon) that can be stopped as `systemctl stop docker`
    stops one (SIGTERM: it stops its containers and exits) and started again on the same data
    root; its DOCKER_HOST is .host."""

    def __init__(self, argv: Sequence[str], env: Optional[Dict[str, str]], work: Path,
                 host: str) -> None:
        self.argv, self.env, self.work, self.host = list(argv), env, work, host
        self.process: Optional[subprocess.Popen] = None

    def start(self) -> None:
        with (self.work / "dockerd.log").open("ab") as log:
            self.process = subprocess.Popen(self.argv, stdout=log, stderr=subprocess.STDOUT,
                                            env=self.env)
        deadline = time.monotonic() + 60
        while not answers(self.host):
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise EngineFailed(f"private dockerd did not start:\n"
                                   f"{(self.work / 'dockerd.log').read_text()}")
            time.sleep(0.5)

    def stop(self) -> None:
        """SIGTERM, and SIGKILL if it has not ended after 30 s."""
        if self.process is None:
            return
        stop(self.process, timeout=30)
        self.process = None


def free_subnet() -> str:
    """A 172.30.X.1/24 of no interface of this machine's (a private engine's bridge: two
    engines on one subnet, in this process or another of the run, would route each other's)."""
    used = subprocess.run(["ip", "-4", "-o", "addr"], capture_output=True, text=True).stdout
    free = [x for x in range(1, 255) if f" 172.30.{x}." not in used]
    return f"172.30.{free[uuid.uuid4().int % len(free)]}.1/24"


@contextlib.contextmanager
def private_daemon(images: Sequence[str] = (), *, modern: bool = False,
                   data_root: Optional[Path] = None) -> Iterator[Daemon]:
    """A private Docker daemon with an empty image store and build cache holding only images
    (copied from the shared engine). modern: Engine 26 of setup.sh on the containerd image
    store, else the distribution's dockerd. The daemon gets a bridge of its own (one started
    with --bridge=none deletes the host's docker0) and no outbound NAT: builds in it that need
    the network use BUILD_NETWORK=host. data_root: where it keeps images and cache (e.g. a
    small file system), else a folder of its own."""
    work = Path(f"/tmp/docker-ros-test-engine-{uuid.uuid4().hex[:8]}")
    bridge = f"drt{work.name[-8:]}"[:15]
    subnet = free_subnet()
    subprocess.run(["ip", "link", "add", bridge, "type", "bridge"], check=True)
    subprocess.run(["ip", "addr", "add", subnet, "dev", bridge], check=True)
    subprocess.run(["ip", "link", "set", bridge, "up"], check=True)
    work.mkdir()
    host = f"unix://{work}/docker.sock"
    argv = ["dockerd", "--data-root", str(data_root or work / "data"),
            "--exec-root", str(work / "exec"), "--pidfile", str(work / "pid"), "-H", host,
            "-b", bridge, "--iptables=false", "--ip-masq=false"]
    env: Optional[Dict[str, str]] = None
    if modern:
        (work / "daemon.json").write_text(CONTAINERD_STORE)
        argv = [str(engine26_dockerd()), "--config-file", str(work / "daemon.json"), *argv[1:]]
        # dockerd starts the containerd first on PATH: Engine 26's own
        path = f"{ENGINE26_ROOT}/usr/bin:{ENGINE26_ROOT}/usr/sbin:{os.environ.get('PATH', '')}"
        env = {**os.environ, "PATH": path}
    daemon = Daemon(argv, env, work, host)
    try:
        daemon.start()
        for ref in images:
            copy_image(ref, host)
        yield daemon
    finally:
        daemon.stop()
        subprocess.run(["ip", "link", "del", bridge], capture_output=True)
        # (its images and cache: a containerd store of a base and a build takes 20 s to remove;
        # nothing waits for it)
        subprocess.Popen(["rm", "-rf", "--one-file-system", str(work)],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True)


@contextlib.contextmanager
def private_engine(images: Sequence[str] = (), *, modern: bool = False,
                   data_root: Optional[Path] = None) -> Iterator[str]:
    """private_daemon's DOCKER_HOST."""
    with private_daemon(images, modern=modern, data_root=data_root) as daemon:
        yield daemon.host


# BuildKit's daemon built from Debian's docker.io source (moby/buildkit cannot be pulled here):
# the image of the docker-container builders the tests create (see tests/docker/buildkit.Dockerfile)
BUILDKIT_DOCKERFILE = Path(__file__).parent / "docker" / "buildkit.Dockerfile"
BUILDKIT_REPOSITORY = "docker-ros-test/buildkit"


# The docker.io source the image is built from while Debian's mirror has it; a stable update
# replaces a revision's files in the pool, and then trixie's current docker.io is taken
# (docker_io_source). The checksums are those of Debian's Sources index.
DOCKER_IO_POOL = "http://deb.debian.org/debian/pool/main/d/docker.io"
DOCKER_IO_SOURCES = "http://deb.debian.org/debian/dists/trixie/main/source/Sources.xz"
DOCKER_IO = {
    "version": "26.1.5+dfsg1", "revision": "9+deb13u1",
    "sha256": {
        "docker.io_26.1.5+dfsg1.orig.tar.xz":
            "e06baad2dbca2a79d3569ee358a4442cf9e550a355872484631860941bee73c9",
        "docker.io_26.1.5+dfsg1.orig-buildkit.tar.xz":
            "3a4a472c237b1caf456aac2cae810fea2b4fae9d0e9e71af5540645b510ff10c",
        "docker.io_26.1.5+dfsg1-9+deb13u1.debian.tar.xz":
            "a579e61d4a60407d52347bb2af497cc16eeb964b9a7ebe3445ea854f5b9d8ee2",
    },
}


def in_pool(name: str) -> bool:
    request = urllib.request.Request(f"{DOCKER_IO_POOL}/{name}", method="HEAD")
    try:
        with urllib.request.urlopen(request, timeout=30):
            return True
    except urllib.error.HTTPError:
        return False


def current_docker_io(sources: str) -> Dict[str, Any]:
    """The last docker.io stanza of a Debian Sources index: its version (upstream and Debian
    revision) and its files' sha256."""
    stanzas = [s for s in sources.split("\n\n") if re.search(r"^Package: docker\.io$", s, re.M)]
    assert stanzas, "trixie's Sources index has no docker.io"
    stanza = stanzas[-1]
    full = re.search(r"^Version: (\S+)$", stanza, re.M)
    sums = re.search(r"^Checksums-Sha256:\n((?: .*\n?)+)", stanza, re.M)
    assert full and sums, stanza[:500]
    version, _, revision = full.group(1).rpartition("-")
    files = {line.split()[2]: line.split()[0] for line in sums.group(1).splitlines()}
    return {"version": version, "revision": revision,
            "sha256": {name: digest for name, digest in files.items()
                       if name.endswith((".orig.tar.xz", ".orig-buildkit.tar.xz",
                                         ".debian.tar.xz"))}}


def docker_io_source() -> Dict[str, Any]:
    """The pinned docker.io source (DOCKER_IO) while the mirror has it, else trixie's current."""
    if all(in_pool(name) for name in DOCKER_IO["sha256"]):
        return DOCKER_IO
    with urllib.request.urlopen(DOCKER_IO_SOURCES, timeout=120) as response:
        return current_docker_io(lzma.decompress(response.read()).decode("utf-8", "replace"))


def buildkit_tag(source: Mapping[str, Any]) -> str:
    """docker-ros-test/buildkit:<Debian docker.io version>-<recipe hash>: another Debian
    version or a changed Dockerfile (another package list) makes another image."""
    text = BUILDKIT_DOCKERFILE.read_text()
    name = re.sub(r"[^\w.-]", "-", f"{source['version']}-{source['revision']}")
    return f"{BUILDKIT_REPOSITORY}:{name}-{hashlib.sha256(text.encode()).hexdigest()[:8]}"


def buildkit_image(host: str, base_image: str) -> str:
    """The buildkit image in the engine at host, built there (on its own builder, from
    base_image, a Debian trixie image that engine holds) unless it exists: about 3 to 5
    minutes on 2 cores (measured 3 min 9 s: apt 61 s, go build 117 s). Its build needs the
    Debian mirror (--network host: Engine 26's bridge has no outbound NAT)."""
    source = docker_io_source()
    tag = buildkit_tag(source)
    if image_content(host, tag):
        return tag
    sums = " ".join(f"{digest}:{name}" for name, digest in sorted(source["sha256"].items()))
    with tempfile.TemporaryDirectory(prefix="docker-ros-test-buildkit-") as context:
        built = subprocess.run(["docker", "buildx", "build", "--builder", "default", "--load",
                                "--network", "host", "--progress", "plain",
                                "--file", str(BUILDKIT_DOCKERFILE), "--build-arg",
                                f"BASE_IMAGE={base_image}",
                                "--build-arg", f"DOCKER_IO_VERSION={source['version']}",
                                "--build-arg", f"DOCKER_IO_REVISION={source['revision']}",
                                "--build-arg", f"DOCKER_IO_SHA256={sums}", "--tag", tag,
                                context],
                               env=env_for(host), capture_output=True, text=True)
    if built.returncode != 0:
        raise RuntimeError(f"building {tag} failed:\n{built.stderr[-6000:]}")
    return tag


def kept_container_builder(host: str, image: str) -> str:
    """A docker-container builder of the engine at host (image: buildkit_image) that is kept
    between runs, as the base images are: its BuildKit keeps its cache for a later run of the
    same code. That needs the same cache keys: BASE_IMAGE is an ARG of the steps, so the
    container-builder test keeps its registry's port from run to run (2026-11-29: its push
    build 45 s instead of 217 to 248 s; the cache mount ids, which follow IMAGE and the
    checkout's path, are not part of the keys). Named after the image, so a new BuildKit makes
    a new one. A builder that must start empty (a fresh CI runner's) is container_builder's."""
    name = f"docker-ros-test-bk-kept-{hashlib.sha256(image.encode()).hexdigest()[:8]}"
    env = env_for(host)
    # (each run has a DOCKER_CONFIG of its own: buildx then knows no builder, and `create`
    # finds the container and state volume of the same name that an earlier run left)
    if subprocess.run(["docker", "buildx", "inspect", name], env=env,
                      capture_output=True).returncode != 0:
        subprocess.run(["docker", "buildx", "create", "--name", name, "--driver",
                        "docker-container", "--driver-opt", f"image={image}", "--driver-opt",
                        "network=host"], env=env, check=True, capture_output=True)
    subprocess.run(["docker", "buildx", "inspect", "--bootstrap", name], env=env, check=True,
                   capture_output=True)
    return name


@contextlib.contextmanager
def container_builder(host: str, image: str) -> Iterator[str]:
    """A buildx docker-container builder (buildkitd in a container of the engine at host,
    image: buildkit_image) with the host's network, so that it reaches a registry on
    127.0.0.1 as a CI runner's builder does (`network=host`); yields its name. Removed
    afterwards with its container and its state volume (`docker buildx rm`)."""
    name = f"docker-ros-test-bk-{uuid.uuid4().hex[:8]}"
    subprocess.run(["docker", "buildx", "create", "--name", name, "--driver", "docker-container",
                    "--driver-opt", f"image={image}", "--driver-opt", "network=host",
                    "--bootstrap"], env=env_for(host), check=True, capture_output=True)
    try:
        yield name
    finally:
        subprocess.run(["docker", "buildx", "rm", name], env=env_for(host),
                       capture_output=True)
