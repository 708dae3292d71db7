"""Shared fixtures: a Docker client, ROS base images built from Debian, a local registry, the
host's CA bundle. Tests that need Docker are marked `@pytest.mark.docker`."""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import secrets
import shutil
import ssl
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, Iterator, Optional, Tuple

import docker
import pytest
import yaml

from docker_ros.host import baseimage
from tests import engines, leftovers, suitelock
from tests.processes import stop
from tests.rosfixtures import free_port
from tests.warmup import Warmup

ROS1_BASE_IMAGE = "docker-ros-test/ros1:bookworm"
ROS2_BASE_IMAGE = "docker-ros-test/ros2:trixie"
ROS1_UBUNTU_BASE_IMAGE = "docker-ros-test/ros1:jammy"
# dockerd treats 127.0.0.0/8 as an insecure (plain http) registry without configuration; a free
# port keeps parallel test runs (and a user's own registry on 5000) apart.
REGISTRY_HOST = "127.0.0.1"
HOST_CA_BUNDLE = Path("/etc/ssl/certs/ca-certificates.crt")
SETUP_HINT = "run `bash scripts/setup.sh` first"
REPO = Path(__file__).resolve().parents[1]
DOCKER_CONFIG_KEY = pytest.StashKey[tuple]()
OWN_ENV = ("DOCKER_CONFIG", "XDG_CACHE_HOME", "PIP_CACHE_DIR")  # (pytest_configure sets them)
DANGLING_KEY = pytest.StashKey[dict]()


def pytest_configure(config: pytest.Config) -> None:
    """The suite runs on a current buildx (scripts/setup.sh installs Debian sid's), the one of
    Docker's own packages, Docker Desktop and CI runners, whatever buildx the machine has: every
    docker command of the run (the tool's, the tests', the CI harnesses') finds it through a
    DOCKER_CONFIG of the run's own, which also keeps the user's logins and contexts out of it.
    test_buildx_versions.py checks that it is current and also builds with Debian's 0.13.
    The records of builds the tool keeps (host/unchanged.py) go to that folder too, not to the
    user's cache folder (pip's cache stays where it was)."""
    if not engines.buildx_plugin("current").is_file():
        return  # every docker test then fails (only_run_on_this_machine): never the machine's own
    folder = Path(tempfile.mkdtemp(prefix="docker-ros-test-docker-config-"))
    config.stash[DOCKER_CONFIG_KEY] = (folder, {name: os.environ.get(name) for name in OWN_ENV})
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    os.environ.setdefault("PIP_CACHE_DIR", str(Path(cache) / "pip"))
    os.environ.update({**engines.buildx_config(folder, "current"),
                       "XDG_CACHE_HOME": str(folder / "cache")})


def pytest_unconfigure(config: pytest.Config) -> None:
    if DOCKER_CONFIG_KEY in config.stash:
        folder, previous = config.stash[DOCKER_CONFIG_KEY]
        shutil.rmtree(folder, ignore_errors=True)
        for name, value in previous.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


TIERS = ("unit", "host", "docker")


def tier(item: pytest.Item) -> str:
    """A test's tier: docker (needs an engine), host (real tools on this machine) or unit."""
    return next((name for name in ("docker", "host") if item.get_closest_marker(name)), "unit")


def worker() -> str:
    """This process's xdist worker id (gw0, gw1, ...), "" in a run of one process."""
    return os.environ.get("PYTEST_XDIST_WORKER", "")


def pytest_sessionstart(session: pytest.Session) -> None:
    """The controller of a run on several processes (`pytest -n`, pytest-xdist, as `nox`
    runs the suite) takes the suite lock before it starts the workers, for all of them
    (suitelock), and removes what a killed run left (only_run_on_this_machine)."""
    if session.config.pluginmanager.hasplugin("dsession"):
        try:
            suitelock.hold_for_workers(3600, say=lambda text: print(text, file=sys.__stderr__))
        except suitelock.Busy as exc:
            raise pytest.UsageError(str(exc)) from None
        remove_killed_runs_images()
        session.config.stash[DANGLING_KEY] = dangling_images()
        share_registries(session.config)


