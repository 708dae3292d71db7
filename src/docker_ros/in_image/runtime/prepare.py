"""prepare (image only, before the ten steps): tini, git, vcstool, rosdep, colcon and ROS itself
when the base image lacks them; a docker-ros workspace in the base moves to /opt/ws_base_image."""

import configparser
import glob
import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Dict, Iterator, List, Mapping, Optional, Sequence

from docker_ros.core.settings import Settings, explicitly_set
from docker_ros.in_image.runtime.apt import DPKG_STATUS, apt_env, install_options
from docker_ros.in_image.runtime.lockapt import (
    LOCK_PREFERENCES,
    apt_sources,
    parse_apt_preferences,
    read_dpkg_status,
    unlocked_installs,
)
from docker_ros.in_image.runtime.process import run
from docker_ros.in_image.runtime.rosenv import BASE_IMAGE_WS, ROS1_DISTROS
from docker_ros.in_image.runtime.workspace import LOG, StepError, Workspace, step_log

# prepare runs in image builds only
IMAGE_INSTALL = install_options("image")

ROS_APT_SOURCE_URL = (
    "https://github.com/ros-infrastructure/ros-apt-source/releases/download/"
    "{version}/{package}_{version}.{codename}_all.deb"
)
BASE_WS = BASE_IMAGE_WS

# tool (command) -> apt package candidates, in order of preference (ROS apt repo, then Debian).
TOOLS: Dict[str, Sequence[str]] = {
    "tini": ("tini",),
    "git": ("git",),
    "vcs": ("python3-vcstool", "vcstool"),
    "rosdep": ("python3-rosdep", "python3-rosdep2"),
    "colcon": ("python3-colcon-common-extensions", "colcon"),
    "pip3": ("python3-pip",),
}
# What docker-ros's images had before any hook ran (its dependencies-install stage installed
# curl, gnupg and python-is-python3 into dev and run images): hooks download with curl, add apt
# keys with gpg, scripts and `#!/usr/bin/env python` nodes call `python`. Installed when
# missing and apt has them (a base whose `python` is Python 2 keeps it).
DOCKER_ROS_TOOLS: Dict[str, Sequence[str]] = {
    "curl": ("curl",),
    "gpg": ("gnupg",),
    "python": ("python-is-python3",),
}
# The toolchain of dev images (run images never get it): prepare with dependency types "all".
DEV_TOOLS = ("build-essential", "cmake", "python3-pip")
# Extra Debian packages that make the plain `colcon` package useful for ROS workspaces.
DEBIAN_COLCON_EXTRAS = ("python3-colcon-ros", "python3-colcon-cmake", "python3-colcon-bash",
                        "python3-colcon-package-selection", "python3-colcon-test-result",
                        "python3-colcon-output", "python3-colcon-library-path",
                        # (COLCON_DEFAULTS_FILE: inv dev-shell's ignore list of blacklisted
                        # packages)
                        "python3-colcon-defaults")


def is_ros1(distro: str) -> bool:
    return distro in ROS1_DISTROS


def ros_present(root: Path = Path("/"), distro: Optional[str] = None) -> bool:
    """ROS in /opt/ros (ROS apt packages) or in /usr (Debian's own ROS packages)."""
    if distro and (root / "opt/ros" / distro / "setup.bash").exists():
        return True
    if glob.glob(str(root / "opt/ros/*/setup.bash")):
        return True
    return any((root / p).exists() for p in ("usr/bin/roscore", "usr/share/ament_cmake_core"))


def distro_problem(distro: Optional[str], root: Path = Path("/")) -> Optional[str]:
    """Why a ROS_DISTRO the user set does not fit the ROS the base image has (None: it fits,
    or the base has none). Built against another distribution's ROS, the build failed only in
    colcon, e.g. in catkin: "ROS_DISTRO was set to 'noetic' before"."""
    if not distro:
        return None
    found = sorted(p.parent.name for p in (root / "opt/ros").glob("*/setup.bash"))
    if found and distro not in found:
        return (f"ROS_DISTRO={distro}, but BASE_IMAGE has ROS {', '.join(found)} in /opt/ros: "
                f"set ROS_DISTRO={found[0]}, or leave it unset")
    if not found and ros_present(root):
        return (f"ROS_DISTRO={distro}, but BASE_IMAGE has Debian's ROS packages in /usr, not "
                f"/opt/ros/{distro}: leave ROS_DISTRO unset")
    return None


