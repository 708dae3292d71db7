"""pip requirement files read by pip's rules (pip/_internal/req/req_file.py): a line ending in
`\\` continues on the next, a comment starts at `#` at line start or after white space, and a
nested `-r`/`-c FILE` is read relative to the folder of the file that names it (a URL stays for
pip to fetch), and so is a `--find-links` folder that exists there. Environment variables
(`${NAME}`) are left for pip to expand when it installs, so that no secret lands in the saved
plan. Standard library only, Python 3.8+ (runs in images)."""

import functools
import os
import re
import shlex
from pathlib import Path
from typing import List, NamedTuple, Optional, Sequence, Tuple

from docker_ros.in_image.runtime.workspace import StepError, read_user_text

COMMENT = re.compile(r"(^|\s+)#.*$")
SCHEME = re.compile(r"^\w+(\+\w+)?://")


class RequirementFile(NamedTuple):
    """What one requirement file adds to a pip install, nested files inlined."""

    requirements: List[str]  # requirement and option lines, in order
    constraints: List[str]  # the lines of the constraint files (-c) it names
    files: List[Path]  # every local file read, the file itself first


def logical_lines(text: str) -> List[Tuple[int, str]]:
    """(first physical line number, line) of each line pip reads: continuations joined, then
    comments and blank lines dropped (pip's join_lines and ignore_comments)."""
    joined: List[Tuple[int, str]] = []
    parts: List[str] = []
    first = 0
    for number, line in enumerate(text.splitlines(), 1):
        if not line.endswith("\\") or COMMENT.match(line):
            if COMMENT.match(line):
                line = " " + line  # a comment ends a continuation and is dropped below
            if parts:
                joined.append((first, "".join(parts + [line])))
                parts = []
            else:
                joined.append((number, line))
        else:
            if not parts:
                first = number
            parts.append(line.strip("\\"))
    if parts:
        joined.append((first, "".join(parts)))
    stripped = [(number, COMMENT.sub("", line).strip()) for number, line in joined]
    return [(number, line) for number, line in stripped if line]


SHORT = {"-r": "--requirement", "-c": "--constraint", "-f": "--find-links"}


def path_options(line: str) -> List[Tuple[str, str]]:
    """(long option, value) of the options naming files on a line, as pip's option parser
    reads it: the options start at the first token beginning with `-`."""
    tokens = line.split(" ")
    start = next((i for i, token in enumerate(tokens) if token.startswith("-")), len(tokens))
    try:
        words = shlex.split(" ".join(tokens[start:]))
    except ValueError:
        return []  # pip rejects the line itself
    found: List[Tuple[str, str]] = []
    for index, word in enumerate(words):
        flag, equals, value = word.partition("=")
        flag = SHORT.get(flag, flag)
        if flag in SHORT.values() and (equals or index + 1 < len(words)):
            found.append((flag, value if equals else words[index + 1]))
        elif word[:2] in SHORT and len(word) > 2:
            found.append((SHORT[word[:2]], word[2:]))
    return found


def nested_file(line: str) -> Optional[Tuple[bool, str]]:
    """(is a constraint file, its name) when the line names a nested file; as in pip, the
    first -r/--requirement wins over -c/--constraint."""
    options = path_options(line)
    for flag, constraint in (("--requirement", False), ("--constraint", True)):
        names = [value for option, value in options if option == flag]
        if names:
            return constraint, names[0]
    return None


def find_links_line(line: str, folder: str) -> str:
    """The line with its first --find-links path made absolute when it exists relative to the
    requirement file's folder (pip's rule; a path relative to the working directory otherwise)."""
    links = [value for option, value in path_options(line) if option == "--find-links"]
    if not links or SCHEME.match(links[0]) or "${" in links[0]:
        return line
    beside = os.path.join(folder, links[0])
    if not os.path.exists(beside):
        return line
    return line.replace(links[0], shlex.quote(os.path.abspath(beside)), 1)


def read_requirement_file(path: Path, *, step: str, missing_ok: bool = False) -> RequirementFile:
    """The lines pip would install from `path` (nested files inlined). A nested file that does
    not exist, or a cycle, is a StepError naming the file and line (with missing_ok: skipped)."""
    result = RequirementFile([], [], [])
    _read(Path(path), False, result, step=step, missing_ok=missing_ok, chain=())
    return result


def _read(path: Path, constraint: bool, result: RequirementFile, *, step: str,
          missing_ok: bool, chain: Sequence[str]) -> None:
    result.files.append(path)
    for number, line in logical_lines(read_user_text(path, functools.partial(StepError, step))):
        nested = nested_file(line)
        if nested is None:
            line = find_links_line(line, os.path.dirname(str(path)))
            (result.constraints if constraint else result.requirements).append(line)
            continue
        nested_constraint, name = nested
        if SCHEME.match(name):
            result.requirements.append(line)  # pip fetches it when it installs
            continue
        target = Path(os.path.normpath(os.path.join(os.path.dirname(str(path)), name)))
        where = f"{path}:{number}"
        if str(target) in (*chain, str(path)):
            raise StepError(step, f"{where}: `{line}` includes a file that includes it again "
                                  f"({' -> '.join([*chain, str(path), str(target)])})")
        if not target.is_file():
            if missing_ok:
                continue
            raise StepError(step, f"{where}: `{line}`: {target} not found (a nested file is "
                                  "read relative to the folder of the file naming it, as pip does)")
        # as pip: -r makes requirements, -c constraints, whatever the naming file was
        _read(target, nested_constraint, result, step=step, missing_ok=missing_ok,
              chain=[*chain, str(path)])
