"""ROS package discovery and the dependency keys rosdep resolves. Packages are found as colcon
finds them; their manifests are parsed (validated) and their REP-149 conditions evaluated by
catkin_pkg, as rosdep and colcon-ros do. rosdep and colcon bring catkin_pkg, so it is there
wherever the steps that read manifests run (blacklist, rosdep, colcon: in images after
`prepare`, on the host with the `host` extra). This module itself imports only the standard
library: it ships into images, and what runs before `prepare` imports it (package_search_dirs,
for the files resolving reads)."""

import logging
import os
from pathlib import Path
from typing import (
    Any,
    Dict,
    Iterable,
    Iterator,
    List,
    Mapping,
    NamedTuple,
    Optional,
    Sequence,
    Set,
    Tuple,
)
from xml.etree import ElementTree

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.files import walk
from docker_ros.in_image.runtime.process import HOST_EXTRA
from docker_ros.in_image.runtime.rosenv import (
    BASE_IMAGE_WS,
    env_paths,
    ros_distro,
    ros_version,
)
from docker_ros.in_image.runtime.workspace import IGNORE_MARKERS, StepError, Workspace

LOG = logging.getLogger(__name__)

# catkin_pkg's dependency lists (`depend` is in build, build_export and exec; format 1's
# `run_depend` in build_export and exec). As rosdep: every type but documentation for a dev
# image, and rosdep's `-t exec` for a run image.
DEPENDENCY_SETS: Dict[str, Tuple[str, ...]] = {
    "all": ("build_depends", "buildtool_depends", "build_export_depends",
            "buildtool_export_depends", "exec_depends", "test_depends"),
    "exec": ("exec_depends",),
}


class Package(NamedTuple):
    name: str
    path: Path
    format: int
    build_type: str
    depends: Mapping[str, Tuple[str, ...]]  # catkin_pkg list name -> keys (conditions evaluated)


def condition_context(
    distro: Optional[str], environ: Optional[Mapping[str, str]] = None
) -> Dict[str, str]:
    """The variables conditions may use (rosdep passes the whole environment, so do we)."""
    env = dict(os.environ if environ is None else environ)
    if distro:
        env["ROS_DISTRO"] = distro
    env["ROS_VERSION"] = ros_version(distro, env)
    env.setdefault("ROS_PYTHON_VERSION", "3")
    return env


def catkin_pkg(step: str) -> Any:
    """catkin_pkg (its package module loaded), or a StepError saying how to get it."""
    try:  # catkin_pkg is no standard library: rosdep's, where it is installed
        import catkin_pkg.package
    except ImportError:
        raise StepError(step, "the Python module catkin_pkg (part of rosdep) is missing; on the "
                        f"host the steps need vcstool, rosdep and colcon: {HOST_EXTRA}") from None
    return catkin_pkg


def one_line(error: Exception) -> str:
    """catkin_pkg's message on one line, without its header naming the file (the caller does):
    `The manifest contains invalid XML: no element found...`."""
    lines = [line.strip() for line in str(error).splitlines()]
    text = ""
    for line in lines:
        if line and not line.startswith("Error(s) in"):
            text += (" " if text.endswith(":") else "; " if text else "") + line
    return text


def parse_package_xml(
    text: str, context: Mapping[str, str], path: Path = Path("."), *, step: str = "packages"
) -> Package:
    """Name, format, build type and (condition-filtered) dependency keys of a package.xml, by
    catkin_pkg. Raises ValueError for an invalid manifest or condition."""
    package_module = catkin_pkg(step).package
    try:
        package = package_module.parse_package_string(text, str(path / "package.xml"), [])
        package.evaluate_conditions(dict(context))
        build_type = package.get_build_type()
    except (package_module.InvalidPackage, ValueError) as exc:
        raise ValueError(one_line(exc)) from None
    return Package(
        name=package.name,
        path=path,
        format=int(package.package_format),
        build_type=build_type,
        depends={kind: tuple(d.name for d in getattr(package, kind)
                             if d.evaluated_condition is not False)
                 for kind in DEPENDENCY_SETS["all"] + ("doc_depends",)},
    )