def ros_package_names(distro: str, rmw_implementation: str) -> List[str]:
    """apt packages of a ROS installation: ros-core, and the RMW implementation on ROS 2."""
    packages = [f"ros-{distro}-ros-core"]
    if not is_ros1(distro) and rmw_implementation:
        packages.append(f"ros-{distro}-{rmw_implementation.replace('_', '-')}")
    return packages


def plan_ros_installation(
    *,
    ros_installed: bool,
    disabled: bool,
    distro: Optional[str],
    rmw_implementation: str,
    apt_source_version: str,
    os_codename: str,
) -> List[List[str]]:
    """Commands that install ROS from the ROS apt source (pinned version), or none."""
    if ros_installed or disabled:
        return []
    if not distro:
        raise StepError(
            "prepare",
            "the base image has no ROS installation: set ROS_DISTRO (e.g. jazzy) to install it, "
            "or DISABLE_ROS_INSTALLATION=true",
        )
    package = "ros-apt-source" if is_ros1(distro) else "ros2-apt-source"
    url = ROS_APT_SOURCE_URL.format(
        version=apt_source_version, package=package, codename=os_codename
    )
    deb = f"/tmp/{package}.deb"
    return [
        ["apt-get", "update"],
        ["apt-get", "install", *IMAGE_INSTALL, "ca-certificates", "curl"],
        ["curl", "-fsSL", "-o", deb, url],
        ["apt-get", "install", "-y", deb],
        ["rm", "-f", deb],
        ["apt-get", "update"],
        ["apt-get", "install", *IMAGE_INSTALL,
         *ros_package_names(distro, rmw_implementation)],
    ]


def plan_rmw_installation(
    *,
    ros_installed: bool,
    disabled: bool,
    distro: Optional[str],
    rmw_implementation: str,
    chosen: bool,
    installed: Sequence[str],
) -> List[List[str]]:
    """A chosen RMW_IMPLEMENTATION's package on a ROS 2 base image that has ROS but lacks it
    (docker-ros installed it on every base unless DISABLE_ROS_INSTALLATION; a base without
    ROS gets it with ROS, plan_ros_installation). The default (unchosen) installs nothing."""
    if not ros_installed or disabled or not chosen or not distro or is_ros1(distro):
        return []
    package = ros_package_names(distro, rmw_implementation)[-1]
    if package in installed:
        return []
    return [["apt-get", "update"], ["apt-get", "install", *IMAGE_INSTALL, package]]


def plan_tool_packages(missing: Sequence[str], available: Sequence[str]) -> List[str]:
    """apt packages providing the missing tools, first candidate the apt sources know."""
    packages: List[str] = []
    for tool in missing:
        candidates = [p for p in TOOLS[tool] if p in available]
        if not candidates:
            raise StepError("prepare", f"no apt package provides '{tool}' (tried "
                            f"{', '.join(TOOLS[tool])}); install it in the base image")
        packages.append(candidates[0])
        if candidates[0] == "colcon":
            packages.extend(p for p in DEBIAN_COLCON_EXTRAS if p in available)
    return packages


def plan_docker_ros_packages(missing: Sequence[str], available: Sequence[str]) -> List[str]:
    """apt packages providing the missing DOCKER_ROS_TOOLS that apt has (the others are left
    out: docker-ros's images had them, the build does not need them)."""
    return [p for tool in missing for p in DOCKER_ROS_TOOLS[tool][:1] if p in available]


def os_release(root: Path = Path("/")) -> Dict[str, str]:
    out: Dict[str, str] = {}
    path = root / "etc/os-release"
    if path.exists():
        for line in path.read_text().splitlines():
            key, _, value = line.partition("=")
            out[key] = value.strip().strip('"')
    return out


