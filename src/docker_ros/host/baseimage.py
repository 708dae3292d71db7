"""Build a ROS base image from a Debian or Ubuntu mirror (debootstrap), for machines without a
registry.

Debian packages ROS 1 (bookworm) and the ROS 2 build tooling (trixie) in /usr, and Ubuntu 22.04
(jammy) has Debian's ROS 1 in universe, so a minbase rootfs plus those packages is a base image
that docker-ros can build on when neither `ros:*` nor `rwthika/*` images can be pulled.
"""

from __future__ import annotations

import base64
import hashlib
import logging
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

from docker_ros.core.labels import ours
from docker_ros.core.loading import host_platform
from docker_ros.host.engine import image_exists, inspect_image, remove_image
from docker_ros.in_image.runtime.process import privileged, run
from docker_ros.in_image.runtime.workspace import StepError, format_argv, step_log

LOG = logging.getLogger(__name__)
STEP = "baseimage"
DEFAULT_MIRROR = "http://deb.debian.org/debian"
UBUNTU_MIRROR = "http://archive.ubuntu.com/ubuntu"  # amd64 (and i386)
UBUNTU_PORTS_MIRROR = "http://ports.ubuntu.com/ubuntu-ports"  # arm64 and the other ports
DOCKERFILE = Path(__file__).parents[1] / "docker" / "baseimage.Dockerfile"
# The Ubuntu archive's signing key (2018, F6EC B376 2474 EDA9 D21B 7022 8719 20D1 991B C93C),
# which Debian does not package: debootstrap checks an Ubuntu suite's Release file against it.
UBUNTU_KEY = Path(__file__).parents[1] / "docker" / "ubuntu-archive-2018.asc"

# What colcon-common-extensions brings, as Debian packages (same names in bookworm and trixie).
COLCON_DEBS = tuple(
    "python3-colcon-" + name
    for name in (
        "bash", "cd", "cmake", "core", "defaults", "devtools", "library-path", "metadata",
        "output", "package-information", "package-selection", "parallel-executor",
        "pkg-config", "python-setup-py", "recursive-crawl", "ros", "test-result",
    )
)
# The tools the steps need (openssh-client: git over ssh in the clone step). No compiler: run
# images are built on this base and must not carry one; dev images get build-essential from the
# image's prepare stage.
TOOL_DEBS = (
    "ca-certificates", "colcon", "git", "openssh-client", "python3-pip", "python3-rosdep2", "tini",
    "vcstool",
)
# Image label holding the recipe fingerprint: an existing image is reused only if it was built
# from the same recipe (a changed package list or Dockerfile rebuilds it).
RECIPE_LABEL = ours("base-recipe")


@dataclass(frozen=True)
class Flavor:
    """A Debian or Ubuntu suite and the ROS packages it provides. name: the image's (default
    tag docker-ros/<name>:<suite>) and the Dockerfile target unless `target` names another;
    pip: what the Dockerfile target installs from PyPI (pinned: it is part of the recipe)."""

    name: str
    suite: str
    debs: Tuple[str, ...]
    distro: str = "debian"
    pip: Tuple[str, ...] = ()
    target: str = ""

    @property
    def stage(self) -> str:
        return self.target or self.name


# ros1 is like `ros:noetic-ros-core`: no compiler, so docker-ros's dev stage must bring it.
# ROS 1 at run time (roscore, roslaunch, rostopic...); -dev packages come from rosdep.
ROS1_DEBS = ("ros-core", "rosbash")
# ros2 is build tooling only (Debian has no rclcpp/rclpy), with the compiler to use it.
ROS2_DEBS = (
    "ament-cmake", "ament-cmake-python", "python3-ament-index", "python3-ament-package",
    "build-essential",
)
# ros1-ubuntu is ROS 1 as Ubuntu 22.04 packages it (a `ros:noetic-ros-core` on Ubuntu). Ubuntu
# has neither colcon nor vcstool as packages: they come from PyPI, as on a base made with pip.
UBUNTU_TOOL_DEBS = tuple(d for d in TOOL_DEBS if d not in ("colcon", "vcstool"))
FLAVORS = {
    "ros1": Flavor("ros1", "bookworm", ROS1_DEBS + TOOL_DEBS + COLCON_DEBS),
    "ros2": Flavor("ros2", "trixie", ROS2_DEBS + TOOL_DEBS + COLCON_DEBS),
    "ros1-ubuntu": Flavor("ros1", "jammy", ROS1_DEBS + UBUNTU_TOOL_DEBS, distro="ubuntu",
                          pip=("colcon-common-extensions==0.3.0", "vcstool==0.3.0"),
                          target="ros1-ubuntu"),
}


def default_tag(flavor: str) -> str:
    """docker-ros/ros1:bookworm, docker-ros/ros2:trixie, docker-ros/ros1:jammy."""
    spec = FLAVORS[flavor]
    return f"docker-ros/{spec.name}:{spec.suite}"


