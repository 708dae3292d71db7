"""Credentials never leak (issue 5): private upstream repositories cloned over HTTPS (Basic auth,
a `git http-backend` server) and SSH (Debian's sshd) during a real `docker-ros build`, then the
password and the private key are searched for in every layer of the dev and run images, their
history and configuration, the build log and the command lines of the processes seen during the
build (/proc polled every 20 ms: a process shorter than that may be missed).

Both servers listen on the host's loopback: the builds use BUILD_NETWORK=host.

proves (each line: where; "image" = a real build here, its images, log and command lines):
- an HTTPS clone without a password fails in clone naming the repository, no secret in the
  log: image, test_https_without_password_fails_in_clone_naming_the_repository
- an HTTPS clone with the password from .env builds, in one bake run granted the host network,
  and the password (in .env, the origin URL, gitlab-ci-local's file) is nowhere: image,
  test_https_password_from_dotenv
- the password from the environment is the same BuildKit secret as from .env, and outranks
  it: unit, tests/unit/test_secret_sources.py; both secrets from the environment stay out of
  a baked build: image, test_secrets_of_a_baked_build_stay_out; a secret from the environment
  clones: image, test_ssh_private_key_from_environment. (Was test_https_password_from_
  environment, the .env build again with the password in the environment.)
- a baked build (no BUILD_NETWORK) keeps both secrets out: image,
  test_secrets_of_a_baked_build_stay_out
- an SSH clone without a key fails in clone naming the repository: image,
  test_ssh_without_key_fails_in_clone_naming_the_repository
- an SSH clone with the key from the environment builds, said in the log, nothing leaks:
  image, test_ssh_private_key_from_environment
- on a base without ssh, the clone installs openssh-client for itself only: image,
  test_ssh_clone_on_a_base_without_ssh_installs_it_for_the_clone_only"""

from __future__ import annotations

import io
import os
import re
import secrets
import subprocess
import sys
import tarfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterator, List, Sequence, Set

import pytest

from tests.docker.buildhelp import image_exists, remove_image, sh, write_env
from tests.rosfixtures import (
    git_http_server,
    make_git_repo,
    make_package,
    ssh_keygen,
    sshd_server,
    write_repos,
)

pytestmark = pytest.mark.docker

USER = "robot"
UPSTREAM = "private_lib"  # a cmake package in a private repository
IMAGE_PREFIX = "docker-ros-test/secrets-"
OVERRIDDEN = ("TARGET", "COMMAND", "IMAGE", "BUILD_NETWORK", "BASE_IMAGE", "GIT_HTTPS_SERVER",
              "GIT_HTTPS_USER", "GIT_HTTPS_PASSWORD", "GIT_SSH_PRIVATE_KEY",
              "GIT_SSH_KNOWN_HOST_KEYS")


@dataclass
class Material:
    """The secrets of this module (fresh per run) and what must never appear anywhere."""

    password: str
    key: str
    key_file: Path
    needles: Dict[str, bytes] = field(default_factory=dict)
    clean_layers: Set[str] = field(default_factory=set)


@pytest.fixture(scope="module")
def material(tmp_path_factory: pytest.TempPathFactory) -> Material:
    work = tmp_path_factory.mktemp("secrets-keys")
    password = "pw-" + secrets.token_hex(16)
    key_file = work / "id_ed25519"
    key = ssh_keygen(key_file, "docker-ros secrets test")
    body = [line for line in key.splitlines() if line and not line.startswith("-----")]
    needles = {"password": password.encode(), "key body (base64, one line)": "".join(body).encode()}
    # Every full-length line of the key's base64 body (the last one may be short and common).
    for number, line in enumerate(body):
        if len(line) >= 40:
            needles[f"key line {number + 1}"] = line.encode()
    assert len(needles) >= 4, key
    return Material(password, key, key_file, needles)


