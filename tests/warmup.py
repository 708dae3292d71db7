"""The run's slow prerequisites, made in the background while the first tests run (issue 44):
the base images (the arm64 one under QEMU takes 5 to 10 minutes on an empty engine) and the
BuildKit image of the container builders (3 to 10 minutes). They were made when the first test
that needed one asked for it, each time with the whole run waiting; now background threads make
them, each lane's jobs in the order the tests need them, while the unit and host tests (one
core) and the docker tests that need none of them run, and each fixture waits for its own only.
A lane is one thread: the arm64 base's emulated bootstrap, the longest wait of an empty
engine's run, has a lane of its own and starts at once.

The thread holds the suite lock first (suitelock.hold): nothing is built while another run
works on the machine. A job that fails fails the tests that need it, with its own error."""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable, Dict, Iterable, Tuple, TypeVar

T = TypeVar("T")


class Warmup:
    """The jobs of a lane run one after another in a background thread of their own; `result`
    waits for a job, or runs it in the caller when it was not started (a run that did not
    predict its need, or a job still queued: the caller need not wait for the jobs before
    it)."""

    def __init__(self) -> None:
        self._pools: Dict[str, ThreadPoolExecutor] = {}
        self._jobs: Dict[str, Future] = {}

    def start(self, jobs: Iterable[Tuple[str, Callable[[], object]]], lane: str = "") -> None:
        for name, job in jobs:
            if lane not in self._pools:
                self._pools[lane] = ThreadPoolExecutor(
                    1, thread_name_prefix=f"docker-ros-test-warmup{lane and '-' + lane}")
            self._jobs[name] = self._pools[lane].submit(job)

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
        """Drop the jobs not begun; wait for the one running in each lane (a bootstrap half
        done would leave its temporary rootfs image)."""
        for pool in self._pools.values():
            pool.shutdown(wait=True, cancel_futures=True)
        self._pools = {}
