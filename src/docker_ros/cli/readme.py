"""Regenerate the README configuration table from the settings declarations."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Dict, List, Sequence

from docker_ros.cli.tasks import ns
from docker_ros.in_image.settings import FIELDS, markdown_table
from docker_ros.in_image.steps import STEPS

BEGIN, END = "<!-- settings-table:begin -->", "<!-- settings-table:end -->"


def flag_tasks() -> Dict[str, List[str]]:
    """Setting name -> the tasks that have it as a flag."""
    out: Dict[str, List[str]] = {}
    for name in sorted(ns.task_names):
        for flag in ns[name].help:
            if flag in FIELDS:
                out.setdefault(flag, []).append(name)
    return out


def tasks_phrase(tasks: Sequence[str], every: Sequence[str], steps: Sequence[str]) -> str:
    """The tasks that have a flag, in the fewest names: listed, "the step tasks" and the
    others, or "every task but" those without it (names listed on a tie)."""
    others = [t for t in tasks if t not in steps]
    missing = [t for t in every if t not in tasks]
    if not missing:
        return "every task"
    phrases = [(len(tasks), ", ".join(tasks)),
               (1 + len(missing), "every task but " + ", ".join(missing))]
    if set(steps) <= set(tasks):
        phrases.append((1 + len(others), ", ".join(["the step tasks", *others])))
    return min(phrases, key=lambda phrase: phrase[0])[1]


def table() -> str:
    every = sorted(ns.task_names)
    return markdown_table({name: tasks_phrase(tasks, every, STEPS)
                           for name, tasks in flag_tasks().items()})


def with_table(text: str) -> str:
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{table()}\n{END}{tail}"


if __name__ == "__main__":
    path = Path(sys.argv[1] if len(sys.argv) > 1 else "README.md")
    path.write_text(with_table(path.read_text()))
