"""The project's own checks: `nox` runs lint, typecheck, docs and tests (see CONTRIBUTING.md)."""

from __future__ import annotations

from pathlib import Path
from typing import List

import nox

nox.options.sessions = ["checks", "tests"]
nox.options.reuse_existing_virtualenvs = True

ROOT = Path(__file__).parent
LINT_PATHS = ("src", "tests", "tasks.py", "noxfile.py", "scripts", "docs")
TYPECHECK_PATHS = ("src", "tasks.py", "noxfile.py", "scripts")


def python_paths(candidates: tuple) -> List[str]:
    """The candidates that exist and hold Python code (ruff and mypy fail on the others)."""
    found = []
    for name in candidates:
        path = ROOT / name
        if path.suffix == ".py" and path.is_file() or path.is_dir() and any(path.rglob("*.py")):
            found.append(name)
    return found


def run_lint(session: nox.Session) -> None:
    session.run("ruff", "check", *python_paths(LINT_PATHS))


def run_typecheck(session: nox.Session) -> None:
    session.run("mypy", *python_paths(TYPECHECK_PATHS))


def run_docs(session: nox.Session) -> None:
    session.run("sphinx-build", "-W", "--keep-going", "-n", "-E", "-b", "html",
                "docs", str(ROOT / "build" / "docs" / "html"))


@nox.session
def checks(session: nox.Session) -> None:
    """lint, typecheck and docs in one environment (one install): what `nox` runs before the
    tests."""
    session.install("-e", ".[test,docs]")
    run_lint(session)
    run_typecheck(session)
    run_docs(session)


@nox.session(default=False)
def lint(session: nox.Session) -> None:
    """ruff over the code and the tests."""
    session.install("ruff>=0.5")
    run_lint(session)


@nox.session(default=False)
def typecheck(session: nox.Session) -> None:
    """mypy with the settings in pyproject.toml."""
    session.install("-e", ".[test]")
    run_typecheck(session)


@nox.session(default=False)
def docs(session: nox.Session) -> None:
    """The documentation site (Sphinx + MyST), strict: a warning, a broken link, a missing page
    or an unknown reference fails. HTML in build/docs/html (`nox -s docs`)."""
    session.install("-e", ".[docs]")
    run_docs(session)


# The whole suite runs on three processes (pytest-xdist) on 2 cores: a docker test waits on the
# engine, a registry or apt as often as it computes (CONTRIBUTING.md has the figures). A
# module's tests stay in one process, in order; the longest modules start first
# (tests/conftest.py, module_rank).
WORKERS = ("-n", "3", "--dist", "loadfile", "--no-loadscope-reorder")


@nox.session
def tests(session: nox.Session) -> None:
    """The whole suite, every tier, on three processes; arguments after `--` go to pytest."""
    session.install("-e", ".[test]")
    session.run("pytest", *WORKERS, *session.posargs)


# One tier at a time, for a quick loop while developing (`nox -s docker -- -k slim`); `nox`
# (and so `.ci/run`) runs them all through `tests`.
TIERS = {"unit": "not docker and not host", "host": "host", "docker": "docker"}


def tier_session(name: str, expression: str) -> None:
    def run(session: nox.Session) -> None:
        session.install("-e", ".[test]")
        session.run("pytest", "-m", expression, *session.posargs)

    run.__doc__ = f"Only the {name} tests (-m '{expression}'); arguments after `--` go to pytest."
    nox.session(name=name)(run)


for _name, _expression in TIERS.items():
    tier_session(_name, _expression)


@nox.session
def bench(session: nox.Session) -> None:
    """Build times and image sizes (scripts/bench.py); only on request: `nox -s bench -- ARGS`.

    Not a test and not a default session. Arguments after `--` go to the script, e.g.
    `nox -s bench -- -n 5 --json bench.json`. It prunes nothing (the engine may be shared) and
    removes only its own images.
    """
    session.install("-e", ".")
    session.run("python", "scripts/bench.py", *session.posargs)