def find_package_dirs(root: Path) -> List[Path]:
    """Folders with a package.xml, as colcon's recursive crawl finds them: symlinks followed,
    each real folder once, hidden folders skipped, nothing below an ignore marker (COLCON_IGNORE,
    and colcon-ros's AMENT_IGNORE, CATKIN_IGNORE) or inside a package. Folders named build,
    install or log are searched (colcon puts a COLCON_IGNORE in its own). (catkin_pkg's
    find_package_paths has the same rules but enters symlink loops and finds a symlinked
    package twice.)"""
    def ignored(entries: Iterable[str]) -> bool:
        return any(marker in entries for marker in IGNORE_MARKERS)

    def prune(directory: Path, entries: List[str]) -> bool:
        return ignored(entries) or "package.xml" in entries

    return [directory for directory in walk(root, prune=prune, skip=hidden)
            if "package.xml" in os.listdir(str(directory))
            and not ignored(os.listdir(str(directory)))]


def hidden(name: str) -> bool:
    return name.startswith(".")


def package_search_dirs(root: Path) -> Iterator[Path]:
    """Every folder find_package_dirs may find a package in or read an ignore marker from, and
    more (below markers and packages too, and every path to a real folder, not just the first
    one): what runs before `prepare` collects the manifests with it. Stops at symlink loops."""
    for dirpath, dirnames, _ in os.walk(str(root), followlinks=True):
        path = Path(dirpath)
        real = os.path.realpath(dirpath)
        above = [os.path.realpath(str(parent)) for parent in path.parents
                 if parent == root or root in parent.parents]
        if real in above:  # a link back to a folder above: a loop
            dirnames[:] = []
            continue
        dirnames[:] = sorted(d for d in dirnames if not hidden(d))
        yield path


def find_packages(
    ws: Workspace, settings: Settings, *, step: str, environ: Optional[Mapping[str, str]] = None
) -> List[Package]:
    """Every ROS package of the workspace sources, conditions evaluated for ROS_DISTRO."""
    ws.require_sources(step)
    context = condition_context(ros_distro(settings, environ), environ)
    packages = []
    catkin_pkg(step)
    for directory in find_package_dirs(ws.src):
        path = directory / "package.xml"
        try:
            packages.append(parse_package_xml(path.read_text(), context, directory, step=step))
        except (ValueError, OSError) as exc:
            raise StepError(step, f"{ws.relative(path)}: {exc}") from None
    duplicates = duplicate_packages(packages)
    if duplicates:
        raise StepError(step, duplicates_message(
            {name: [ws.relative(p) for p in paths] for name, paths in duplicates.items()}))
    return packages


SHOWN = 5  # entries a message lists; it counts the rest


def listed(items: Sequence[str]) -> str:
    """The first SHOWN items, '; '-joined, and how many more there are."""
    more = f"; and {len(items) - SHOWN} more" if len(items) > SHOWN else ""
    return "; ".join(items[:SHOWN]) + more


def duplicates_message(duplicates: Mapping[str, Sequence[str]]) -> str:
    found = [name + " in " + " and ".join(paths) for name, paths in duplicates.items()]
    text = (f"two packages with the same name: {listed(found)} (colcon cannot build both: "
            "remove one, or put a COLCON_IGNORE file in its folder)")
    if len(duplicates) > SHOWN:
        text += ("; so many look like a folder of several checkouts: run docker-ros in one "
                 "repository, or set BUILD_CONTEXT to it")
    return text


def manifest_problem(directory: Path) -> Optional[str]:
    """What keeps directory's package.xml from naming a package (colcon and the steps would
    stop on it), found without catkin_pkg; None when it names one."""
    path = directory / "package.xml"
    if not path.is_file():
        return "is not a file"
    try:
        root = ElementTree.parse(str(path)).getroot()
    except ElementTree.ParseError as exc:
        return f"is not valid XML ({exc})"
    except OSError as exc:
        return f"cannot be read ({exc.strerror})"
    tag = root.tag.rpartition("}")[2]  # (a namespace, which catkin_pkg allows)
    if tag != "package":
        return f"holds <{tag}>, not <package>"
    name = root.findtext("name")
    return None if name and name.strip() else "has no <name>"


def repository_duplicates(repository: Path, package_dirs: Sequence[Path]
                          ) -> Dict[str, List[str]]:
    """Package names found more than once in a repository's package_dirs (find_package_dirs:
    its own packages, before anything is imported), with the folders relative to it;
    package.xml files that do not parse are left to the steps, which name their error."""
    paths: Dict[str, List[str]] = {}
    for directory in package_dirs:
        name = manifest_name(directory)
        if name:
            paths.setdefault(name, []).append(directory.relative_to(repository).as_posix())
    return {name: found for name, found in sorted(paths.items()) if len(found) > 1}


