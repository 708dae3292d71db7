"""Regenerate the README configuration table from the settings declarations."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Dict, List

from docker_ros.cli.tasks import ns
from docker_ros.in_image.settings import FIELDS, markdown_table

BEGIN, END = "<!-- settings-table:begin -->", "<!-- settings-table:end -->"


def flag_tasks() -> Dict[str, List[str]]:
    """Setting name -> the tasks that have it as a flag."""
    out: Dict[str, List[str]] = {}
    for name in sorted(ns.task_names):
        for flag in ns[name].help:
            if flag in FIELDS:
                out.setdefault(flag, []).append(name)
    return out


def table() -> str:
    return markdown_table(flag_tasks())


def with_table(text: str) -> str:
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{table()}\n{END}{tail}"


if __name__ == "__main__":
    path = Path(sys.argv[1] if len(sys.argv) > 1 else "README.md")
    path.write_text(with_table(path.read_text()))
