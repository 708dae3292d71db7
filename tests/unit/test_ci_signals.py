"""A CI job's tasks after Ctrl-C or SIGTERM: each task process cleans up and ends (real
processes and signals)."""

import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from docker_ros.cli import settingstask
from docker_ros.host.pipeline import let_end

# A task stand-in: on SIGTERM it "cleans up" (writes the file) and exits 143, as tasks do.
TASK = textwrap.dedent("""
    import signal, sys, time
    def cleanup(signum, frame):
        open(sys.argv[1], "w").write("cleaned")
        sys.exit(143)
    signal.signal(signal.SIGTERM, cleanup)
    print("ready", flush=True)
    time.sleep(60)
""")


def started(tmp_path: Path) -> subprocess.Popen:
    task = subprocess.Popen([sys.executable, "-c", TASK, str(tmp_path / "cleaned")],
                            stdout=subprocess.PIPE, text=True)
    assert task.stdout is not None and task.stdout.readline() == "ready\n"
    return task


def test_a_task_the_signal_did_not_reach_is_terminated_and_cleans_up(tmp_path: Path) -> None:
    """SIGTERM to `docker-ros ci` alone: its running task gets SIGTERM after the grace time
    (subprocess.call killed it: no clean-up)."""
    with started(tmp_path) as task:
        began = time.monotonic()
        let_end(task, grace=0.3)
        assert task.returncode == 143
        assert (tmp_path / "cleaned").read_text() == "cleaned"
        assert time.monotonic() - began < 10


def test_a_task_that_got_the_signal_too_is_left_to_end(tmp_path: Path) -> None:
    with started(tmp_path) as task:
        task.send_signal(signal.SIGTERM)  # (a runner signals every process of the job)
        let_end(task, grace=30)
        assert task.returncode == 143 and (tmp_path / "cleaned").exists()


def test_a_second_sigterm_does_not_cut_the_clean_up_short() -> None:
    previous = signal.getsignal(signal.SIGTERM)
    try:
        signal.signal(signal.SIGTERM, settingstask.terminated)
        with pytest.raises(settingstask.Terminated):
            settingstask.terminated(signal.SIGTERM, None)
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGTERM, previous)
