"""One run with docker tests at a time (tests/suitelock.py): a real lock held by another
process."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests import suitelock

HOLD = """import fcntl, os, sys, time
handle = open(sys.argv[1], "a+")
fcntl.flock(handle, fcntl.LOCK_EX)
handle.write(str(os.getpid()))
handle.flush()
print("held", flush=True)
time.sleep(float(sys.argv[2]))
"""


def test_a_second_run_names_the_first_waits_for_it_and_gives_up_after_its_time(
        tmp_path: Path) -> None:
    lock = tmp_path / "run.lock"
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(lock), "3"],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        said: list = []
        with lock.open("a+") as handle:
            with pytest.raises(suitelock.Busy, match=f"pid {holder.pid}.*let it end"):
                suitelock.acquire(handle, 0.5, said.append, poll=0.1)
            assert len(said) == 1 and f"pid {holder.pid}" in said[0], said
            # the holder ends after 3 s, and its lock with it
            suitelock.acquire(handle, 30, said.append, poll=0.1)
            assert holder.wait(timeout=10) == 0  # (its lock went as it exited)
            assert lock.read_text() == str(os.getpid())
    finally:
        holder.kill()
        holder.wait()
        assert holder.stdout is not None
        holder.stdout.close()


def test_a_free_lock_is_taken_at_once_without_a_word(tmp_path: Path) -> None:
    lock = tmp_path / "run.lock"
    lock.write_text("12345")  # a run that ended: its id stays, its lock went with it
    said: list = []
    with lock.open("a+") as handle:
        suitelock.acquire(handle, 0, said.append)
    assert said == [] and lock.read_text() == str(os.getpid())
