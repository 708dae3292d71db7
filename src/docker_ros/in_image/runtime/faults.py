"""What a failed tool said: its own error lines (apt, dpkg, pip, git, a compiler, CMake), a full
disk, a host or URL it could not reach, and the advice for each. Pure functions of its output
lines. Standard library only, Python 3.8+ (the steps use it in images and on the host)."""

import re
from typing import List, Optional, Sequence, Tuple
from urllib.parse import urljoin

# How many of a tool's lines a message carries, and how long each may be.
SHOWN_LINES = 3
LINE_LENGTH = 300

# apt's errors, and those of its warnings that say why an install will fail.
APT = re.compile(r"^E: |^W: .*(?:[Ff]ail|space)")
DPKG = re.compile(r"^dpkg: error")
PIP = re.compile(r"^ERROR: (?!Exception:$)")
# The first compiler diagnostic: file, line (and column).
COMPILER = re.compile(r"^(?P<file>[^\s:]+):(?P<line>\d+):(?:\d+:)? (?:fatal )?error: ")
CMAKE = re.compile(r"^CMake Error")
GIT = re.compile(r"^fatal: ")
# Any program, in any words: the errno of a full file system (and apt's check before it).
NO_SPACE = re.compile(r"no space left on device|ENOSPC|\[Errno 28\]|"
                      r"You don't have enough free space in", re.IGNORECASE)

# (url, reason) of a network failure, by the words of apt, git, vcstool, pip and curl.
_APT_FETCH = re.compile(r"Failed to fetch (\S+)\s+(.*)")
_GIT_ACCESS = re.compile(r"unable to access '([^']+)': (.*)")
_GIT_CONNECT = re.compile(r"fatal: unable to connect to (\S+?):?$")
_VCS_CLONE = re.compile(r"Could not clone repository '([^']+)'")
_GIT_REMOTE = re.compile(r"fatal: (?:'([^']+)' does not appear to be a git repository|"
                         r"the remote end hung up unexpectedly|early EOF|"
                         r"Could not read from remote repository)")
_PIP_FETCH = re.compile(r"Could not fetch URL (\S+?): (.*)")
_PIP_RETRY = re.compile(r"after connection broken by '(.*)': (/\S*)$")
_PIP_INDEX = re.compile(r"Looking in indexes: (\S+?),?$")
_CURL = re.compile(r"curl: \(\d+\) (.*)")
_REASON = re.compile(r"Could not connect to [^\s(]+|Failed to connect to \S+ port \d+|"
                     r"Could not resolve(?: host)?:? '?[^'\s)]+'?|Temporary failure resolving "
                     r"'[^']*'|Temporary failure in name resolution|Connection refused|"
                     r"Connection timed out|Network is unreachable|No route to host|"
                     r"Name or service not known|Connection reset by peer|"
                     r"Couldn't connect to server|Max retries exceeded", re.IGNORECASE)


def shorten(text: str) -> str:
    text = text.strip()
    return text if len(text) <= LINE_LENGTH else text[:LINE_LENGTH - 3] + "..."


def tool_lines(lines: Sequence[str]) -> List[str]:
    """The failing tool's own error lines, in their order, each once, at most SHOWN_LINES:
    apt's `E:` and its warnings of a failure (of its failed fetches the first), dpkg's error
    with the line after it, pip's `ERROR:`, git's `fatal:`, the first compiler `error:`
    (file:line: ...), CMake's error with the first line of its explanation, and a `No space
    left on device` anywhere."""
    found: List[str] = []
    compiler = False
    for index, raw in enumerate(lines):
        line = raw.strip()
        following = lines[index + 1].strip() if index + 1 < len(lines) else ""
        text = ""
        if APT.match(line) or PIP.match(line) or GIT.match(line):
            text = line
        elif DPKG.match(line):
            text = f"{line} {following}" if following else line
        elif CMAKE.match(line):
            text = f"{line.rstrip(':')}: {following}" if following else line
        elif COMPILER.match(line) and not compiler:
            compiler = True
            text = line
        elif NO_SPACE.search(line) and not any(NO_SPACE.search(f) for f in found):
            text = line
        if "Failed to fetch " in text and any("Failed to fetch " in f for f in found):
            continue  # (one per URL: the first says why, the others repeat it)
        if text and shorten(text) not in found:
            found.append(shorten(text))
    return prefer_errors(found)[:SHOWN_LINES]


