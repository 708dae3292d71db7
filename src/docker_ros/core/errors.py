"""The errors docker-ros reports as one line."""

from __future__ import annotations


class BuildError(Exception):
    """A build failed: which target, which step, why."""

    def __init__(self, message: str, returncode: int = 1, *, stage: str = "",
                 step: str = "") -> None:
        super().__init__(message)
        self.returncode = returncode
        self.stage = stage  # the Dockerfile stage and docker-ros step that failed, when known
        self.step = step
