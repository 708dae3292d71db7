"""Faults of the machine, made for real: an engine whose data root fills up during a build, a
git server that is gone when the build clones from it, an apt proxy that is gone, the engine's
socket gone during a dev shell, the engine stopped during a push and during a slim run. The
last lines of output say what happened and what to do, nothing is tagged or pushed, and the
same command works once the fault is gone."""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
import uuid
from contextlib import suppress
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Callable, Iterator, List, Optional

import pytest

from tests import engines
from tests.docker.buildhelp import docker_ros, docker_ros_started, write_env
from tests.rosfixtures import free_port, git_daemon, make_git_repo, make_package, write_repos

pytestmark = pytest.mark.docker

# The engine's file system: room for the base image (about 550 MB) and a build's layers;
# filled up to leave LEFT, less than prepare's apt-get install needs (the fault of issue 47).
DISK_SIZE = "2500M"
LEFT = 100 * 1000 * 1000


@pytest.fixture(scope="module")
def small_disk() -> Iterator[Path]:
    """A loop-mounted ext4 file system of DISK_SIZE (a sparse file), removed afterwards."""
    name = f"docker-ros-test-disk-{uuid.uuid4().hex[:8]}"
    image, mount = Path("/tmp") / f"{name}.img", Path("/tmp") / name
    subprocess.run(["truncate", "-s", DISK_SIZE, str(image)], check=True)
    try:
        subprocess.run(["mkfs.ext4", "-q", "-F", "-m", "0", str(image)], check=True)
        mount.mkdir()
        subprocess.run(["mount", "-o", "loop", str(image), str(mount)], check=True)
        try:
            yield mount
        finally:
            subprocess.run(["umount", str(mount)], check=True)
    finally:
        if mount.is_dir():
            mount.rmdir()
        image.unlink()


# The image of the module's private engine: built by the full-disk test (its build after the
# disk had room again), pushed and slimmed by the tests that stop that engine.
DISK_IMAGE = "docker-ros-test/faults-disk:latest"


@dataclass
class DiskEngine:
    """The module's private engine (data root on small_disk) and its project."""

    daemon: engines.Daemon
    data_root: Path
    project: Path

    @property
    def host(self) -> str:
        return self.daemon.host


@pytest.fixture(scope="module")
def module_engine(ros1_base_image: str, small_disk: Path,
                  tmp_path_factory: pytest.TempPathFactory) -> Iterator[DiskEngine]:
    """A private engine whose data root is on small_disk, holding the ROS 1 base image, and a
    project of one package (IMAGE DISK_IMAGE; COMMAND runs until stopped, for slim's trace)."""
    if shutil.which("dockerd") is None:
        pytest.fail("dockerd is not installed; run scripts/setup.sh")
    project = tmp_path_factory.mktemp("faults-disk")
    make_package(project / "pkg", "pkg")
    write_env(project, BASE_IMAGE=ros1_base_image, IMAGE=DISK_IMAGE, BUILD_NETWORK="host",
              TARGET="run", COMMAND="sleep 600")
    data_root = small_disk / "docker"
    with engines.private_daemon([ros1_base_image], data_root=data_root) as daemon:
        yield DiskEngine(daemon, data_root, project)


@pytest.fixture
def disk_engine(module_engine: DiskEngine) -> DiskEngine:
    """module_engine, answering (a test that failed with it stopped started it not again)."""
    if module_engine.daemon.process is None:
        module_engine.daemon.start()
    return module_engine


def fill(mount: Path, left: int) -> Path:
    """A file taking all room on mount but `left` bytes."""
    filler = mount / "filler"
    subprocess.run(["fallocate", "-l", str(shutil.disk_usage(mount).free - left), str(filler)],
                   check=True)
    return filler


def engine_has(host: Optional[str], ref: str) -> bool:
    """Whether the engine at host (None: the shared one) has the image ref."""
    return subprocess.run(["docker", "image", "inspect", ref],
                          env=engines.env_for(host) if host else None,
                          capture_output=True).returncode == 0


@pytest.fixture
def own_image() -> Iterator[str]:
    """A tag of this test's own on the shared engine, removed afterwards (with its dev image)."""
    image = f"docker-ros-test/faults:{uuid.uuid4().hex[:8]}"
    yield image
    subprocess.run(["docker", "image", "rm", image, f"{image}-dev"], capture_output=True)