def apt_available(packages: Sequence[str]) -> List[str]:
    """Which of the packages the configured apt sources offer (needs fresh lists)."""
    out = run(["apt-cache", "policy", *packages], step="prepare", capture=True)
    available, current = [], None
    for line in out.splitlines():
        if not line.startswith(" "):
            current = line.rstrip(":")
        elif current and "Candidate:" in line and "(none)" not in line:
            available.append(current)
    return available


# LOCKED: the lock's pins for prepare as apt preferences, base.pref (the base stage: the run
# entry's) and dev.pref (the toolchain: the dev entry's), which the tool passes as BuildKit
# secrets and the stages mount here; ensure-python.sh, first in the base stage, puts base.pref
# in place and keeps dpkg's state from before it installs anything.
LOCK_PINS = Path("/docker-ros/lock-pins")
BEFORE_PREPARE = Path("/run/docker-ros/dpkg-status.before")


@contextmanager
def held_to_lock(dependency_types: object, *, dry_run: bool) -> Iterator[None]:
    """In a locked build (the stage holds the lock's pins): what prepare installs meanwhile
    comes at docker-ros.lock's versions, dependencies included (apt preferences, removed
    again); then stop unless what it installed is exactly the lock's, naming each difference."""
    pins_file = LOCK_PINS / ("dev.pref" if dependency_types == "all" else "base.pref")
    if dry_run or not pins_file.is_file() or not pins_file.stat().st_size:
        yield
        return
    before = read_dpkg_status(BEFORE_PREPARE if BEFORE_PREPARE.is_file() else DPKG_STATUS)
    LOCK_PREFERENCES.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(str(pins_file), str(LOCK_PREFERENCES))
    try:
        yield
    finally:
        LOCK_PREFERENCES.unlink()
    problems = unlocked_installs(parse_apt_preferences(pins_file.read_text()), before,
                                 read_dpkg_status(DPKG_STATUS))
    if problems:
        raise StepError("prepare", f"LOCKED: prepare installed otherwise than docker-ros.lock: "
                        f"{'; '.join(problems)}. A locked version is no longer available from "
                        f"apt's sources ({'; '.join(apt_sources()) or 'none configured'}), or "
                        "the base image or ROS_DISTRO, RMW_IMPLEMENTATION, "
                        "ROS_APT_SOURCE_VERSION, DISABLE_ROS_INSTALLATION changed since the "
                        "lock: run `inv lock`")


APT_KEEP_CACHE = Path("/etc/apt/apt.conf.d/docker-ros-keep-cache")
DOCKER_CLEAN = Path("/etc/apt/apt.conf.d/docker-clean")


def keep_apt_downloads(*, dry_run: bool) -> None:
    """Official Debian/Ubuntu images delete downloaded .debs (docker-clean); the build keeps
    them in a cache mount instead, so a rebuild downloads nothing twice."""
    if dry_run:
        print(f"[dry-run] prepare: remove {DOCKER_CLEAN}, write {APT_KEEP_CACHE}")
        return
    if DOCKER_CLEAN.exists():
        DOCKER_CLEAN.unlink()
    if APT_KEEP_CACHE.parent.is_dir():
        APT_KEEP_CACHE.write_text('Binary::apt::APT::Keep-Downloaded-Packages "true";\n')


PIP_CONF = Path("/etc/pip.conf")


def allow_pip_system_installs(conf: Path = PIP_CONF, *, dry_run: bool) -> None:
    """As docker-ros (`pip config --global set global.break-system-packages true`): a `pip
    install` in the user's hooks or in a dev container works on PEP 668 bases (Debian 12,
    Ubuntu 24.04); a pip that predates the option ignores it. The file's other settings stay."""
    if dry_run:
        print(f"[dry-run] prepare: set break-system-packages = true in {conf}")
        return
    config = configparser.ConfigParser()
    config.read(str(conf))
    if not config.has_section("global"):
        config.add_section("global")
    if config.get("global", "break-system-packages", fallback="") == "true":
        return
    config.set("global", "break-system-packages", "true")
    with conf.open("w") as out:
        config.write(out)


