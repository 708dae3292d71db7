"""The run's slow prerequisites, made in the background while the first tests run (issue 44):
the base images (the arm64 one under QEMU takes 5 to 10 minutes on an empty engine) and the
BuildKit image of the container builders (3 to 10 minutes). They were made when the first test
that needed one asked for it, each time with the whole run waiting; now one thread makes them,
in the order the tests need them, while the unit and host tests (one core) and the docker tests
that need none of them run, and each fixture waits for its own only.

The thread holds the suite lock first (suitelock.hold): nothing is built while another run
works on the machine. A job that fails fails the tests that need it, with its own error."""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable, Dict, Iterable, Optional, Tuple, TypeVar

T = TypeVar("T")


class Warmup:
    """Jobs run one after another in one background thread; `result` waits for a job, or runs
    it in the caller when it was not started (a run that did not predict its need, or a job
    still queued: the caller need not wait for the jobs before it)."""

    def __init__(self) -> None:
        self._pool: Optional[ThreadPoolExecutor] = None
        self._jobs: Dict[str, Future] = {}

    def start(self, jobs: Iterable[Tuple[str, Callable[[], object]]]) -> None:
        for name, job in jobs:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(1, thread_name_prefix="docker-ros-test-warmup")
            self._jobs[name] = self._pool.submit(job)

    def started(self) -> Tuple[str, ...]:
        return tuple(self._jobs)

    def result(self, name: str, job: Callable[[], T]) -> T:
        """The job's result; a job still queued behind others runs in the caller at once (its
        own lock, suitelock.once, keeps the two from making the same thing twice)."""
        future = self._jobs.get(name)
        if future is None or future.cancel():
            return job()
        return future.result()

    def stop(self) -> None:
        """Drop the jobs not begun; wait for the one running (a bootstrap half done would leave
        its temporary rootfs image)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