def default_mirror(distro: str, platform: str) -> str:
    """Debian's mirror serves every architecture; Ubuntu's archive only amd64 and i386, its
    ports the others (arm64)."""
    if distro != "ubuntu":
        return DEFAULT_MIRROR
    return UBUNTU_MIRROR if platform in ("amd64", "i386") else UBUNTU_PORTS_MIRROR


def dearmor(armored: str) -> bytes:
    """The binary key of an ASCII-armored OpenPGP key block (RFC 4880, 6.2): what debootstrap's
    gpgv takes as --keyring."""
    lines = armored.strip().splitlines()
    start = lines.index("") + 1  # the armor headers end at the first empty line
    body = [line for line in lines[start:-1] if not line.startswith("=")]  # "=" CRC-24 line
    return base64.b64decode("".join(body))


def arch_ref(ref: str, platform: str) -> str:
    """The local name of ref's image for another architecture: `<ref>-<arch>` (`name` without
    a tag: `name:latest-<arch>`). The classic image store holds one image per tag, so the
    images of several architectures need a tag each."""
    return f"{ref}-{platform}" if ":" in ref.rsplit("/", 1)[-1] else f"{ref}:latest-{platform}"


def platform_tag(tag: str, platform: str, host: str) -> str:
    """The tag bootstrap gives the image of platform: `tag` for the host's architecture,
    arch_ref for any other, so that no architecture's image replaces another's."""
    return tag if platform == host else arch_ref(tag, platform)


def bootstrap(
    flavor: str,
    *,
    tag: str,
    mirror: str = "",
    platform: str = "",
    ca_bundle: Optional[Path] = None,
    force: bool = False,
    cli: Sequence[str] = ("docker",),
    network: str = "",
) -> str:
    """Build the base image of `flavor` (a key of FLAVORS) for `platform`, tagged `tag` for the
    host's architecture and `<tag>-<platform>` for another (platform_tag); return that name.
    mirror: the flavor's distribution's for that platform unless given (default_mirror).
    Reuse an image of that name built from the current recipe (RECIPE_LABEL), else rebuild it.
    platform: this machine's architecture unless given. cli: the docker command of the engine
    to build it in (`docker --context NAME` for a docker context's; the SDK client must be
    bound to the same engine, engine.bind). network: the apt-get's `--network` (BUILD_NETWORK)."""
    if flavor not in FLAVORS:
        raise StepError(STEP, f"unknown flavor {flavor!r}; choose one of {', '.join(FLAVORS)}")
    platform = platform or host_platform()
    tag = platform_tag(tag, platform, host_platform())
    if ca_bundle is not None and not Path(ca_bundle).is_file():
        raise StepError(STEP, f"CA bundle '{ca_bundle}' not found")
    spec = FLAVORS[flavor]
    if not force and image_exists(tag):
        reason = stale_reason(image_label(tag, RECIPE_LABEL), image_architecture(tag),
                              recipe=recipe(spec), platform=platform)
        if not reason:
            LOG.info("%s: %s exists, not rebuilding it (`inv bootstrap-base-image --force` "
                     "does)", STEP, tag)
            return tag
        LOG.info("%s: %s %s, rebuilding it", STEP, tag, reason)
    with step_log(f"{STEP} {tag}"), tempfile.TemporaryDirectory(prefix="docker-ros-base-") as tmp:
        work = Path(tmp)
        rootfs = work / "rootfs"
        rootfs_tag = f"docker-ros-rootfs/{spec.suite}:{platform}-{work.name.lower()}"
        mirror = mirror or default_mirror(spec.distro, platform)
        keyring: Optional[Path] = None
        components: Tuple[str, ...] = ()
        if spec.distro == "ubuntu":  # its ROS packages are in universe
            keyring = work / "ubuntu-archive.gpg"
            keyring.write_bytes(dearmor(UBUNTU_KEY.read_text()))
            components = ("main", "universe")
        try:
            with step_log(f"{STEP} debootstrap {spec.suite} ({platform})"):
                argv = debootstrap_argv(spec.suite, rootfs, mirror, platform,
                                        components=components, keyring=keyring)
                run(privileged(argv), step=STEP)
            with step_log(f"{STEP} import rootfs"):
                import_rootfs(rootfs, rootfs_tag, platform, work, cli)
        finally:
            remove_rootfs(rootfs)
        try:
            with step_log(f"{STEP} apt-get install ({len(spec.debs)} packages)"):
                context = work / "context"
                context.mkdir()
                run(build_argv(spec, tag, rootfs_tag, platform, ca_bundle, context, cli, network),
                    step=STEP)
        finally:
            remove_image(rootfs_tag)
    return tag