def fails_then_works(project: Path, image: str, restore: Callable[[], object],
                     host: Optional[str] = None) -> List[str]:
    """The run image of project built on the engine at host (None: the shared one): the build
    fails and tags nothing; after restore() (the fault gone) the same build works. The failed
    build's final message, its lines."""
    env = {"DOCKER_HOST": host} if host else {}
    failed = docker_ros(project, "build", "--target", "run", env=env)
    assert failed.returncode != 0, failed.stdout[-4000:]
    assert "Traceback" not in failed.stdout
    assert not engine_has(host, image)
    restore()
    rebuilt = docker_ros(project, "build", "--target", "run", env=env)
    assert rebuilt.returncode == 0, rebuilt.stdout[-4000:]
    assert engine_has(host, image)
    final = failed.stdout.strip().splitlines()
    return final[max(i for i, line in enumerate(final)
                     if line.startswith("docker-ros build: ")):]


def test_a_full_engine_disk_is_named_with_its_data_root_and_room(
    disk_engine: DiskEngine, small_disk: Path
) -> None:
    """An engine whose data root has about 100 MB left (a loop-mounted file system filled
    up): the build's last lines name the full disk, the engine's data root and its room, and
    what to do; after the filler is removed the same build works."""
    filler = fill(small_disk, LEFT)
    try:
        final = fails_then_works(disk_engine.project, DISK_IMAGE, filler.unlink,
                                 disk_engine.host)
    finally:
        filler.unlink(missing_ok=True)
    data_root = disk_engine.data_root
    print("\n".join(final))
    assert "failed in step prepare: failed with exit code 100: apt-get " in final[0], final
    assert "No space left on device" in final[1] or "enough free space" in final[1], final
    disk = final[-1]
    assert disk.startswith(f"  the disk is full: the engine's data root {data_root} ("), final
    assert re.search(r"/docker \(\d+ (bytes|kB|MB) free\)", disk), disk
    assert "docker system df" in disk and "docker-ros removes nothing" in disk, disk


def test_a_git_server_that_is_gone_is_named_with_its_url(
    ros1_base_image: str, own_image: str, tmp_path: Path
) -> None:
    """A git daemon that is not running when the clone step imports from it: the last line
    names the repository, its URL and the refused connection; once it serves, the same build
    works."""
    make_package(tmp_path / "libs" / "up_a", "up_a")
    remotes = tmp_path / "remotes"
    make_git_repo(tmp_path / "libs", {}, bare_copy_to=remotes / "libs.git")
    port = free_port()
    url = f"git://127.0.0.1:{port}/libs.git"
    repo = tmp_path / "repo"
    make_package(repo / "app", "app")
    write_repos(repo / ".repos", {"libs": {"url": url, "version": "main"}})
    write_env(repo, BASE_IMAGE=ros1_base_image, IMAGE=own_image, BUILD_NETWORK="host",
              COMMAND="up_a_node")
    daemons: List[subprocess.Popen] = []
    try:  # (the server is not running at first)
        final = fails_then_works(repo, own_image,
                                 lambda: daemons.append(git_daemon(remotes, port)))
    finally:
        for daemon in daemons:
            daemon.terminate()
            daemon.wait(timeout=30)
    print("\n".join(final))
    assert "failed in step clone" in final[-1] and f"'libs' ({url} @ main)" in final[-1], final
    assert "Connection refused" in final[-1] and "is the server running?" in final[-1], final


class Forward(BaseHTTPRequestHandler):
    """An HTTP proxy for apt: each GET of an absolute URL fetched from its server."""

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        try:
            with urllib.request.urlopen(self.path, timeout=120) as upstream:
                body, status = upstream.read(), upstream.status
        except urllib.error.HTTPError as refused:
            body, status = b"", refused.code
        self.send_response(status)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args: object) -> None:
        pass


def forward(port: int) -> ThreadingHTTPServer:
    """The Forward proxy serving at 127.0.0.1:port."""
    server = ThreadingHTTPServer(("127.0.0.1", port), Forward)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def test_an_apt_proxy_that_is_gone_is_named_with_the_url_apt_could_not_fetch(
    ros1_base_image: str, own_image: str, tmp_path: Path
) -> None:
    """A hook that installs a package through an apt proxy (a mirror's stand-in) that is not
    running: the last lines name apt's errors, the URL it could not fetch and the proxy that
    refused; once the proxy serves, the same build works."""
    port = free_port()
    make_package(tmp_path / "app", "app")
    # (archives of its own: the build's apt cache mount may hold jq from the run that worked)
    apt = (f"apt-get -o Acquire::http::Proxy=http://127.0.0.1:{port} "
           "-o Dir::Cache::archives=/tmp/archives/")
    (tmp_path / "docker").mkdir()
    (tmp_path / "docker" / "custom.sh").write_text(
        f"mkdir -p /tmp/archives/partial\n{apt} update\n"
        f"{apt} install -y --no-install-recommends jq\nrm -rf /tmp/archives\n")
    write_env(tmp_path, BASE_IMAGE=ros1_base_image, IMAGE=own_image, BUILD_NETWORK="host",
              COMMAND="jq --version")
    servers: List[ThreadingHTTPServer] = []
    try:  # (the proxy is not running at first)
        final = fails_then_works(tmp_path, own_image, lambda: servers.append(forward(port)))
    finally:
        for server in servers:
            server.shutdown()
            server.server_close()
    print("\n".join(final))
    assert "failed in step custom: " in final[0] and "exit code 100" in final[0], final
    assert any(line.startswith("  E: ") for line in final[1:-1]), final
    assert final[-1].startswith("  could not reach http://deb.debian.org/debian/"), final
    assert f"(Could not connect to 127.0.0.1:{port}: Connection refused)" in final[-1], final


