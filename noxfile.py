"""The project's own checks: `nox` runs lint, typecheck and tests (see README)."""

from __future__ import annotations

from pathlib import Path
from typing import List

import nox

nox.options.sessions = ["lint", "typecheck", "tests"]
nox.options.reuse_existing_virtualenvs = True

ROOT = Path(__file__).parent
LINT_PATHS = ("src", "tests", "tasks.py", "noxfile.py", "scripts")
TYPECHECK_PATHS = ("src", "tasks.py", "noxfile.py", "scripts")


def python_paths(candidates: tuple) -> List[str]:
    """The candidates that exist and hold Python code (ruff and mypy fail on the others)."""
    found = []
    for name in candidates:
        path = ROOT / name
        if path.suffix == ".py" and path.is_file() or path.is_dir() and any(path.rglob("*.py")):
            found.append(name)
    return found


@nox.session
def lint(session: nox.Session) -> None:
    """ruff over the code and the tests."""
    session.install("ruff>=0.5")
    session.run("ruff", "check", *python_paths(LINT_PATHS))


@nox.session
def typecheck(session: nox.Session) -> None:
    """mypy with the settings in pyproject.toml."""
    session.install("-e", ".[test]")
    session.run("mypy", *python_paths(TYPECHECK_PATHS))


@nox.session
def tests(session: nox.Session) -> None:
    """pytest; arguments after `--` go to pytest (e.g. `nox -s tests -- -m "not docker"`)."""
    session.install("-e", ".[test]")
    session.run("pytest", *session.posargs)


@nox.session
def bench(session: nox.Session) -> None:
    """Build times and image sizes (scripts/bench.py); only on request: `nox -s bench -- ARGS`.

    Not a test and not a default session. Arguments after `--` go to the script, e.g.
    `nox -s bench -- -n 5 --json bench.json`. It prunes nothing (the engine may be shared) and
    removes only its own images.
    """
    session.install("-e", ".")
    session.run("python", "scripts/bench.py", *session.posargs)