@pytest.fixture(scope="module")
def remotes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Bare repositories: <root>/private_lib.git holds a cmake package."""
    root = tmp_path_factory.mktemp("secrets-remotes")
    work = make_package(root / "work" / UPSTREAM, UPSTREAM)
    make_git_repo(work, {}, bare_copy_to=root / f"{UPSTREAM}.git")
    return root


@pytest.fixture(scope="module")
def http_remote(remotes: Path, material: Material) -> Iterator[str]:
    """`127.0.0.1:<port>` of a Basic-auth git server for `remotes`."""
    server = git_http_server(remotes, USER, material.password)
    yield f"127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


@dataclass
class SshRemote:
    url: str
    known_hosts: str


@pytest.fixture(scope="module")
def ssh_remote(remotes: Path, material: Material) -> Iterator[SshRemote]:
    """sshd on 127.0.0.1:<port> accepting the module's key for root; the repository's URL."""
    public_key = material.key_file.with_suffix(".pub").read_text()
    server = sshd_server(remotes.parent / "sshd", public_key)
    scan = subprocess.run(["ssh-keyscan", "-p", str(server.port), "127.0.0.1"],
                          capture_output=True, text=True, timeout=30)
    assert scan.stdout.strip(), scan.stderr
    url = f"ssh://root@127.0.0.1:{server.port}{remotes / UPSTREAM}.git"
    yield SshRemote(url, scan.stdout)
    server.stop()


@pytest.fixture(scope="module", autouse=True)
def remove_images_afterwards() -> Iterator[None]:
    yield
    listed = subprocess.run(["docker", "image", "ls", "--format", "{{.Repository}}:{{.Tag}}"],
                            capture_output=True, text=True).stdout.split()
    for ref in listed:
        if ref.startswith(IMAGE_PREFIX):
            remove_image(ref)


# --- building, and watching every process's command line meanwhile ---


class CommandLines(threading.Thread):
    """Every distinct /proc/*/cmdline on the machine while running (polled)."""

    def __init__(self) -> None:
        super().__init__(daemon=True)
        self.seen: Set[bytes] = set()
        self.done = threading.Event()

    def run(self) -> None:
        while not self.done.is_set():
            for entry in os.scandir("/proc"):
                if entry.name.isdigit():
                    try:
                        with open(f"/proc/{entry.name}/cmdline", "rb") as handle:
                            self.seen.add(handle.read())
                    except OSError:
                        pass
            time.sleep(0.02)

    def stop(self) -> Set[bytes]:
        self.done.set()
        self.join()
        return self.seen


@dataclass
class Build:
    returncode: int
    log: str
    cmdlines: Set[bytes]
    dev: str
    run: str
    control: str  # the project's README text


def project(tmp_path: Path, name: str, url: str, **settings: str) -> Path:
    """A repository with no package of its own: a `.repos` naming the private repository."""
    repo = tmp_path / name
    repo.mkdir()
    write_repos(repo / ".repos", {UPSTREAM: {"url": url, "version": "main"}})
    (repo / "README.md").write_text(f"docker-ros secrets test: project {name}\n")
    return repo


def build(repo: Path, base: str, name: str, env: Dict[str, str], **dotenv: str) -> Build:
    image = f"{IMAGE_PREFIX}{name}:latest"
    dev, run = f"{image}-dev", image
    for ref in (dev, run):
        remove_image(ref)
    write_env(repo, **{"BASE_IMAGE": base, "IMAGE": image, "TARGET": "dev,run",
                       "BUILD_NETWORK": "host", "COMMAND": f"{UPSTREAM}_node", **dotenv})
    watcher = CommandLines()
    watcher.start()
    # Only the settings given here (the environment outranks .env: none may come from ours).
    full_env = {k: v for k, v in os.environ.items() if k not in OVERRIDDEN}
    try:
        result = subprocess.run([sys.executable, "-m", "docker_ros", "build"], cwd=repo,
                                env={**full_env, **env}, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True, timeout=600)
    finally:
        cmdlines = watcher.stop()
    control = (repo / "README.md").read_text()
    return Build(result.returncode, result.stdout, cmdlines, dev, run, control)


# --- the leak search ---


def hits(data: bytes, needles: Dict[str, bytes]) -> List[str]:
    return [what for what, needle in needles.items() if needle in data]


def tar_hits(tar: tarfile.TarFile, needles: Dict[str, bytes], where: str) -> List[str]:
    found = []
    for member in tar:
        meta = " ".join([member.name, member.linkname, *member.pax_headers.values()]).encode()
        found += [f"{where}: name of {member.name}: {w}" for w in hits(meta, needles)]
        if member.isfile():
            handle = tar.extractfile(member)
            assert handle is not None
            found += [f"{where}: {member.name}: {w}" for w in hits(handle.read(), needles)]
    return found


CONTROL = "control (expected in the dev image)"


def image_hits(refs: Sequence[str], material: Material, control: bytes) -> List[str]:
    """`docker save` of refs: every layer untarred, every file's bytes (and every other file of
    the archive: configs, manifests) searched for the secrets, and for `control`, a text that
    is in the images (proof that the search sees file contents). Layers found clean before are
    skipped."""
    needles = {**material.needles, CONTROL: control}
    save = subprocess.Popen(["docker", "save", *refs], stdout=subprocess.PIPE)
    assert save.stdout is not None
    found: List[str] = []
    layers = 0
    with tarfile.open(fileobj=save.stdout, mode="r|") as archive:
        for member in archive:
            if not member.isfile():
                continue
            if member.name in material.clean_layers:
                layers += 1
                continue
            handle = archive.extractfile(member)
            assert handle is not None
            data = handle.read()
            # Layers are tars themselves (legacy `<id>/layer.tar`, or OCI blobs); their raw
            # bytes are searched too (tar headers included).
            found += [f"{member.name}: {w}" for w in hits(data, needles)]
            if data[257:262] == b"ustar":
                layers += 1
                with tarfile.open(fileobj=io.BytesIO(data), mode="r:") as layer:
                    layer_found = tar_hits(layer, needles, member.name)
                found += layer_found
                if not layer_found and member.name.endswith("/layer.tar"):
                    material.clean_layers.add(member.name)
    assert save.wait() == 0, f"docker save {refs} failed"
    assert layers, f"no layers found in the saved images {refs}"
    return found


def assert_nothing_leaked(built: Build, material: Material) -> None:
    leaks = [f"build log: {w}" for w in hits(built.log.encode(), material.needles)]
    buildx = [c for c in built.cmdlines if b"buildx\0bake" in c or b"buildx\0build" in c]
    assert buildx, "the command line of `docker buildx bake` (or `build`) was never seen"
    for cmdline in built.cmdlines:
        shown = cmdline.replace(b"\0", b" ")[:200].decode(errors="replace")
        leaks += [f"command line {shown!r}: {w}" for w in hits(cmdline, material.needles)]
    for ref in (built.dev, built.run):
        for argv in (["docker", "image", "inspect", ref], ["docker", "history", "--no-trunc", ref]):
            out = subprocess.run(argv, capture_output=True, check=True).stdout
            leaks += [f"{' '.join(argv)}: {w}" for w in hits(out, material.needles)]
    found = image_hits([built.dev, built.run], material, built.control.encode())
    control = [hit for hit in found if hit.endswith(CONTROL)]
    assert any("src/target/README.md" in hit for hit in control), control
    leaks += [hit for hit in found if not hit.endswith(CONTROL)]
    # BuildKit's cache records (their descriptions are the RUN lines and cache keys' sources)
    cache = subprocess.run(["docker", "buildx", "du", "--verbose"], capture_output=True, check=True)
    leaks += [f"docker buildx du --verbose: {w}" for w in hits(cache.stdout, material.needles)]
    assert not leaks, "\n".join(leaks)


def assert_upstream_built(built: Build) -> None:
    assert built.returncode == 0, built.log[-6000:]
    node = f"/docker-ros/ws/install/{UPSTREAM}/bin/{UPSTREAM}_node"
    ran = sh(built.run, f"ls {node} && {UPSTREAM}_node")
    assert ran.returncode == 0, ran.stdout + ran.stderr
    assert ran.stdout.strip().endswith(UPSTREAM), ran.stdout
    sources = sh(built.dev, f"ls -A src/target && ls src/upstream/{UPSTREAM}/package.xml")
    assert sources.returncode == 0, sources.stdout + sources.stderr
    for name in (".env", ".git", ".gitlab-ci-local-variables.yml"):
        assert name not in sources.stdout.split(), sources.stdout


def assert_failed_in_clone(built: Build, url: str) -> None:
    assert built.returncode != 0, built.log[-4000:]
    last = built.log.strip().splitlines()[-3:]
    message = "\n".join(last)
    assert "step clone" in message and f"repository '{UPSTREAM}'" in message, built.log[-4000:]
    assert url in message, message
    assert not image_exists(built.dev) and not image_exists(built.run)


# --- HTTPS ---


def https_settings(remote: str) -> Dict[str, str]:
    return {"GIT_HTTPS_SERVER": remote, "GIT_HTTPS_USER": USER}


def test_https_without_password_fails_in_clone_naming_the_repository(
    ros1_base_image: str, http_remote: str, material: Material, tmp_path: Path
) -> None:
    url = f"http://{http_remote}/{UPSTREAM}.git"
    repo = project(tmp_path, "https-nopassword", url)
    built = build(repo, ros1_base_image, "https-nopassword", {}, **https_settings(http_remote))
    assert_failed_in_clone(built, url)
    assert not hits(built.log.encode(), material.needles)


def test_secrets_of_a_baked_build_stay_out(
    ros1_base_image: str, material: Material, tmp_path: Path
) -> None:
    """Without BUILD_NETWORK too, dev and run are one `docker buildx bake` with both secrets as
    secret mounts (the definition file names their variables only: a unit test of bake_file),
    and nothing reaches the images, logs or command lines."""
    repo = tmp_path / "baked"
    make_package(repo / "baked_pkg", "baked_pkg")  # something to build
    (repo / "README.md").write_text("docker-ros secrets test: project baked\n")
    built = build(repo, ros1_base_image, "baked",
                  {"GIT_HTTPS_PASSWORD": material.password, "GIT_SSH_PRIVATE_KEY": material.key},
                  BUILD_NETWORK="", COMMAND="baked_pkg_node")
    assert built.returncode == 0, built.log[-4000:]
    assert any(b"buildx\0bake" in c for c in built.cmdlines)
    assert_nothing_leaked(built, material)


def test_https_password_from_dotenv(
    ros1_base_image: str, http_remote: str, material: Material, tmp_path: Path
) -> None:
    """The repository is a git checkout whose origin URL holds the password (as GitLab runners
    before 18.0 put CI_JOB_TOKEN there; actions/checkout keeps a header in .git/config), and
    gitlab-ci-local's variables file names it too: neither reaches an image."""
    url = f"http://{http_remote}/{UPSTREAM}.git"
    repo = project(tmp_path, "https-dotenv", url)
    subprocess.run(["git", "init", "-q", str(repo)], check=True)
    subprocess.run(["git", "-C", str(repo), "remote", "add", "origin",
                    f"http://{USER}:{material.password}@{http_remote}/project.git"], check=True)
    (repo / ".gitlab-ci-local-variables.yml").write_text(
        f"GIT_HTTPS_PASSWORD: {material.password}\n")
    built = build(repo, ros1_base_image, "https-dotenv", {},
                  GIT_HTTPS_PASSWORD=material.password, **https_settings(http_remote))
    assert material.password in (repo / ".env").read_text()
    assert_upstream_built(built)
    # BUILD_NETWORK=host on the suite's current buildx: dev and run in one bake run, granted
    # the host's network
    assert any(b"buildx\0bake" in c and b"--allow=network.host" in c for c in built.cmdlines)
    assert_nothing_leaked(built, material)


# --- SSH ---


def test_ssh_without_key_fails_in_clone_naming_the_repository(
    ros1_base_image: str, ssh_remote: SshRemote, material: Material, tmp_path: Path
) -> None:
    repo = project(tmp_path, "ssh-nokey", ssh_remote.url)
    built = build(repo, ros1_base_image, "ssh-nokey", {},
                  GIT_SSH_KNOWN_HOST_KEYS=ssh_remote.known_hosts.replace("\n", "\\n"))
    assert_failed_in_clone(built, ssh_remote.url)


def test_ssh_private_key_from_environment(
    ros1_base_image: str, ssh_remote: SshRemote, material: Material, tmp_path: Path
) -> None:
    repo = project(tmp_path, "ssh-key", ssh_remote.url)
    env = {"GIT_SSH_PRIVATE_KEY": material.key, "GIT_SSH_KNOWN_HOST_KEYS": ssh_remote.known_hosts}
    built = build(repo, ros1_base_image, "ssh", env)
    assert_upstream_built(built)
    assert re.search(r"SSH private key in use", built.log), built.log[-4000:]
    assert_nothing_leaked(built, material)


@pytest.fixture(scope="module")
def base_without_ssh(ros1_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> str:
    """A base image like Ubuntu's ros:*-ros-core: no ssh client."""
    tag = f"{IMAGE_PREFIX}nossh-base:1"
    context = tmp_path_factory.mktemp("nossh")
    (context / "Dockerfile").write_text(
        f"FROM {ros1_base_image}\nRUN apt-get purge -y openssh-client && ! command -v ssh\n"
    )
    subprocess.run(["docker", "buildx", "build", "--load", "-t", tag, str(context)],
                   check=True, capture_output=True)
    return tag


def test_ssh_clone_on_a_base_without_ssh_installs_it_for_the_clone_only(
    base_without_ssh: str, ssh_remote: SshRemote, material: Material, tmp_path: Path
) -> None:
    repo = project(tmp_path, "ssh-nossh", ssh_remote.url)
    env = {"GIT_SSH_PRIVATE_KEY": material.key, "GIT_SSH_KNOWN_HOST_KEYS": ssh_remote.known_hosts}
    built = build(repo, base_without_ssh, "ssh-nossh", env)
    assert_upstream_built(built)
    assert "installing openssh-client for SSH clones" in built.log
    for ref in (built.dev, built.run):
        probe = subprocess.run(["docker", "run", "--rm", "--entrypoint", "sh", ref, "-c",
                                "command -v ssh || echo absent"], capture_output=True, text=True)
        assert probe.stdout.strip() == "absent", ref
    assert_nothing_leaked(built, material)