class SocketProxy:
    """A unix socket forwarding every connection to the engine's: DOCKER_HOST for docker-ros,
    and stopped (all its connections cut) to make the engine go away from the client's side
    while the engine and what runs in it stay."""

    def __init__(self, path: Path, target: str = "/var/run/docker.sock") -> None:
        self.path, self.target = path, target
        self.open: List[socket.socket] = []
        self.listener = socket.socket(socket.AF_UNIX)

    def start(self) -> SocketProxy:
        self.listener = socket.socket(socket.AF_UNIX)
        self.listener.bind(str(self.path))
        self.listener.listen(64)
        threading.Thread(target=self.accept, daemon=True).start()
        return self

    def accept(self) -> None:
        with suppress(OSError):
            while True:
                client, _ = self.listener.accept()
                engine = socket.socket(socket.AF_UNIX)
                engine.connect(self.target)
                self.open += [client, engine]
                for source, sink in ((client, engine), (engine, client)):
                    threading.Thread(target=pump, args=(source, sink), daemon=True).start()

    def stop(self) -> None:
        self.listener.close()
        self.path.unlink()
        for connection in self.open:
            with suppress(OSError):
                connection.shutdown(socket.SHUT_RDWR)
            connection.close()
        self.open.clear()


def pump(source: socket.socket, sink: socket.socket) -> None:
    with suppress(OSError):
        while True:
            data = source.recv(65536)
            if not data:
                sink.shutdown(socket.SHUT_WR)
                return
            sink.sendall(data)


