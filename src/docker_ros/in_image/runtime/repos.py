""".repos files read the way `vcs import` reads them: by vcstool's own reader (YAML; the vcstool
format, `repositories: {name: {type, url, version}}`, and the rosinstall format, a list of
`- git: {local-name, uri, version}`). vcstool, and PyYAML with it, is present wherever the clone
step runs (the image's prepare step installs it before); it is imported when a file is read,
so that importing this module needs the standard library only (Python 3.8+, runs in images)."""

import functools
import io
import json
import re
import shutil
import subprocess
from pathlib import Path, PurePosixPath
from typing import Any, Dict, Iterable, List, Mapping, Optional, Tuple

from docker_ros.in_image.runtime.process import tool_path
from docker_ros.in_image.runtime.rosdeprules import yaml_module, yaml_problem
from docker_ros.in_image.runtime.workspace import StepError, read_user_text

Repos = Dict[str, Dict[str, str]]
KEYS = ("type", "url", "version")

# Run by an interpreter that has vcstool when ours has not (e.g. vcs installed with pipx).
READER = """
import json, sys
from vcstool.commands.import_ import get_repositories
try:
    with open(sys.argv[1]) as handle:
        print(json.dumps({"repositories": get_repositories(handle)}, default=str))
except RuntimeError as exc:
    print(json.dumps({"error": str(exc)}))
"""


def is_empty(text: str) -> bool:
    """Nothing but comments, blank lines and document markers: an empty .repos file, which the
    clone step skips (vcstool would reject it as 'not valid format')."""
    return all(
        not line.strip() or line.lstrip().startswith("#") or line.strip() in ("---", "...")
        for line in text.splitlines()
    )


def normalise(repos: Mapping[str, Any]) -> Repos:
    """name -> {type, url, version} as strings (YAML may give `version: 1.0` as a number)."""
    return {
        str(name): {key: str(spec[key]) for key in KEYS if spec.get(key) is not None}
        for name, spec in repos.items()
        if isinstance(spec, Mapping)
    }


# The keys of an entry vcstool reads (vcstool format, then rosinstall's).
READ_KEYS = ("type", "url", "version", "local-name", "uri")

EXPECTED = ("expected `repositories:` with `name: {type, url, version}` entries, or a "
            "rosinstall list of `- git: {local-name, uri, version}`")


def read_repos(path: Path, *, step: str, shown: str = "") -> Repos:
    """The repositories `vcs import --input path` would import: name -> {type, url, version}.
    A file vcstool cannot read is a StepError naming the file (as `shown`) and vcstool's
    reason."""
    text = read_user_text(path, functools.partial(StepError, step), shown)
    if is_empty(text):
        return {}
    problems: List[str] = []
    try:  # vcstool is no standard library: where it is installed (the host extra, images' tools)
        from vcstool.commands.import_ import get_repositories
    except ImportError:
        repos = _read_elsewhere(Path(path), step=step, shown=shown)
    else:
        import yaml  # vcstool's own dependency

        try:
            repos = normalise(get_repositories(io.StringIO(text)))
        except RuntimeError as exc:
            raise StepError(step, unreadable(shown or str(path), str(exc))) from None
        problems = entry_problems(yaml.safe_load(text), yaml.load(text, Loader=yaml.BaseLoader))
    problems = problems or name_problems(repos)
    if problems:
        raise StepError(step, f"{shown or path}: {'; '.join(problems)}: fix the file")
    return repos


def name_problems(names: Iterable[str]) -> List[str]:
    """Repository names `vcs import` would clone outside the folder it imports into."""
    return [f"repository name '{name}' leaves src/upstream (give a relative path without '..')"
            for name in names
            if not name.strip() or PurePosixPath(name).is_absolute()
            or ".." in PurePosixPath(name).parts]


def raw_entries(data: Any) -> List[Tuple[str, Mapping[str, Any], Tuple[str, str]]]:
    """A .repos file's entries as YAML gives them: (name, attributes, required keys)."""
    if isinstance(data, dict) and isinstance(data.get("repositories"), dict):
        return [(str(name), spec, ("type", "url"))
                for name, spec in data["repositories"].items() if isinstance(spec, Mapping)]
    if isinstance(data, list):
        specs = [next(iter(item.values())) if isinstance(item, dict) and len(item) == 1 else None
                 for item in data]
        return [(str(spec.get("local-name") or f"#{index + 1}"), spec, ("local-name", "uri"))
                for index, spec in enumerate(specs) if isinstance(spec, Mapping)]
    return []