def move_base_workspace(ws: Workspace, *, dry_run: bool) -> None:
    """A base image built by docker-ros has its install at /docker-ros/ws/install: underlay it."""
    if not ws.install.is_dir():
        return
    LOG.info("prepare: base image holds a docker-ros workspace; moving it to %s", BASE_WS)
    if dry_run:
        print(f"[dry-run] prepare: move {ws.install} -> {BASE_WS / 'install'}")
        return
    if (BASE_WS / "install").exists():
        shutil.rmtree(str(BASE_WS / "install"))
    BASE_WS.mkdir(parents=True, exist_ok=True)
    shutil.move(str(ws.install), str(BASE_WS / "install"))
    for leftover in ("src", "build", "log", ".docker-ros"):
        shutil.rmtree(str(ws.root / leftover), ignore_errors=True)


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    environ: Optional[Mapping[str, str]] = None,
    **options: object,
) -> None:
    environ = os.environ if environ is None else environ
    with step_log("prepare"), held_to_lock(options.get("dependency_types"), dry_run=dry_run):
        move_base_workspace(ws, dry_run=dry_run)
        keep_apt_downloads(dry_run=dry_run)
        allow_pip_system_installs(dry_run=dry_run)
        problem = distro_problem(settings.ros_distro)
        if problem:
            raise StepError("prepare", problem)
        distro = settings.ros_distro or environ.get("ROS_DISTRO")
        commands = plan_ros_installation(
            ros_installed=ros_present(distro=distro),
            disabled=settings.disable_ros_installation,
            distro=distro,
            rmw_implementation=settings.rmw_implementation,
            apt_source_version=settings.ros_apt_source_version,
            os_codename=os_release().get("VERSION_CODENAME", ""),
        )
        chosen = explicitly_set(settings, "rmw_implementation")
        if chosen and not distro and not settings.disable_ros_installation and ros_present():
            LOG.warning("prepare: RMW_IMPLEMENTATION=%s is set, but the ROS distribution is "
                        "unknown (no ROS_DISTRO): its package is not installed; set ROS_DISTRO "
                        "or install it in the base image", settings.rmw_implementation)
        for argv in commands:
            run(argv, step="prepare", dry_run=dry_run, env=apt_env())
        rmw_commands = [] if commands else plan_rmw_installation(
            ros_installed=ros_present(distro=distro),
            disabled=settings.disable_ros_installation,
            distro=distro,
            rmw_implementation=settings.rmw_implementation,
            chosen=chosen,
            installed=list(read_dpkg_status()),
        )
        try:
            for argv in rmw_commands:
                run(argv, step="prepare", dry_run=dry_run, env=apt_env())
        except StepError as exc:
            rmw = settings.rmw_implementation
            raise StepError("prepare", exc.said_more(
                f": the package of RMW_IMPLEMENTATION={rmw} could not be installed: check "
                f"RMW_IMPLEMENTATION and ROS_DISTRO ({distro}), and that the base image's apt "
                "sources have ROS packages (or set DISABLE_ROS_INSTALLATION=true)"),
                exc.returncode) from None
        if options.get("dependency_types") == "all":
            # dependencies-dev stage: the base is prepared already; add the build toolchain.
            if shutil.which("g++") is None:
                LOG.info("prepare: installing the build toolchain of the dev image")
                run(["apt-get", "update"], step="prepare", dry_run=dry_run, env=apt_env())
                run(["apt-get", "install", *IMAGE_INSTALL, *DEV_TOOLS],
                    step="prepare", dry_run=dry_run, env=apt_env())
            return
        missing = [tool for tool in TOOLS if shutil.which(tool) is None]
        extra = [tool for tool in DOCKER_ROS_TOOLS if shutil.which(tool) is None]
        if missing or extra:
            LOG.info("prepare: installing missing tools: %s", ", ".join([*missing, *extra]))
            run(["apt-get", "update"], step="prepare", dry_run=dry_run, env=apt_env())
            candidates = [p for tool in [*missing, *extra]
                          for p in {**TOOLS, **DOCKER_ROS_TOOLS}[tool]]
            available = apt_available([*candidates, *DEBIAN_COLCON_EXTRAS])
            packages = [*plan_tool_packages(missing, available),
                        *plan_docker_ros_packages(extra, available)]
            if packages:
                run(["apt-get", "install", *IMAGE_INSTALL, *packages],
                    step="prepare", dry_run=dry_run, env=apt_env())