def prefer_errors(found: Sequence[str]) -> List[str]:
    """found, apt's warnings after the errors when there are more than SHOWN_LINES (a full
    disk's line first of all: the cause, where apt's `E:` after it is the consequence)."""
    if len(found) <= SHOWN_LINES:
        return list(found)
    rank = [0 if NO_SPACE.search(f) else 2 if f.startswith("W: ") else 1 for f in found]
    return [f for _, _, f in sorted(zip(rank, range(len(found)), found))]


def disk_full(lines: Sequence[str]) -> bool:
    """Whether the output says that a file system was full (apt, dpkg, pip, a compiler, git,
    BuildKit's layer export: `no space left on device` in their words, or apt's own check)."""
    return any(NO_SPACE.search(line) for line in lines)


def unreachable(lines: Sequence[str]) -> Tuple[str, str]:
    """(URL, reason) of the first host that the output says could not be reached: apt's
    `Failed to fetch URL  reason`, git's `unable to access 'URL'` or `unable to connect to
    HOST`, vcstool's `Could not clone repository 'URL'` with git's reason, pip's `Could not
    fetch URL` or its retries (the index's URL), curl's; ("", "") when it names none."""
    index = ""
    for number, raw in enumerate(lines):
        line = raw.strip()
        found = _PIP_INDEX.search(line)
        if found:
            index = found.group(1)
        for pattern in (_APT_FETCH, _GIT_ACCESS, _PIP_FETCH):
            found = pattern.search(line)
            if found and (_REASON.search(found.group(2)) or pattern is not _APT_FETCH):
                return found.group(1), reason_of(found.group(2))
        found = _GIT_CONNECT.search(line)
        if found:
            following = lines[number + 1].strip() if number + 1 < len(lines) else ""
            return found.group(1), reason_of(following)
        found = _VCS_CLONE.search(line)
        if found:
            reason = clone_reason(lines[number:number + 6])
            if reason:
                return found.group(1), reason
        found = _PIP_RETRY.search(line)
        if found and index:
            return urljoin(index.rstrip("/") + "/", found.group(2)), reason_of(found.group(1))
        found = _CURL.search(line)
        if found and _REASON.search(found.group(1)):
            return "", reason_of(found.group(1))
    return "", ""


def clone_reason(block: Sequence[str]) -> str:
    """Why git could not reach the remote of a clone, from the lines vcstool shows of it (its
    own `Could not clone repository` line first), '' when they say nothing of the remote."""
    for line in block:
        if _REASON.search(line):
            return reason_of(line)
        remote = _GIT_REMOTE.search(line)
        if remote:
            return reason_of(remote.group(0)[len("fatal: "):])
    return ""


def reason_of(text: str) -> str:
    """The words of a network failure that say what happened (`Could not connect to
    127.0.0.1:9: Connection refused`), else the text itself, shortened."""
    found: List[str] = []
    for match in _REASON.finditer(text):
        if match.group(0) not in found:
            found.append(match.group(0))
    return ": ".join(found[:2]) if found else shorten(text)[:120]


def network_line(url: str, reason: str) -> str:
    """The message's line for a host the tool could not reach."""
    return (f"could not reach {url} ({reason}): check that the server is up and reachable "
            "from here (a proxy, DNS, or the mirror, index or repository URL), then rerun")


def size(free: Optional[int]) -> str:
    if free is None:
        return "free space unknown"
    for unit, factor in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if free >= factor:
            return f"{free / factor:.0f} {unit} free" if unit != "GB" else \
                f"{free / factor:.1f} {unit} free"
    return f"{free} bytes free"


def engine_disk_line(root: str, free: Optional[int]) -> str:
    """The message's line for a full disk of the engine (root: its DockerRootDir, '' when
    unknown; free: bytes free there, None when that cannot be read from here)."""
    where = f"the engine's data root {root} ({size(free)})" if root else "the engine's disk"
    return (f"the disk is full: {where}; see what takes the room with `docker system df`, "
            "then remove images or build cache of yours that you no longer need (`docker "
            "image rm`, `docker builder prune`) and rerun; docker-ros removes nothing itself")


def host_disk_line(places: Sequence[Tuple[str, Optional[int]]]) -> str:
    """The message's line for a full disk of the host (places: the folders the step writes
    to, as (path, bytes free))."""
    where = ", ".join(f"{path} ({size(free)})" for path, free in places) or "the host"
    return (f"the disk is full: {where}; free room there and rerun; docker-ros removes "
            "nothing itself")
