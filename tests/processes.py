"""The processes of this machine, for tests that check what an interrupted task leaves running."""

import subprocess
import time
from pathlib import Path


def running(text: str) -> list:
    """The command lines of the live processes (not zombies) that name text."""
    found = []
    for folder in Path("/proc").glob("[0-9]*"):
        try:
            state = (folder / "stat").read_text().rsplit(")", 1)[1].split()[0]
            argv = (folder / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, IndexError):
            continue  # ended meanwhile
        if text in argv and state != "Z":
            found.append(argv.strip())
    return found


def left_after(text: str, seconds: float = 10) -> list:
    """`running(text)` once none is left, or after seconds: what outlived its end."""
    deadline = time.monotonic() + seconds
    while running(text) and time.monotonic() < deadline:
        time.sleep(0.1)
    return running(text)


def stop(process: subprocess.Popen, *, timeout: float) -> None:
    """Terminate a server the tests started; kill it if it does not end in time."""
    process.terminate()
    try:
        process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
