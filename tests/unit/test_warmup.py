"""The suite's warm-up (tests/warmup.py): a lane's jobs run in order in one background thread,
lanes side by side, a fixture waits for its own job, one not started (or still queued) runs in
the caller, a failure reaches the caller."""

from __future__ import annotations

import threading
import time
from typing import List

import pytest

from tests.warmup import Warmup


def test_jobs_run_in_order_in_one_background_thread_and_each_result_waits_for_its_own():
    ran: List[str] = []
    threads = set()
    release = threading.Event()

    def job(name: str, wait: bool = False):
        def run() -> str:
            if wait:
                release.wait(10)
            threads.add(threading.current_thread().name)
            ran.append(name)
            return name.upper()
        return run

    warmup = Warmup()
    warmup.start([("first", job("first", wait=True)), ("second", job("second")),
                  ("third", job("third"))])
    assert warmup.started() == ("first", "second", "third")
    time.sleep(0.1)
    assert ran == []  # the first waits, the others are behind it
    # a job still queued runs in the caller at once, and not again in the background
    assert warmup.result("second", job("second in the caller")) == "SECOND IN THE CALLER"
    assert ran == ["second in the caller"]
    release.set()
    assert warmup.result("first", job("never")) == "FIRST"
    assert warmup.result("third", job("never")) == "THIRD"
    assert ran == ["second in the caller", "first", "third"]
    assert len(threads) == 2 and threading.current_thread().name in threads
    assert warmup.result("other", lambda: "in the caller") == "in the caller"
    warmup.stop()


def test_a_lane_of_its_own_runs_beside_the_others():
    release = threading.Event()
    warmup = Warmup()
    warmup.start([("ros1", lambda: release.wait(10) and "ros1")])
    warmup.start([("arm64", lambda: threading.current_thread().name)], lane="arm64")
    # the arm64 job ends while the other lane's first job still waits
    assert warmup.result("arm64", lambda: "not run").startswith("docker-ros-test-warmup-arm64")
    assert not release.is_set()
    release.set()
    assert warmup.result("ros1", lambda: "not run") == "ros1"
    warmup.stop()


def test_a_failed_job_fails_the_fixture_that_waits_for_it():
    def broken() -> str:
        raise RuntimeError("no Engine 26 answers")

    warmup = Warmup()
    warmup.start([("buildkit_image", broken)])
    with pytest.raises(RuntimeError, match="no Engine 26 answers"):
        warmup.result("buildkit_image", lambda: "not run")
    warmup.stop()
