"""A CI job's record and its GitHub job summary.

A CI job runs each task in a process of its own (pipeline.run_ci_plan): the tasks append what
they made and pushed to the job's record (a JSON-lines file named by RECORD_ENV), and the job
renders it as a markdown table into `$GITHUB_STEP_SUMMARY`. Image names, figures and digests
only: nothing of the settings, so never a secret."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Dict, Iterator, List, Mapping, MutableMapping, Sequence

RECORD_ENV = "DOCKER_ROS_JOB_RECORD"


def record(entry: Mapping[str, Any], environ: Mapping[str, str]) -> None:
    """Append entry to the job's record, when the task runs in a job that keeps one."""
    path = environ.get(RECORD_ENV)
    if path:
        with open(path, "a", encoding="utf-8") as out:
            out.write(json.dumps(dict(entry), sort_keys=True) + "\n")


def read_record(path: Path) -> List[Dict[str, Any]]:
    """The record's entries (a line that does not read is skipped)."""
    entries = []
    for line in path.read_text(encoding="utf-8").splitlines() if path.is_file() else []:
        with contextlib.suppress(ValueError):
            entries.append(json.loads(line))
    return [e for e in entries if isinstance(e, dict)]


def pushed_digests(entries: Sequence[Mapping[str, Any]]) -> Dict[str, str]:
    """Each name the job's tasks pushed -> its registry digest ('' unknown), from the record."""
    return {str(e.get("name", "")): str(e.get("digest") or "")
            for e in entries if e.get("kind") == "pushed" and e.get("name")}


def megabytes(size: int) -> str:
    return f"{size / 1e6:.0f} MB" if size else "-"


def image_row(entry: Mapping[str, Any]) -> List[str]:
    """One built or slimmed image: name, platform, size, build time, cached steps, slim ratio."""
    cached, steps = (list(entry.get("cached") or []) + [0, 0])[:2]
    seconds = f"{float(entry.get('seconds', 0)):.1f} s"
    if entry.get("target") == "slim":
        seconds += " (up to date)" if entry.get("reused") else " (traced, checked)"
    size, run_size = int(entry.get("size") or 0), int(entry.get("run_size") or 0)
    ratio = f"{run_size / size:.1f}x" if entry.get("target") == "slim" and size and run_size \
        else ""
    return [f"`{entry.get('ref', '')}`", str(entry.get("platform", "")), megabytes(size),
            seconds, f"{cached}/{steps}" if steps else "", ratio]


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> List[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header),
            *("| " + " | ".join(row) + " |" for row in rows)]


def render_summary(entries: Sequence[Mapping[str, Any]], title: str = "docker-ros") -> str:
    """The job summary (markdown): a table of the images made (build time: the buildx run's,
    one for the images one bake run made together; cached steps: of that run), and one of the
    pushed names with their digests. '' when the record holds neither."""
    images = [e for e in entries if e.get("kind") == "image"]
    pushed = [e for e in entries if e.get("kind") == "pushed"]
    if not images and not pushed:
        return ""
    lines = [f"### {title}", ""]
    if images:
        lines += table(("image", "platform", "size", "build time", "cached steps",
                        "slim ratio"), [image_row(e) for e in images]) + [""]
    if pushed:
        lines += table(("pushed", "digest"), [
            (f"`{e.get('name', '')}`", f"`{e['digest']}`" if e.get("digest") else "-")
            for e in pushed]) + [""]
    return "\n".join(lines)


def write_summary(text: str, environ: Mapping[str, str]) -> None:
    """Append text to GitHub's job summary (`$GITHUB_STEP_SUMMARY`), when there is one."""
    path = environ.get("GITHUB_STEP_SUMMARY")
    if path and text:
        with open(path, "a", encoding="utf-8") as out:
            out.write(text + "\n")


@contextlib.contextmanager
def job_record(environ: MutableMapping[str, str] = os.environ) -> Iterator[Path]:
    """A record for this job's tasks (RECORD_ENV in environ, which the task processes inherit);
    at the end, also after a failure, its summary goes to GitHub's job summary. A record that
    environ already names (a job inside a job) is kept and left to its owner."""
    if environ.get(RECORD_ENV):
        yield Path(environ[RECORD_ENV])
        return
    with tempfile.TemporaryDirectory(prefix="docker-ros-job-") as tmp:
        path = Path(tmp) / "record.jsonl"
        environ[RECORD_ENV] = str(path)
        try:
            yield path
        finally:
            del environ[RECORD_ENV]
            write_summary(render_summary(read_record(path)), environ)
