"""The errors docker-ros expects: one base class, which the command line catches once and
reports as one line (`docker-ros <task>: <message>`) with its exit code."""

from __future__ import annotations


class DockerRosError(Exception):
    """An expected failure the user can fix: its message says what and what to do."""

    exit_code = 1


class BuildError(DockerRosError):
    """A build failed: which target, which step, why."""

    def __init__(self, message: str, returncode: int = 1, *, stage: str = "",
                 step: str = "") -> None:
        super().__init__(message)
        self.returncode = returncode  # buildx's (the task's exit code stays 1)
        self.stage = stage  # the Dockerfile stage and docker-ros step that failed, when known
        self.step = step
