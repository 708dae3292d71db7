"""The repository's rosdep rules file (ROSDEP_RULES_FILE): checked as YAML before anything runs
(rosdep skips a file it cannot read, with a warning lost in the build log), and compared with
the base's rules that `rosdep update` cached, to name the keys it overrides.
Standard library at import time (runs in images); YAML is read with PyYAML, which rosdep needs
and the host has with invoke, imported when a file is checked."""

import hashlib
import importlib
import os
import pickle
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Tuple

from docker_ros.in_image.runtime.workspace import read_user_text

Rules = Dict[str, Any]
CACHE = Path("rosdep") / "sources.cache"  # below ROS_HOME


def yaml_module() -> Any:
    """PyYAML (rosdep's), else invoke's (the host's docker-ros has invoke), else None."""
    for name in ("yaml", "invoke.util"):
        try:
            module = importlib.import_module(name)
        except ImportError:
            continue
        return module if name == "yaml" else getattr(module, "yaml", None)
    return None


def yaml_problem(path: Path, shown: str) -> Tuple[Any, Optional[str]]:
    """(the file's data, None), or (None, one line naming `shown`:line:column and YAML's
    reason) when it is not valid YAML; (None, None) when no YAML reader is here."""
    yaml = yaml_module()
    if yaml is None:
        return None, None
    try:
        return yaml.safe_load(read_user_text(path, ValueError, shown)), None
    except ValueError as exc:  # (not UTF-8)
        return None, str(exc)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{shown}:{mark.line + 1}:{mark.column + 1}" if mark else shown
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        context, started = getattr(exc, "context", None), getattr(exc, "context_mark", None)
        if context and started and (not mark or started.line != mark.line):
            problem += f" ({context} at line {started.line + 1})"
        return None, f"{where}: not valid YAML: {problem}"


def rules_problem(path: Path, shown: str) -> Optional[str]:
    """What makes a rules file unusable, in one line naming `shown`:line:column (None when it
    is fine, or when no YAML reader is here: rosdep's own update reports it then)."""
    data, problem = yaml_problem(path, shown)
    if problem:
        return f"ROSDEP_RULES_FILE {problem}: fix the file (rosdep would skip all of its rules)"
    if data is not None and not isinstance(data, dict):
        return (f"ROSDEP_RULES_FILE {shown}: holds a {type(data).__name__}, not rules: map each "
                "rosdep key to its packages, e.g. `my_key: {debian: [libfoo-dev]}`")
    return None


def _cache_file(cache_dir: Path, key: str) -> Path:
    # rosdep's compute_filename_hash: sha1 of the URL (of the URLs joined, for '^' lists)
    return cache_dir / (hashlib.sha1("".join(key.split("^")).encode()).hexdigest() + ".pickle")


def cached_sources(ros_home: Path) -> List[Tuple[str, Rules]]:
    """(URL, rules) of every source `rosdep update` cached under ros_home, in rosdep's order
    (earlier sources win)."""
    cache_dir = ros_home / CACHE
    index = cache_dir / "index"
    if not index.is_file():
        return []
    sources: List[Tuple[str, Rules]] = []
    for line in index.read_text().splitlines():
        parts = line.split()
        if len(parts) < 2 or parts[0] != "yaml":
            continue
        cached = _cache_file(cache_dir, parts[1])
        if cached.is_file():
            data = pickle.loads(cached.read_bytes())  # rosdep's own cache of plain data
            if isinstance(data, dict):
                sources.append((parts[1], data))
    return sources


def overridden_keys(
    own_url: str, sources: List[Tuple[str, Rules]]
) -> Dict[str, Tuple[str, Any, Any]]:
    """key -> (base source URL, the base's definition, ours) for each key of our rules that a
    base source defines otherwise (the first such source: the one rosdep would have used)."""
    own = next((data for url, data in sources if url == own_url), None)
    found: Dict[str, Tuple[str, Any, Any]] = {}
    for url, data in sources:
        if own is None or url == own_url:
            continue
        for key, definition in own.items():
            if key in data and key not in found and data[key] != definition:
                found[key] = (url, data[key], definition)
    return found


def flow(value: Any) -> str:
    """A rule in YAML flow style, as users write them (`debian: [a, b]`)."""
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k}: {flow(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(flow(v) for v in value) + "]"
    return str(value)


def describe(definition: Any, os_name: str) -> str:
    """The part of a definition for this OS (`debian: [...]`), else all of it."""
    if isinstance(definition, Mapping) and os_name in definition:
        return f"{os_name}: {flow(definition[os_name])}"
    return flow(definition)


def override_lines(shown: str, overrides: Mapping[str, Tuple[str, Any, Any]],
                   os_name: str) -> List[str]:
    """One line per overridden key: which, where the base's rule comes from, both rules."""
    return [f"ROSDEP_RULES_FILE {shown} overrides '{key}' of the base's rules ({url}): the base "
            f"has {describe(base, os_name)}, {shown} has {describe(own, os_name)}"
            for key, (url, base, own) in sorted(overrides.items())]


def os_name(os_release: Path = Path("/etc/os-release")) -> str:
    """The OS rosdep resolves for (ROS_OS_OVERRIDE `name:version`, else os-release's ID)."""
    override = os.environ.get("ROS_OS_OVERRIDE", "")
    if override:
        return override.split(":")[0]
    try:
        for line in os_release.read_text().splitlines():
            if line.startswith("ID="):
                return line[3:].strip().strip('"')
    except OSError:
        pass
    return ""
