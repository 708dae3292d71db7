"""What a failed build's log says about the machine, for the last lines of its message: the
failing tool's own error lines, a host it could not reach, a full disk of the engine (its data
root and the room left there). docker-ros never frees room itself: the advice is the user's."""

from __future__ import annotations

import os
import re
import shutil
from typing import Callable, List, Optional, Sequence, Tuple

from docker.errors import DockerException
from requests.exceptions import RequestException
from urllib3.exceptions import HTTPError as TransportError

from docker_ros.host import buildlog, engine
from docker_ros.in_image.runtime import faults

# BuildKit's prefix of a build step's output line (`#12 3.456 `), and its own lines about a
# step (`#12 ERROR: process ... did not complete successfully`, `#12 DONE 1.2s`)
PREFIX = re.compile(r"^#\d+ (?:\d+\.\d+ )?")
STEP_STATUS = re.compile(r"^#\d+ (?:ERROR|DONE|CANCELED|CACHED)\b")

DataRoot = Tuple[str, Optional[int]]


def step_output(lines: Sequence[str]) -> List[str]:
    """The output of the failed build steps, as the tools wrote it (no `#N 1.234 ` prefix)."""
    return [PREFIX.sub("", line.rstrip("\n")) for line in buildlog.failed_output(lines)
            if not STEP_STATUS.match(line)]


def build_lines(lines: Sequence[str], data_root: Callable[[], DataRoot],
                said: str = "") -> List[str]:
    """The lines a failed build's message adds (lines: BuildKit's plain log; said: what the
    message says already, e.g. the clone step's URL and reason): the failing tool's error
    lines, the URL it could not reach, and for a full disk (in a step or in BuildKit's own
    export) the engine's data root and its room (data_root: read only then)."""
    output = step_output(lines)
    shown = [line for line in faults.tool_lines(output) if line not in said]
    own = [line.strip() for line in lines if not line.startswith("#")
           and line.startswith("ERROR") and faults.disk_full([line])]
    if own and not any(faults.disk_full([s]) for s in shown):
        shown.append(faults.shorten(own[0]))
    url, reason = faults.unreachable(output)
    if "://" in url and url not in said:
        shown.append(faults.network_line(url, reason))
    if faults.disk_full(output) or own:
        shown.append(faults.engine_disk_line(*data_root()))
    return shown


def engine_data_root() -> DataRoot:
    """The engine's DockerRootDir, and the bytes free there when it is on this machine (an
    engine at a local socket whose data root exists here), else None; ('', None) when the
    engine does not say."""
    try:
        root = str(engine.client().info().get("DockerRootDir") or "")
    except (DockerException, engine.EngineError):
        return "", None
    local = engine.cli_host(os.environ).startswith("unix://") and os.path.isdir(root)
    try:
        return root, shutil.disk_usage(root).free if local else None
    except OSError:
        return root, None


def with_lines(message: str, shown: Sequence[str]) -> str:
    """message, then each of shown on a line of its own, indented."""
    return message + "".join(f"\n  {line}" for line in shown)


# What a task is doing with the engine, as its lost-engine message says it.
TASK_WORDS = {"push": "the push", "slim": "the slim run", "test": "the test run",
              "dev-shell": "the dev shell", "ci": "the CI job", "manifest": "the manifest lists"}
LOST = "the connection to the Docker engine was lost"


def task_doing(name: str) -> str:
    """What the task `name` was doing, for engine_lost_line (`docker-ros NAME` when unnamed)."""
    return TASK_WORDS.get(name, f"`docker-ros {name}`")


def lost_during(doing: str, failure: str, *, answered: bool,
                answers: Callable[[], bool]) -> Optional[str]:
    """The message of a task's failure (its text) when the engine went away under it: the
    engine answered during the task (answered) and answers no longer (answers(), asked only
    then), so the failure is what its going away did (a container its shutdown stopped, a
    request cut short); its first line is the detail. None when the failure is the task's own,
    or says already that the engine was lost (a build's)."""
    if not answered or LOST in failure or answers():
        return None
    return engine_lost_line(doing, shorten_detail(failure.splitlines()[0] if failure else ""))


def engine_lost_line(doing: str, detail: str) -> str:
    """The message of an engine that went away while docker-ros was `doing` something (a
    push, a slim run, a command in a container, a dev shell), as a lost build says it."""
    return (f"{LOST} during {doing} ({detail}); an image "
            "is tagged or pushed only once it is complete, so rerunning is safe once "
            "`docker info` answers")


def request_detail(exc: BaseException) -> str:
    """What the Engine API's transport (requests) said when the engine went away: the
    innermost reason, e.g. `Connection refused` or `Response ended prematurely`."""
    text = str(exc)
    found = re.findall(r"\w*Error\(\d+, '([^']+)'\)|ProtocolError\('([^']+)'", text)
    reasons = [a or b for a, b in found]
    if not reasons and exc.args and isinstance(exc.args[0], str):  # (urllib3's own)
        reasons = [exc.args[0]]
    return shorten_detail(reasons[-1] if reasons else text or type(exc).__name__)


def shorten_detail(text: str) -> str:
    return text if len(text) <= 160 else text[:157] + "..."


def engine_answers() -> bool:
    """Whether the engine answers now (a fresh client: the cached one pinged once, earlier)."""
    engine.client.cache_clear()
    try:
        engine.client()
    except engine.EngineError:
        return False
    return True


# The Engine API's transport failing: the SDK raises requests' errors (no DockerException) when
# the engine stops mid-request or no longer listens, and urllib3's own when it stops in the
# middle of a stream the SDK reads raw (a push's progress: measured, engine stopped mid-push).
TRANSPORT_ERRORS = (RequestException, TransportError)


def lost_engine(exc: BaseException) -> bool:
    """Whether exc is the Engine API's transport failing (TRANSPORT_ERRORS)."""
    return isinstance(exc, TRANSPORT_ERRORS)