def entry_problems(data: Any, text: Any = None) -> List[str]:
    """What vcstool would skip with only a warning (an entry without type or url, or without
    local-name or uri), clone outside src/upstream (a name with '..'), or read otherwise than
    written: a list or mapping as a value (vcstool fails with a traceback), a value that YAML
    reads as another text (`version: 1.10` is the number 1.1, and vcstool would check out
    `1.1`). text: the same file read with all values as written (YAML's BaseLoader)."""
    entries = raw_entries(data)
    written = {name: spec for name, spec, _ in raw_entries(text)}
    problems = [f"repository '{name}' has no {key}" for name, spec, keys in entries
                for key in keys if spec.get(key) in (None, "")]
    for name, spec, _ in entries:
        for key, value in spec.items():
            if key not in READ_KEYS:
                continue  # (vcstool reads no other key)
            as_written = written.get(name, {}).get(key)
            if isinstance(value, (list, dict)):
                problems.append(f"repository '{name}' has a {type(value).__name__} as {key}: "
                                "give one value")
            elif (value is not None and not isinstance(value, str)
                  and isinstance(as_written, str) and str(value) != as_written):
                problems.append(f"repository '{name}': YAML reads {key} {as_written} as "
                                f"{value}: quote it ({key}: '{as_written}')")
    return problems + name_problems(name for name, _, _ in entries)


def unreadable(shown: str, reason: str) -> str:
    """One line: vcstool's reason (a YAML error spans lines), and the expected form when the
    file is YAML but not a list of repositories."""
    text = " ".join(reason.split())
    if "yaml" not in text:
        text += f" ({EXPECTED})"
    return f"{shown} is not a .repos file vcstool can read: {text}: fix the file"


def repos_problem(path: Path, shown: str) -> Optional[str]:
    """What keeps vcstool from reading a .repos file, in one line naming `shown` (None when it
    reads, or when no YAML reader is here: the clone step reports it then)."""
    data, problem = yaml_problem(path, shown)
    if problem:
        return f"{problem}: fix the file (vcstool cannot import it)"
    if data is None or isinstance(data, list) or (
            isinstance(data, dict) and isinstance(data.get("repositories"), dict)):
        yaml = yaml_module()
        text = yaml.load(read_user_text(path, ValueError, shown), Loader=yaml.BaseLoader) if (
            yaml and data is not None) else None
        problems = entry_problems(data, text)
        return f"{shown}: {'; '.join(problems)}: fix the file" if problems else None
    return f"{shown}: not a .repos file: {EXPECTED}"


def interpreters(vcs: Optional[str]) -> List[List[str]]:
    """Interpreters that may have vcstool: the one of the `vcs` script (its #! line), then
    python3 from PATH."""
    found: List[List[str]] = []
    if vcs:
        try:
            with open(vcs, "rb") as handle:
                first = handle.readline().decode(errors="replace")
        except OSError:
            first = ""
        if first.startswith("#!") and re.search(r"python[\d.]*\b", first):
            found.append(first[2:].split())
    return found + [["python3"]]


def _read_elsewhere(path: Path, *, step: str, shown: str) -> Repos:
    for interpreter in interpreters(shutil.which(tool_path("vcs"))):
        try:
            proc = subprocess.run([*interpreter, "-c", READER, str(path)],
                                  capture_output=True, text=True)
        except OSError:
            continue
        lines = proc.stdout.strip().splitlines()
        if proc.returncode != 0 or not lines:
            continue
        answer = json.loads(lines[-1])
        if "error" in answer:
            raise StepError(step, unreadable(shown or str(path), answer["error"]))
        return normalise(answer["repositories"])
    raise StepError(step, f"cannot read {path}: no Python here has vcstool (which the clone "
                          "step needs anyway): install vcstool (pip install vcstool, or apt "
                          "python3-vcstool)")
