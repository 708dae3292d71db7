"""Regenerate the README configuration table from the settings declarations."""

from __future__ import annotations

import sys
from pathlib import Path

from docker_ros.settings import markdown_table

BEGIN, END = "<!-- settings-table:begin -->", "<!-- settings-table:end -->"


def with_table(text: str) -> str:
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{markdown_table()}\n{END}{tail}"


if __name__ == "__main__":
    path = Path(sys.argv[1] if len(sys.argv) > 1 else "README.md")
    path.write_text(with_table(path.read_text()))
