"""ROS package discovery: package.xml parsing (formats 1-3, conditions) and dependency keys."""

import logging
import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Dict, Iterable, List, Mapping, NamedTuple, Optional, Sequence, Set, Tuple

from docker_ros.runtime.files import walk
from docker_ros.runtime.rosenv import BASE_IMAGE_WS, ros_distro, ros_version
from docker_ros.runtime.workspace import IGNORE_MARKERS, StepError, Workspace

LOG = logging.getLogger(__name__)

DEPENDENCY_TAGS = (
    "depend",
    "build_depend",
    "buildtool_depend",
    "build_export_depend",
    "buildtool_export_depend",
    "exec_depend",
    "run_depend",
    "test_depend",
    "doc_depend",
)
# As rosdep: every type except documentation for a dev image ...
DEPENDENCY_SETS: Dict[str, Tuple[str, ...]] = {
    "all": tuple(t for t in DEPENDENCY_TAGS if t != "doc_depend"),
    # ... and what rosdep's `-t exec` means (catkin_pkg's exec_depends) for a run image.
    "exec": ("depend", "exec_depend", "run_depend"),
}


class Package(NamedTuple):
    name: str
    path: Path
    format: int
    build_type: str
    depends: Mapping[str, Tuple[str, ...]]  # dependency tag -> keys (conditions evaluated)


# --- conditions (catkin_pkg's grammar: comparisons joined by `and`/`or`, parentheses) ---

_TOKEN = re.compile(
    r"""\s*(?:
        (?P<op>==|!=|>=|<=|>|<)
      | (?P<paren>[()])
      | "(?P<dq>[^"]*)"
      | '(?P<sq>[^']*)'
      | (?P<var>\$[A-Za-z0-9_]+)
      | (?P<word>[A-Za-z0-9_-]+)
    )""",
    re.VERBOSE,
)


def _tokens(text: str) -> List[Tuple[str, str]]:
    out: List[Tuple[str, str]] = []
    pos = 0
    text = text.rstrip()
    while pos < len(text):
        match = _TOKEN.match(text, pos)
        if not match or match.end() == pos:
            raise ValueError(f"condition {text!r}: cannot parse at {text[pos:]!r}")
        pos = match.end()
        kind = match.lastgroup or ""
        value = match.group(kind)
        if kind in ("dq", "sq"):
            kind = "value"
        elif kind == "word":
            kind = value if value in ("and", "or") else "value"
        out.append((kind, value))
    return out


def evaluate_condition(condition: Optional[str], context: Mapping[str, str]) -> bool:
    """Evaluate a package.xml `condition` attribute like catkin_pkg (unset variables are "")."""
    if condition is None:
        return True
    tokens = _tokens(condition)
    if not tokens:
        raise ValueError(f"condition {condition!r} is empty")
    pos = 0
    ops = {
        "==": lambda a, b: a == b,
        "!=": lambda a, b: a != b,
        ">=": lambda a, b: a >= b,
        "<=": lambda a, b: a <= b,
        ">": lambda a, b: a > b,
        "<": lambda a, b: a < b,
    }

    def peek() -> str:
        return tokens[pos][0] if pos < len(tokens) else ""

    def take(kind: str) -> str:
        nonlocal pos
        if peek() != kind:
            found = tokens[pos][1] if pos < len(tokens) else "end"
            raise ValueError(f"condition {condition!r}: expected {kind}, found {found!r}")
        pos += 1
        return tokens[pos - 1][1]

    def term() -> str:
        if peek() == "var":
            return str(context.get(take("var")[1:], ""))
        return take("value")

    def atom() -> bool:
        if peek() == "paren" and tokens[pos][1] == "(":
            take("paren")
            value = disjunction()
            if peek() != "paren" or tokens[pos][1] != ")":
                raise ValueError(f"condition {condition!r}: missing ')'")
            take("paren")
            return value
        left = term()
        op = take("op")
        right = term()
        return bool(ops[op](left, right))

    def conjunction() -> bool:
        values = [atom()]
        while peek() == "and":
            take("and")
            values.append(atom())
        return all(values)

    def disjunction() -> bool:
        values = [conjunction()]
        while peek() == "or":
            take("or")
            values.append(conjunction())
        return any(values)

    result = disjunction()
    if pos != len(tokens):
        raise ValueError(f"condition {condition!r}: unexpected {tokens[pos][1]!r}")
    return result


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


# --- package.xml ---


def parse_package_xml(
    text: str, context: Optional[Mapping[str, str]] = None, path: Path = Path(".")
) -> Package:
    """Name, format, build type and (condition-filtered) dependency keys of a package.xml."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ValueError(f"not valid XML: {exc}") from None
    if root.tag != "package":
        raise ValueError(f"root element is <{root.tag}>, not <package>")
    name = (root.findtext("name") or "").strip()
    if not name:
        raise ValueError("no <name>")
    fmt = int(root.get("format", "1"))
    ctx = context if context is not None else {}
    depends: Dict[str, List[str]] = {tag: [] for tag in DEPENDENCY_TAGS}
    for element in root:
        if element.tag not in depends:
            continue
        key = (element.text or "").strip()
        if key and evaluate_condition(element.get("condition"), ctx):
            depends[element.tag].append(key)
    build_type = "catkin" if fmt == 1 else ""
    export = root.find("export")
    if export is not None:
        for element in export.findall("build_type"):
            if evaluate_condition(element.get("condition"), ctx):
                build_type = (element.text or "").strip()
                break
    return Package(
        name=name,
        path=path,
        format=fmt,
        build_type=build_type or "catkin",
        depends={tag: tuple(keys) for tag, keys in depends.items()},
    )


def _is_ignored(entries: Iterable[str]) -> bool:
    return any(marker in entries for marker in IGNORE_MARKERS)


def find_package_dirs(root: Path) -> List[Path]:
    """Directories with a package.xml, as colcon finds them: not below an ignore marker,
    not inside another package."""
    found: List[Path] = []

    def prune(directory: Path, entries: List[str]) -> bool:
        return _is_ignored(entries) or "package.xml" in entries

    for directory in walk(root, prune=prune):
        entries = os.listdir(str(directory))
        if _is_ignored(entries):
            continue
        if "package.xml" in entries:
            found.append(directory)
    return found


def find_packages(
    ws: Workspace, settings: object, *, step: str, environ: Optional[Mapping[str, str]] = None
) -> List[Package]:
    """Every ROS package of the workspace sources, conditions evaluated for ROS_DISTRO."""
    ws.require_sources(step)
    context = condition_context(ros_distro(settings, environ), environ)
    packages = []
    for directory in find_package_dirs(ws.src):
        path = directory / "package.xml"
        try:
            packages.append(parse_package_xml(path.read_text(), context, directory))
        except (ValueError, OSError) as exc:
            raise StepError(step, f"{path}: {exc}") from None
    duplicates = duplicate_packages(packages)
    if duplicates:
        listed = "; ".join(
            f"{name} in {' and '.join(ws.relative(p) for p in paths)}"
            for name, paths in duplicates.items()
        )
        raise StepError(step, f"two packages with the same name: {listed} (colcon cannot build "
                        "both: remove one, or put a COLCON_IGNORE file in its folder)")
    return packages


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


def underlay_packages(root: Path = BASE_IMAGE_WS) -> List[str]:
    """Names of the packages installed in a base image's docker-ros workspace (colcon's
    package index, isolated or merged layout)."""
    install = root / "install"
    index = [*install.glob("share/colcon-core/packages/*"),
             *install.glob("*/share/colcon-core/packages/*")]
    return sorted({p.name for p in index if p.is_file()})
