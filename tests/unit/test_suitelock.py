"""One run with docker tests at a time (tests/suitelock.py): a real lock held by another
process."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
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


def test_the_workers_of_the_run_that_holds_the_lock_go_on_and_no_other_process_does(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    lock = tmp_path / "run.lock"
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(lock), "30"],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        monkeypatch.setenv(suitelock.HOLDER, str(holder.pid))
        assert suitelock.held_by_this_run(lock)
        monkeypatch.setenv(suitelock.HOLDER, str(os.getpid()))  # alive, but not the holder
        assert not suitelock.held_by_this_run(lock)
        monkeypatch.setenv(suitelock.HOLDER, str(holder.pid))
    finally:
        holder.kill()
        holder.wait()
        assert holder.stdout is not None
        holder.stdout.close()
    assert not suitelock.held_by_this_run(lock)  # the holder ended


def test_a_step_made_once_per_run_waits_for_the_one_making_it(tmp_path: Path) -> None:
    order: list = []
    inside = threading.Event()

    def first() -> None:
        with suitelock.once("step", tmp_path):
            order.append("first in")
            inside.set()
            time.sleep(0.3)
            order.append("first out")

    thread = threading.Thread(target=first)
    thread.start()
    assert inside.wait(10)
    with suitelock.once("step", tmp_path):
        order.append("second in")
    thread.join()
    assert order == ["first in", "first out", "second in"]