def manifest_name(directory: Path) -> Optional[str]:
    """The package name in directory's package.xml; None where it does not parse."""
    try:
        name = ElementTree.parse(str(directory / "package.xml")).findtext("name")
    except (ElementTree.ParseError, OSError):
        return None
    return name.strip() if name and name.strip() else None


def duplicate_packages(packages: Sequence[Package]) -> Dict[str, List[Path]]:
    """Package names found more than once, with every folder holding one."""
    paths: Dict[str, List[Path]] = {}
    for package in packages:
        paths.setdefault(package.name, []).append(package.path)
    return {name: found for name, found in sorted(paths.items()) if len(found) > 1}


# --- keys ---


def select_keys(
    packages: Sequence[Package],
    dependency_types: str,
    blacklist: Iterable[str] = (),
    underlay: Iterable[str] = (),
) -> Dict[str, List[str]]:
    """rosdep keys -> sorted names of the packages needing them, for "all" or "exec" types.

    Blacklisted packages are left out, and so are their names: a package depending on a
    blacklisted one does not make it a rosdep key (see blacklisted_dependents, for the warning).
    Keys naming a workspace package are built from source, and packages of the `underlay` (a
    docker-ros base image's workspace) are installed: neither is a rosdep key."""
    if dependency_types not in DEPENDENCY_SETS:
        raise ValueError(
            f"unknown dependency types {dependency_types!r}; use {' or '.join(DEPENDENCY_SETS)}"
        )
    skip: Set[str] = set(blacklist)
    kept = [p for p in packages if p.name not in skip]
    # Blacklisted names count even when their folders are hidden (COLCON_IGNORE in the image).
    local = {p.name for p in packages} | skip | set(underlay)
    keys: Dict[str, Set[str]] = {}
    for package in kept:
        for tag in DEPENDENCY_SETS[dependency_types]:
            for key in package.depends.get(tag, ()):
                if key not in local:
                    keys.setdefault(key, set()).add(package.name)
    return {key: sorted(names) for key, names in sorted(keys.items())}


def blacklisted_dependents(
    packages: Sequence[Package], dependency_types: str, blacklist: Iterable[str]
) -> Dict[str, List[str]]:
    """Blacklisted package -> the packages (not blacklisted) that depend on it."""
    skip = set(blacklist)
    found: Dict[str, Set[str]] = {}
    for package in packages:
        if package.name in skip:
            continue
        for tag in DEPENDENCY_SETS[dependency_types]:
            for key in package.depends.get(tag, ()):
                if key in skip:
                    found.setdefault(key, set()).add(package.name)
    return {name: sorted(users) for name, users in sorted(found.items())}


def environment_packages(env: Mapping[str, str]) -> List[str]:
    """Names of the packages of a (sourced) ROS environment: below each ROS_PACKAGE_PATH folder
    (ROS 1) and in the ament index of each AMENT_PREFIX_PATH prefix (ROS 2). docker-ros runs
    `rosdep install --from-paths src --ignore-src` with /opt/ros/$ROS_DISTRO/setup.bash sourced,
    and rosdep's --ignore-src leaves out exactly these: a package the base image has (in
    /opt/ros or a workspace its setup chains) is installed, not a key that needs a rule."""
    names: Set[str] = set()
    for root in env_paths(env, "ROS_PACKAGE_PATH"):
        if root.is_dir():
            names.update(n for n in map(manifest_name, find_package_dirs(root)) if n)
    for prefix in env_paths(env, "AMENT_PREFIX_PATH"):
        index = prefix / "share/ament_index/resource_index/packages"
        if index.is_dir():
            names.update(entry.name for entry in index.iterdir())
    return sorted(names)


def underlay_packages(root: Path = BASE_IMAGE_WS) -> List[str]:
    """Names of the packages installed in a base image's docker-ros workspace (colcon's
    package index, isolated or merged layout)."""
    install = root / "install"
    index = [*install.glob("share/colcon-core/packages/*"),
             *install.glob("*/share/colcon-core/packages/*")]
    return sorted({p.name for p in index if p.is_file()})
