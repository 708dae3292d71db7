"""One test run with Docker at a time on a machine. The docker tests build under fixed names
(`docker-ros-test/...`, so that the next run's builds find their cache) and remove what their
run leaves at its end: two runs at once would build over each other's images and remove them
under each other. A second run waits for the first: an exclusive lock on a file in the
machine's temporary folder, which the kernel releases when its process ends, however it ends.

A run on several processes (`pytest -n`, pytest-xdist) is one run: its controller takes the
lock before it starts the workers and names itself in HOLDER, and the workers see that their
run holds it. What the workers must make once per run (a base image, the BuildKit image, the
wheel of this checkout) each makes under `once`: the second waits for the first, then finds it
made."""

from __future__ import annotations

import contextlib
import fcntl
import functools
import os
import tempfile
import threading
import time
from pathlib import Path
from typing import IO, Callable, Iterator, TypeVar

LOCK = Path(tempfile.gettempdir()) / "docker-ros-test-run.lock"
# (the environment variable naming the process of this run that holds LOCK: the xdist controller)
HOLDER = "DOCKER_ROS_TEST_LOCK_HOLDER"
T = TypeVar("T")
# (pip builds this checkout in its own folder: two processes of a run at once break each other)
SOURCE_TREE_BUILD = "source-tree-build"


class Busy(Exception):
    """Another run held the lock for longer than a run may wait."""


def acquire(handle: IO[str], seconds: float, say: Callable[[str], None],
            poll: float = 2.0) -> None:
    """Take the lock of the open file `handle`, waiting up to `seconds` for the run holding it
    (named once by `say`), and write this process's id into the file."""
    deadline = time.monotonic() + seconds
    said = False
    while True:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "?"
            if time.monotonic() >= deadline:
                raise Busy(f"another docker-ros test run (pid {holder}) still holds {LOCK} "
                           f"after {seconds:.0f} s: let it end, then run again") from None
            if not said:
                say(f"waiting for another docker-ros test run (pid {holder}) on this machine "
                    f"to end: they would build over each other's images ({LOCK})")
                said = True
            time.sleep(poll)
    handle.seek(0)
    handle.truncate()
    handle.write(str(os.getpid()))
    handle.flush()


_HELD: list = []  # this process's open, locked handle (kept until the process ends)
_GAVE_UP: list = []  # the Busy of this process's wait that ran out (asked again: at once)
_HOLDING = threading.Lock()


def hold(seconds: float, say: Callable[[str], None]) -> None:
    """Take the lock for this process unless it holds it already (the warm-up thread and the
    first docker test both ask: a second flock of the same file from this process, through
    another handle, would wait for itself). Busy as acquire; once this process's wait ran out,
    every later call raises that Busy at once (each warm-up job and the first docker test ask:
    they waited an hour each)."""
    with _HOLDING:
        if _HELD or held_by_this_run():
            return
        if _GAVE_UP:
            raise _GAVE_UP[0]
        handle = LOCK.open("a+")
        try:
            acquire(handle, seconds, say)
        except Busy as exc:
            handle.close()
            _GAVE_UP.append(exc)
            raise
        except BaseException:
            handle.close()
            raise
        _HELD.append(handle)


def held_by_this_run(lock: Path = LOCK) -> bool:
    """Whether HOLDER names a live process that holds lock (this process's xdist controller:
    its workers inherit its environment)."""
    holder = os.environ.get(HOLDER, "")
    if not holder.isdigit():
        return False
    try:
        os.kill(int(holder), 0)
        return lock.read_text().strip() == holder
    except OSError:
        return False


def hold_for_workers(seconds: float, say: Callable[[str], None]) -> None:
    """hold, in the process that then starts the run's workers: they inherit HOLDER."""
    hold(seconds, say)
    os.environ[HOLDER] = str(os.getpid())


@contextlib.contextmanager
def once(name: str, folder: Path = LOCK.parent) -> Iterator[None]:
    """An exclusive lock of this machine's, by name, for a step that processes of one run may
    ask for at once (the step then finds what the first made and does not make it again)."""
    with (folder / f"docker-ros-test-{name}.lock").open("a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def made_once(name: str) -> Callable[[Callable[[], T]], Callable[[], T]]:
    """A function that makes something once per run, run under once(name)."""
    def wrap(make: Callable[[], T]) -> Callable[[], T]:
        @functools.wraps(make)
        def run() -> T:
            with once(name):
                return make()
        return run
    return wrap