def pytest_collection_finish(session: pytest.Session) -> None:
    for item in session.items:
        item.user_properties.append(("tier", tier(item)))
    docker_items = [item for item in session.items if tier(item) == "docker"]
    # (the first docker test needs the ROS 1 base: foreign_cache_record; --collect-only runs
    # no test, so nothing is made; of a run's workers, the first makes them in the background,
    # the others wait for a fixture's own when they need it: suitelock.once)
    if docker_items and not session.config.getoption("collectonly") and worker() in ("", "gw0"):
        needed = {"ros1_base_image"}.union(
            *(getattr(item, "fixturenames", ()) for item in docker_items))
        for name, job in WARM_JOBS:
            if name in needed:
                WARMUP.start([(name, locked(job))], lane=WARM_LANES.get(name, ""))


def pytest_sessionfinish(session: pytest.Session) -> None:
    """The warm-up stops; the controller of a run's processes removes what they left
    (this_runs_images), below its temporary folder, which holds theirs."""
    WARMUP.stop()
    if REGISTRIES_KEY in session.config.stash:
        session.config.stash[REGISTRIES_KEY].close()
    if DANGLING_KEY in session.config.stash:
        remove_this_runs_images(session.config._tmp_path_factory.getbasetemp(),  # type: ignore
                                session.config.stash[DANGLING_KEY])


def lock_the_suite() -> None:
    suitelock.hold(3600, say=lambda text: print(text, file=sys.__stderr__))


def locked(job: Callable[[], object]) -> Callable[[], object]:
    """job, once this run holds the suite lock (a run that waits for another builds nothing)."""
    def run() -> object:
        lock_the_suite()
        return job()
    return run


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """Where the time went: the seconds of each tier and of the 15 slowest modules (setup,
    call and teardown of their tests), so that the next person sees what a change costs."""
    per_tier: dict = {}
    per_module: dict = {}
    for reports in terminalreporter.stats.values():
        for report in reports:
            if not isinstance(report, pytest.TestReport):
                continue
            name = dict(report.user_properties).get("tier", "unit")
            per_tier[name] = per_tier.get(name, 0.0) + report.duration
            module = report.nodeid.split("::", 1)[0]
            per_module[module] = per_module.get(module, 0.0) + report.duration
    if not per_tier:
        return
    terminalreporter.write_sep("=", "time per tier")
    terminalreporter.write_line("  ".join(
        f"{name}: {per_tier.get(name, 0.0) / 60:.1f} min" for name in TIERS))
    terminalreporter.write_sep("-", "time per module (slowest 15)")
    for module, seconds in sorted(per_module.items(), key=lambda kv: -kv[1])[:15]:
        terminalreporter.write_line(f"{seconds / 60:6.1f} min  {module}")


def pytest_report_header() -> str:
    return f"docker buildx: {buildx_version() if shutil.which('docker') else 'no docker CLI'}"


def buildx_version(env: Optional[dict] = None) -> str:
    """`docker buildx version`'s line (env: the environment, default this process's)."""
    proc = subprocess.run(["docker", "buildx", "version"], capture_output=True, text=True, env=env)
    return (proc.stdout or proc.stderr).strip()


@pytest.fixture(scope="session")
def docker_client() -> Iterator[docker.DockerClient]:
    """A docker SDK client (`docker.from_env()`) to a daemon that answers."""
    try:
        client = docker.from_env()
        client.ping()
    except docker.errors.DockerException as exc:
        pytest.fail(f"no Docker daemon answers ({exc}); {SETUP_HINT}")
    yield client
    client.close()


# Modules whose tests need what the warm-up takes longest to make (the arm64 base, the BuildKit
# image)
LATE_FIXTURES = ("ros1_arm64_base_image", "buildkit_image")


# Minutes the slowest docker modules took in a full run (CONTRIBUTING.md, "Warm engine", has
# the last figures): a run on several processes starts them first, longest first, so that no
# long one runs alone at its end
MINUTES = {"tests/ci/test_multiarch.py": 8.5, "tests/docker/test_engine26.py": 9.7,
           "tests/ci/test_multiarch_builder.py": 3.0,
           "tests/ci/test_github_action.py": 5.6, "tests/docker/test_faults.py": 2.4,
           "tests/docker/test_lock.py": 2.1, "tests/docker/test_slim.py": 2.0,
           "tests/docker/test_in_container.py": 1.9, "tests/ci/test_gitlab_template.py": 1.9,
           "tests/docker/test_buildx_versions.py": 1.8, "tests/docker/test_image_build.py": 1.8,
           "tests/docker/test_secrets.py": 1.5, "tests/docker/test_fast_rebuilds.py": 1.4}