def test_an_engine_gone_during_a_dev_shell_is_named(
    ros1_base_image: str, own_image: str, tmp_path: Path
) -> None:
    """The engine's socket cut while a dev shell runs: the last line says that the connection
    to the engine was lost and that rerunning is safe, with no traceback; once it answers
    again, the same dev shell works."""
    project, name = tmp_path / "project", f"docker-ros-test-faults-{uuid.uuid4().hex[:8]}"
    make_package(project / "app", "app")
    write_env(project, BASE_IMAGE=ros1_base_image, IMAGE=own_image, BUILD_NETWORK="host")
    proxy = SocketProxy(tmp_path / "docker.sock").start()
    env = {"DOCKER_HOST": f"unix://{proxy.path}"}
    shell = subprocess.Popen([sys.executable, "-m", "docker_ros", "dev-shell", "--name", name,
                              "--cmd", "sleep 60"], cwd=project, env={**os.environ, **env},
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 600
        while not running(name):
            assert shell.poll() is None and time.monotonic() < deadline, shell.communicate()[0]
            time.sleep(1)
        proxy.stop()
        output, _ = shell.communicate(timeout=120)
        last = output.strip().splitlines()[-1]
        print(last)
        assert shell.returncode != 0 and "Traceback" not in output, output[-3000:]
        assert last.startswith("docker-ros dev-shell: the connection to the Docker engine "
                               "was lost during the dev shell (`docker run` ended with exit "
                               "code "), last
        assert "rerunning is safe once `docker info` answers" in last, last
        proxy.start()
        again = docker_ros(project, "dev-shell", "--cmd", "true", env=env)
        assert again.returncode == 0, again.stdout[-3000:]
    finally:
        if shell.poll() is None:
            shell.kill()
            shell.communicate()
        subprocess.run(["docker", "rm", "-f", name], capture_output=True)
        with suppress(FileNotFoundError):
            proxy.stop()


def running(name: str) -> bool:
    shown = subprocess.run(["docker", "inspect", "-f", "{{.State.Running}}", name],
                           capture_output=True, text=True)
    return shown.stdout.strip() == "true"


class RegistryDoor:
    """A port in front of a registry (host:port): while shut, it takes every connection and
    answers nothing, so a push to it is surely in flight (the engine waits for the registry);
    once opened, it forwards each new connection to the registry."""

    def __init__(self, registry: str) -> None:
        host, port = registry.rsplit(":", 1)
        self.registry = (host, int(port))
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.address = f"127.0.0.1:{self.listener.getsockname()[1]}"
        self.connections: List[socket.socket] = []
        self.knocked = threading.Event()
        self.opened = False
        threading.Thread(target=self.accept, daemon=True).start()

    def accept(self) -> None:
        with suppress(OSError):
            while True:
                client, _ = self.listener.accept()
                self.connections.append(client)
                if not self.opened:
                    self.knocked.set()
                    continue
                registry = socket.create_connection(self.registry)
                self.connections.append(registry)
                for source, sink in ((client, registry), (registry, client)):
                    threading.Thread(target=pump, args=(source, sink), daemon=True).start()

    def close(self) -> None:
        self.listener.close()
        for connection in self.connections:
            connection.close()


def registry_tags(registry: str, repository: str) -> List[str]:
    """The tags the registry holds of repository (none when it has no such repository)."""
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    try:
        with opener.open(f"http://{registry}/v2/{repository}/tags/list", timeout=10) as answer:
            return list(json.loads(answer.read()).get("tags") or [])
    except urllib.error.HTTPError as refused:
        assert refused.code == 404, refused
        return []


def stopped_during(run: subprocess.Popen, daemon: engines.Daemon,
                   busy: Callable[[], bool]) -> List[str]:
    """The engine stopped (SIGTERM, as `systemctl stop docker`) once busy() says that the
    docker-ros command `run` is in the middle of its work; its output lines once it ended:
    it failed, with no traceback. The engine is left stopped."""
    try:
        deadline = time.monotonic() + 900
        while not busy():
            assert run.poll() is None and time.monotonic() < deadline, \
                run.communicate()[0][-4000:]
            time.sleep(0.5)
        daemon.stop()
        output, _ = run.communicate(timeout=300)
    finally:
        if run.poll() is None:
            run.kill()
            run.communicate()
    lines = output.strip().splitlines()
    print("\n".join(lines[-3:]))
    assert run.returncode != 0 and "Traceback" not in output, output[-4000:]
    return lines


def lost_line(task: str, during: str) -> Callable[[str], None]:
    """A check of a last line saying that the engine was lost during the task."""

    def check(last: str) -> None:
        assert last.startswith(f"docker-ros {task}: the connection to the Docker engine was "
                               f"lost during {during} ("), last
        assert last.endswith("rerunning is safe once `docker info` answers"), last

    return check


def test_an_engine_stopped_during_a_push_is_named_and_nothing_is_pushed(
    disk_engine: DiskEngine, local_registry: str
) -> None:
    """The module's engine stopped while it pushes (to a port in front of the registry that
    takes the connection and answers nothing, so the push is surely in flight): the last line
    says that the connection to the engine was lost during the push and that rerunning is
    safe, with no traceback, and the registry holds nothing; once the engine is started again
    on the same data root (and the port forwards to the registry), the same push works."""
    door = RegistryDoor(local_registry)
    try:
        env = {"DOCKER_HOST": disk_engine.host,
               "IMAGE": f"{door.address}/docker-ros-test/faults-push:latest"}
        push = docker_ros_started(disk_engine.project, "push", env=env)
        lines = stopped_during(push, disk_engine.daemon, door.knocked.is_set)
        lost_line("push", "the push")(lines[-1])
        assert registry_tags(local_registry, "docker-ros-test/faults-push") == []
        door.opened = True
        disk_engine.daemon.start()
        again = docker_ros(disk_engine.project, "push", env=env)
        assert again.returncode == 0, again.stdout[-4000:]
        assert registry_tags(local_registry, "docker-ros-test/faults-push") == ["latest"]
    finally:
        door.close()


def tracing_on(host: str) -> bool:
    """Whether slim's trace container runs in the engine at host."""
    shown = subprocess.run(["docker", "ps", "-q", "--filter", "name=docker-ros-slim-trace-"],
                           env=engines.env_for(host), capture_output=True, text=True)
    return bool(shown.stdout.strip())


def test_an_engine_stopped_during_a_slim_run_is_named_and_nothing_is_tagged(
    disk_engine: DiskEngine
) -> None:
    """The module's engine stopped while slim's trace container runs the run image's COMMAND:
    the last line says that the connection to the engine was lost during the slim run and
    that rerunning is safe, with no traceback, and no slim image is tagged; once the engine is
    started again on the same data root, the same slim run works."""
    env = {"DOCKER_HOST": disk_engine.host}
    slim = docker_ros_started(disk_engine.project, "slim", env=env)
    lines = stopped_during(slim, disk_engine.daemon, lambda: tracing_on(disk_engine.host))
    disk_engine.daemon.start()
    lost_line("slim", "the slim run")(lines[-1])
    assert not engine_has(disk_engine.host, f"{DISK_IMAGE}-slim")
    again = docker_ros(disk_engine.project, "slim", env=env)
    assert again.returncode == 0, again.stdout[-4000:]
    assert engine_has(disk_engine.host, f"{DISK_IMAGE}-slim")