def recipe(spec: Flavor) -> str:
    """Fingerprint of what an image of `spec` is built from: Dockerfile, target and packages."""
    text = "\0".join([DOCKERFILE.read_text(), spec.stage, spec.suite, *spec.debs, *spec.pip])
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def stale_reason(
    label: Optional[str], architecture: Optional[str], *, recipe: str, platform: str
) -> str:
    """Why an existing base image cannot be reused ('' when it can)."""
    if architecture != platform:
        return f"is built for {architecture or 'an unknown architecture'}, not {platform}"
    if label != recipe:
        return "was built from another recipe (package list)"
    return ""


def image_architecture(tag: str) -> Optional[str]:
    attrs = inspect_image(tag)
    return str(attrs.get("Architecture") or "") or None if attrs else None


def image_label(tag: str, label: str) -> Optional[str]:
    attrs = inspect_image(tag)
    labels = ((attrs or {}).get("Config") or {}).get("Labels") or {}
    value = labels.get(label)
    return str(value) if value is not None else None


def debootstrap_argv(
    suite: str, rootfs: Path, mirror: str, platform: str, *,
    components: Sequence[str] = (), keyring: Optional[Path] = None,
) -> List[str]:
    argv = ["debootstrap", "--variant=minbase", f"--arch={platform}"]
    argv += [f"--components={','.join(components)}"] if components else []
    argv += [f"--keyring={keyring}"] if keyring is not None else []
    return argv + [suite, str(rootfs), mirror]


def build_argv(
    spec: Flavor,
    tag: str,
    rootfs_image: str,
    platform: str,
    ca_bundle: Optional[Path],
    context: Path,
    cli: Sequence[str] = ("docker",),
    network: str = "",
) -> List[str]:
    argv = [*cli, "buildx", "build", "--load", "--platform", f"linux/{platform}"]
    argv += ["--network", network] if network else []
    argv += ["--file", str(DOCKERFILE), "--target", spec.stage, "--tag", tag]
    argv += ["--build-arg", f"ROOTFS_IMAGE={rootfs_image}"]
    argv += ["--build-arg", "DEBS=" + " ".join(spec.debs)]
    argv += ["--build-arg", "PIP_PACKAGES=" + " ".join(spec.pip)] if spec.pip else []
    argv += ["--label", f"{RECIPE_LABEL}={recipe(spec)}"]
    if ca_bundle is not None:
        argv += ["--secret", f"id=EXTRA_CA_CERTS,src={ca_bundle}"]
    return argv + [str(context)]


def import_rootfs(rootfs: Path, tag: str, platform: str, work: Path, cli: Sequence[str]) -> None:
    """Make the rootfs an image. `docker import --platform` records the wrong architecture on
    Engine 20.10, so a foreign rootfs goes through a `FROM scratch` build instead."""
    if platform == host_platform():
        pack = privileged(["tar", "-C", str(rootfs), "-c", "."])
        tar = subprocess.Popen(pack, stdout=subprocess.PIPE)
        imported = subprocess.run(
            [*cli, "import", "-", tag], stdin=tar.stdout, stdout=subprocess.DEVNULL
        )
        assert tar.stdout is not None
        tar.stdout.close()
        if tar.wait() != 0 or imported.returncode != 0:
            raise StepError(
                STEP,
                f"importing {rootfs} as {tag} failed"
                f" (tar: exit code {tar.returncode}, docker import: {imported.returncode})",
            )
        return
    context = work / "import"
    context.mkdir()
    run(privileged(["tar", "-C", str(rootfs), "-cf", str(context / "rootfs.tar"), "."]), step=STEP)
    (context / "Dockerfile").write_text("FROM scratch\nADD rootfs.tar /\nCMD [\"bash\"]\n")
    try:
        build = [*cli, "buildx", "build", "--load", "--platform", f"linux/{platform}"]
        run(build + ["--tag", tag, str(context)], step=STEP)
    finally:
        (context / "rootfs.tar").unlink()


def remove_rootfs(rootfs: Path) -> None:
    """debootstrap leaves root-owned files and, when interrupted, mounts (proc, sys, dev):
    unmount those first and never cross into another file system while removing."""
    if not rootfs.exists():
        return
    for mount in reversed(mounts_below(rootfs)):
        LOG.warning("%s: unmounting leftover %s", STEP, mount)
        subprocess.run(privileged(["umount", "--lazy", mount]))
    argv = privileged(["rm", "-rf", "--one-file-system", str(rootfs)])
    if subprocess.run(argv).returncode != 0:
        LOG.warning("%s: could not remove %s (%s)", STEP, rootfs, format_argv(argv))


def mounts_below(path: Path) -> List[str]:
    """Mount points at or below `path`, outermost first (/proc/self/mounts escapes spaces)."""
    prefix = str(path.resolve())
    found = []
    for line in Path("/proc/self/mounts").read_text().splitlines():
        point = line.split()[1].replace("\\040", " ")
        if point == prefix or point.startswith(prefix + "/"):
            found.append(point)
    return sorted(found, key=len)