def module_rank(items: list, workers: bool = False) -> Dict[str, Tuple[int, float]]:
    """Each module's place in the run: unit, host, docker, and then, in a run of one process,
    docker modules that need what the warm-up makes last, so that it is made while the others
    run; in a run on several processes (workers), the docker modules longest first (MINUTES).
    A module's tests stay together (its fixtures are made once) and in their order."""
    rank: Dict[str, Tuple[int, float]] = {}
    for item in items:
        own = TIERS.index(tier(item))
        module = item.nodeid.split("::", 1)[0]
        if own == 2 and not workers and any(name in item.fixturenames
                                            for name in LATE_FIXTURES):
            own = 3
        rank[module] = max(rank.get(module, (0, 0.0)), (own, -MINUTES.get(module, 0.0)))
    return rank


def pytest_collection_modifyitems(items: list) -> None:
    """Unit and host tests first, then the docker modules (module_rank). Every docker test runs
    while this run is the machine's only one, after the foreign cache record exists, and before
    the images the run leaves are removed."""
    rank = module_rank(items, workers=bool(worker()))
    items.sort(key=lambda item: rank[item.nodeid.split("::", 1)[0]])
    for item in items:
        if item.get_closest_marker("docker"):
            for name in ("this_runs_images", "foreign_cache_record", "only_run_on_this_machine"):
                if name not in item.fixturenames:
                    item.fixturenames.insert(0, name)


@pytest.fixture(scope="session")
def only_run_on_this_machine() -> Iterator[None]:
    """Waits (up to an hour) for another run with docker tests on this machine (suitelock);
    then removes what an earlier run that was killed left named after its registries. Without
    the current buildx of setup.sh every docker test fails, naming it (the unit and host tests
    need none)."""
    if not engines.buildx_plugin("current").is_file():
        pytest.fail(f"no current buildx at {engines.buildx_plugin('current')}; {SETUP_HINT}")
    try:
        lock_the_suite()  # (the warm-up thread or the run's controller may hold it: at once)
    except suitelock.Busy as exc:
        pytest.fail(str(exc))
    if not worker():  # (the controller of a run's workers did it before it started them)
        remove_killed_runs_images()
    yield


def remove_killed_runs_images() -> None:
    for host in (None, engines.ENGINE26_HOST):
        with ENGINE_DOWN, engine_client(host) as client:
            leftovers.remove_killed_runs_images(client)


# An engine that does not answer: the docker SDK's errors, and requests' (OSError) for a socket
# nobody listens on.
ENGINE_DOWN = contextlib.suppress(docker.errors.DockerException, OSError)


@pytest.fixture(scope="session")
def this_runs_images(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """At the end of the run, on the shared engine and on Engine 26: the imports images of the
    repositories this run made (they are under pytest's temporary folder) and the images its
    rebuilds untagged (see leftovers.py). Another repository's stay; an engine that did not
    answer at the start is left alone. In a run on several processes, their controller does it
    when all have ended (an image another process is building is dangling until tagged)."""
    if worker():
        yield
        return
    before = dangling_images()
    yield
    remove_this_runs_images(tmp_path_factory.getbasetemp(), before)


def dangling_images() -> Dict[Optional[str], set]:
    """leftovers.untagged of the shared engine (None) and Engine 26, of those that answer."""
    before = {}
    for host in (None, engines.ENGINE26_HOST):
        with ENGINE_DOWN, engine_client(host) as client:
            before[host] = leftovers.untagged(client)
    return before


def remove_this_runs_images(root: Path, before: Dict[Optional[str], set]) -> None:
    """leftovers.remove_run_images on each engine of before (dangling_images), for the
    repositories below root and below STABLE_ROOT (stable_folder)."""
    for host, dangling in before.items():
        with ENGINE_DOWN, engine_client(host) as client:
            leftovers.remove_run_images(client, (root, STABLE_ROOT), dangling)


def engine_client(host: Optional[str]) -> contextlib.closing:
    """A client of the shared engine (None) or of host, closed at the end of the block."""
    return contextlib.closing(docker.DockerClient(base_url=host) if host else docker.from_env())


@pytest.fixture(scope="session")
def foreign_cache_record(
    ros1_base_image: str, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[str]:
    """A BuildKit cache record that stands for another project's, made before any docker test
    and checked after the last one (this fixture's teardown, whatever ran and in which order):
    the suite must leave it alone, as the engine is shared and the tool and its tests remove
    only what they made. A missing record is an error of the run. Yields its description."""
    marker = f"/docker-ros-test-foreign-{uuid.uuid4().hex[:12]}"
    context = tmp_path_factory.mktemp("foreign")
    (context / "Dockerfile").write_text(
        f"FROM {ros1_base_image}\nRUN --mount=type=cache,id={marker[1:]},target={marker} "
        f"touch {marker}/x\n")
    built = subprocess.run(["docker", "buildx", "build", "--output", "type=cacheonly",
                            str(context)], capture_output=True, text=True)
    assert built.returncode == 0, built.stderr
    assert cache_mount_id(marker), "the foreign cache record was not created"
    yield marker
    gone = not cache_mount_id(marker)
    # (the cache mount and the layer of the RUN that used it: both are this fixture's)
    for record in cache_record_ids(marker):
        subprocess.run(["docker", "buildx", "prune", "-f", "--filter", f"id={record}"],
                       capture_output=True)
    if gone:
        pytest.fail("a BuildKit cache record this suite did not create is gone: something pruned "
                    "the shared engine's build cache (never `docker builder prune -a`)")


def cache_record_ids(marker: str) -> dict:
    """IDs of the BuildKit cache records whose description holds marker -> their description."""
    du = subprocess.run(["docker", "buildx", "du", "--verbose"], capture_output=True, text=True)
    found, record = {}, ""
    for line in du.stdout.splitlines():
        if line.startswith("ID:"):
            record = line.split()[-1]
        elif line.startswith("Description:") and marker in line:
            found[record] = line.split(":", 1)[1].strip()
    return found


def cache_mount_id(marker: str) -> str:
    """ID of the cache mount record (`RUN --mount=type=cache`) at marker ('' if none)."""
    return next((record for record, description in cache_record_ids(marker).items()
                 if description.startswith(f"cached mount {marker} ")), "")


# Each made once per run (suitelock.once: a second process of the run waits for the first,
# then finds the image made)
@suitelock.made_once("ros1-base")
def make_ros1() -> str:
    return baseimage.bootstrap("ros1", tag=ROS1_BASE_IMAGE)


@suitelock.made_once("ros1-arm64-base")
def make_ros1_arm64() -> str:
    return baseimage.bootstrap("ros1", tag=ROS1_BASE_IMAGE, platform="arm64")


@suitelock.made_once("ros2-base")
def make_ros2() -> str:
    return baseimage.bootstrap("ros2", tag=ROS2_BASE_IMAGE)


@suitelock.made_once("ros1-ubuntu-base")
def make_ros1_ubuntu() -> str:
    bundle = Path(ssl.get_default_verify_paths().openssl_cafile)
    return baseimage.bootstrap("ros1-ubuntu", tag=ROS1_UBUNTU_BASE_IMAGE,
                               ca_bundle=bundle if bundle.is_file() else None)


@suitelock.made_once("buildkit-image")
def make_buildkit_image() -> str:
    if not engines.answers(engines.ENGINE26_HOST):
        raise RuntimeError(f"no Engine 26 answers at {engines.ENGINE26_HOST}; {SETUP_HINT}")
    engines.copy_once(make_ros2(), engines.ENGINE26_HOST)
    return engines.buildkit_image(engines.ENGINE26_HOST, ROS2_BASE_IMAGE)


# What the warm-up makes (tests/warmup.py), in the order the run needs it: fixture -> job.
# The arm64 base has a lane of its own (WARM_LANES) and starts at once: emulated, it is the
# longest wait of an empty engine's run (test_multiarch*), and it needs no other job. The
# BuildKit image (the container builders) comes before the Ubuntu base, which one module needs.
WARM_JOBS = (("ros1_base_image", make_ros1), ("ros2_base_image", make_ros2),
             ("buildkit_image", make_buildkit_image),
             ("ros1_ubuntu_base_image", make_ros1_ubuntu),
             ("ros1_arm64_base_image", make_ros1_arm64))
WARM_LANES = {"ros1_arm64_base_image": "arm64"}
WARMUP = Warmup()


def warm(fixture: str) -> str:
    """What the warm-up made for fixture (WARM_JOBS), once it is there."""
    return WARMUP.result(fixture, dict(WARM_JOBS)[fixture])


@pytest.fixture(scope="session")
def ros1_base_image(docker_client: docker.DockerClient) -> str:
    """Tag of a Debian bookworm image with ROS 1 from Debian (in /usr); built once, then reused."""
    return warm("ros1_base_image")


@pytest.fixture(scope="session")
def ros1_arm64_base_image(ros1_base_image: str) -> str:
    """The arm64 image of the ROS 1 base: `<ROS1_BASE_IMAGE>-arm64` (bootstrap tags another
    architecture's image so, and a build for arm64 with BASE_IMAGE=ROS1_BASE_IMAGE finds it);
    built under QEMU once (5 to 10 minutes, in the warm-up's background), then reused while its
    recipe is unchanged."""
    return warm("ros1_arm64_base_image")


@pytest.fixture(scope="session")
def ros2_base_image(docker_client: docker.DockerClient) -> str:
    """Tag of a Debian trixie image with ROS 2 build tooling (ament, colcon); built once."""
    return warm("ros2_base_image")


@pytest.fixture(scope="session")
def ros1_ubuntu_base_image(docker_client: docker.DockerClient) -> str:
    """Tag of an Ubuntu 22.04 image with Ubuntu's ROS 1 (in /usr), colcon and vcstool from
    PyPI; built once (about a minute), then reused. The machine's CA bundle is the pip's: where
    a TLS-intercepting proxy re-signs PyPI, the machine trusts its CA."""
    return warm("ros1_ubuntu_base_image")


@dataclass(frozen=True)
class AuthRegistry:
    """A registry that answers only with a user and password (htpasswd), as a CI's does."""

    address: str
    user: str
    password: str

    @property
    def auth(self) -> dict:
        """Engine API credentials (docker SDK auth_config)."""
        return {"username": self.user, "password": self.password}


# The run's two registries, a plain one and one that wants a login (REGISTRIES), serve all its
# processes and modules; each module pushes under repository names of its own. One for the run,
# not one per module: Engine 20.10 compresses the layers it pushes anew for each registry
# (within one, it mounts them from a repository that has them), and the ROS bases are most of
# every push. Their ports are the same in every run where they are free (stable_port): the
# images pushed there hold the address in their names, and so do the cache keys of the builds
# FROM them (a private base) and docker-ros's build cache ids (see stable_folder), which the
# engines keep from run to run.
REGISTRIES = "DOCKER_ROS_TEST_REGISTRIES"  # (a file naming them, for a run's processes)
REGISTRIES_KEY = pytest.StashKey[contextlib.ExitStack]()


@contextlib.contextmanager
def serve_registries(work: Path) -> Iterator[Tuple[str, AuthRegistry]]:
    """The plain registry and the one with a login, their storage and logs below work."""
    with serve_registry(work / "plain", port=stable_port("docker-ros-test-registry")) as plain, \
            serve_auth_registry(work / "login",
                                port=stable_port("docker-ros-test-login-registry")) as login:
        yield plain, login


def share_registries(config: pytest.Config) -> None:
    """The controller of a run's processes serves its registries before it starts them and
    names them in the file REGISTRIES points to (only its owner reads it: it holds the
    password); pytest_sessionfinish stops them. Without docker-registry or htpasswd, the
    processes' fixtures fail, saying what is missing."""
    if not (shutil.which("docker-registry") and shutil.which("htpasswd")):
        return
    work = config._tmp_path_factory.getbasetemp() / "registries"  # type: ignore[attr-defined]
    stack = contextlib.ExitStack()
    try:
        plain, login = stack.enter_context(serve_registries(work))
    except pytest.fail.Exception as exc:
        raise pytest.UsageError(str(exc)) from None
    config.stash[REGISTRIES_KEY] = stack
    named = work / "registries.json"
    named.touch(mode=0o600)
    stack.callback(named.unlink)
    stack.callback(os.environ.pop, REGISTRIES, None)
    named.write_text(json.dumps({"plain": plain, "login": dataclasses.asdict(login)}))
    os.environ[REGISTRIES] = str(named)


@pytest.fixture(scope="session")
def registries(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Tuple[str, AuthRegistry]]:
    """The run's registries: its controller's (share_registries), or in a run of one process
    its own."""
    if os.environ.get(REGISTRIES):
        named = json.loads(Path(os.environ[REGISTRIES]).read_text())
        yield named["plain"], AuthRegistry(**named["login"])
        return
    with serve_registries(tmp_path_factory.mktemp("registries")) as both:
        yield both


@pytest.fixture(scope="session")
def local_registry(registries: Tuple[str, AuthRegistry]) -> str:
    """The address of a private `docker-registry` on 127.0.0.1, this run's (registries).
    Push under a repository name of the test's module: the run's modules share it."""
    return registries[0]


@pytest.fixture(scope="session")
def auth_registry(registries: Tuple[str, AuthRegistry]) -> AuthRegistry:
    """A `docker-registry` that requires authentication, this run's (registries); its password
    is new in every run (tests search logs and command lines for it). Push under a repository
    name of the test's module: the run's modules share it."""
    return registries[1]


STABLE_ROOT = Path(tempfile.gettempdir()) / "docker-ros-test-stable"


def stable_folder(name: str) -> Path:
    """An empty folder at the same path in every run (STABLE_ROOT/name; what an earlier run
    left there is removed first, the imports images of its repositories at the run's end).
    docker-ros's colcon build cache id holds the build context's path and the image name
    (buildplan.cache_id), and Engine 20.10's BuildKit keys the build step on the cache id: a
    repository at a new path in each run is compiled again in each run (under QEMU for arm64:
    25 s for one Python package)."""
    folder = STABLE_ROOT / name
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    return folder


@contextlib.contextmanager
def serve_auth_registry(work: Path, port: int = 0) -> Iterator[AuthRegistry]:
    """serve_registry with a login (user docker-ros-ci, a new password)."""
    htpasswd = shutil.which("htpasswd")
    if htpasswd is None:
        pytest.fail(f"htpasswd (Debian package apache2-utils) is not installed; {SETUP_HINT}")
    work.mkdir(parents=True, exist_ok=True)
    user, password = "docker-ros-ci", f"pw-{secrets.token_hex(16)}"
    entry = subprocess.run([htpasswd, "-iBn", user], input=password, capture_output=True,
                           text=True, check=True).stdout
    (work / "htpasswd").write_text(entry)
    auth = {"htpasswd": {"realm": "docker-ros-test", "path": str(work / "htpasswd")}}
    with serve_registry(work, auth=auth, port=port) as address:
        yield AuthRegistry(address, user, password)


@contextlib.contextmanager
def serve_registry(work: Path, auth: Optional[dict] = None, port: int = 0) -> Iterator[str]:
    """A `docker-registry` serving work/storage; on port when given, else on a free one."""
    executable = shutil.which("docker-registry")
    if executable is None:
        pytest.fail(f"docker-registry (Debian package) is not installed; {SETUP_HINT}")
    work.mkdir(parents=True, exist_ok=True)
    address = f"{REGISTRY_HOST}:{port or free_port()}"
    config = {
        "version": 0.1,
        "log": {"level": "warn"},
        "storage": {
            "filesystem": {"rootdirectory": str(work / "storage")},
            "delete": {"enabled": True},
        },
        "http": {"addr": address},
        **({"auth": auth} if auth else {}),
    }
    (work / "config.yml").write_text(yaml.safe_dump(config))
    log_path = work / "registry.log"
    with log_path.open("wb") as log:
        server = subprocess.Popen(
            [executable, "serve", str(work / "config.yml")], stdout=log, stderr=subprocess.STDOUT
        )
    try:
        wait_for_registry(address, server, log_path)
        yield address
    finally:
        stop(server, timeout=10)
        # Images named after this registry (a port of this run) were made by the tests; its
        # storage is of no use any more (a few GB: the run's folder is kept for its logs)
        with ENGINE_DOWN, engine_client(None) as client:
            leftovers.remove_registry_images(client, address)
        shutil.rmtree(work / "storage", ignore_errors=True)


def stable_port(name: str) -> int:
    """The same free port in every run for name (a registry whose address is in the names of
    the images a kept BuildKit caches), or any free port when that one is taken."""
    return free_port(20000 + int(hashlib.sha256(name.encode()).hexdigest(), 16) % 20000)


def wait_for_registry(address: str, server: subprocess.Popen, log_path: Path) -> None:
    # No proxy for a loopback address, whatever the environment says.
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        if server.poll() is not None:
            pytest.fail(f"docker-registry exited with {server.returncode}:\n{log_path.read_text()}")
        try:
            with opener.open(f"http://{address}/v2/", timeout=2) as answer:
                if answer.status == 200:
                    return
        except urllib.error.HTTPError as exc:
            if exc.code == 401:  # it answers, and wants credentials
                return
            time.sleep(0.2)
        except OSError:
            time.sleep(0.2)
    pytest.fail(f"docker-registry did not answer on {address} within 15 s:\n{log_path.read_text()}")


@pytest.fixture(scope="session")
def host_ca_bundle() -> Path:
    """The host's CA bundle (it includes any TLS-intercepting proxy's CA the host trusts)."""
    if not HOST_CA_BUNDLE.is_file():
        pytest.fail(f"{HOST_CA_BUNDLE} not found (package ca-certificates); {SETUP_HINT}")
    return HOST_CA_BUNDLE


@pytest.fixture
def empty_engine(ros1_base_image: str) -> Iterator[str]:
    """A private Docker daemon (the shared engine's generation) with an empty image store and
    build cache (a fresh CI machine) holding only the ROS 1 base image; yields its DOCKER_HOST.
    The shared engine's cache is never pruned (see tests.engines.private_engine)."""
    if shutil.which("dockerd") is None:
        pytest.fail(f"dockerd is not installed; {SETUP_HINT}")
    try:
        with engines.private_engine([ros1_base_image]) as host:
            yield host
    except engines.EngineFailed as exc:
        pytest.fail(str(exc))


@pytest.fixture
def empty_engine26(ros1_base_image: str) -> Iterator[str]:
    """empty_engine of Engine 26 on the containerd image store (a fresh modern CI runner)."""
    if not engines.engine26_dockerd().is_file():
        pytest.fail(f"Engine 26 is not installed at {engines.ENGINE26_ROOT}; {SETUP_HINT}")
    try:
        with engines.private_engine([ros1_base_image], modern=True) as host:
            yield host
    except engines.EngineFailed as exc:
        pytest.fail(str(exc))


@pytest.fixture(scope="session")
def engine26(ros1_base_image: str) -> str:
    """The DOCKER_HOST of Engine 26 with the containerd image store that scripts/setup.sh
    starts beside the shared engine, holding the ROS 1 base image (copied once)."""
    if not engines.answers(engines.ENGINE26_HOST):
        pytest.fail(f"no Engine 26 answers at {engines.ENGINE26_HOST}; {SETUP_HINT}")
    engines.copy_once(ros1_base_image, engines.ENGINE26_HOST)
    return engines.ENGINE26_HOST


@pytest.fixture(scope="session")
def buildkit_image(engine26: str, ros2_base_image: str) -> str:
    """The image of a buildx docker-container builder on Engine 26 (tests.engines
    .buildkit_image: BuildKit from Debian's source, as moby/buildkit cannot be pulled here),
    built once per machine (3 to 10 minutes, in the warm-up's background), then reused by its
    tag."""
    return warm("buildkit_image")


@pytest.fixture(scope="session")
def kept_builder(engine26: str, buildkit_image: str) -> str:
    """The docker-container builder on Engine 26 that is kept between runs (tests.engines
    .kept_container_builder); its name."""
    with suitelock.once("kept-builder"):
        return engines.kept_container_builder(engine26, buildkit_image)


@pytest.fixture(scope="session")
def docker_ros_wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """This checkout as a wheel, built once per run: CI jobs install it (a pip requirement as
    DOCKER_ROS_PIP_SPEC allows) in seconds, and jobs that run at once do not build in the same
    source tree (pip builds a local folder in place: two builds at once break each other)."""
    folder = tmp_path_factory.mktemp("wheel")
    with suitelock.once(suitelock.SOURCE_TREE_BUILD):
        subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet",
                        "--disable-pip-version-check", "-w", str(folder), str(REPO)], check=True)
    return next(folder.glob("docker_ros-*.whl"))
