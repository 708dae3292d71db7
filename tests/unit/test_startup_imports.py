"""`docker-ros --help` and `inv --list` import nothing they do not need: the docker SDK (and
requests, urllib3 under it), python-dotenv and the host modules (build, pipeline, ...) come
only with a task that uses them. Asserted on which modules a fresh interpreter holds after
printing the help, never on a time."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import List, Set

SRC = Path(__file__).resolve().parents[2] / "src"

# Top-level packages that start-up must not import (each costs tens of ms or more).
DEFERRED = ("docker", "requests", "urllib3", "charset_normalizer", "idna", "certifi",
            "dotenv", "catkin_pkg")


def loaded_after(script: str, cwd: Path) -> Set[str]:
    """The modules that script added to sys.modules in a fresh interpreter (not those the
    interpreter's start-up, site and its .pth files, had imported already)."""
    probe = "import sys\nBEFORE = set(sys.modules)\n" + textwrap.dedent(script) + (
        textwrap.dedent("""
        import json
        sys.stdout.flush()
        sys.__stderr__.write("\\nMODULES " + json.dumps(sorted(
            set(sys.modules) - BEFORE)) + "\\n")
        """))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(SRC), *filter(None, [os.environ.get("PYTHONPATH")])])}
    done = subprocess.run([sys.executable, "-c", probe], cwd=cwd, env=env, text=True,
                          capture_output=True, timeout=120, check=False)
    line = [each for each in done.stderr.splitlines() if each.startswith("MODULES ")]
    assert line, done.stderr
    return set(json.loads(line[-1][len("MODULES "):]))


def heavy(loaded: Set[str]) -> List[str]:
    """The deferred packages and host modules among loaded."""
    return sorted({name for name in loaded if name.split(".")[0] in DEFERRED
                   or name.startswith("docker_ros.host")})


def test_docker_ros_help_imports_no_heavy_module(tmp_path: Path) -> None:
    loaded = loaded_after("""
        from docker_ros.cli.program import main
        try:
            main(["--help"])
        except SystemExit:
            pass
        """, tmp_path)
    assert "docker_ros" in loaded and "invoke" in loaded
    assert heavy(loaded) == []


def test_inv_list_imports_no_heavy_module(tmp_path: Path) -> None:
    (tmp_path / "tasks.py").write_text("from docker_ros.tasks import ns  # noqa: F401\n")
    loaded = loaded_after("""
        import sys
        from invoke.main import program
        sys.argv = ["inv", "--list"]
        try:
            program.run()
        except SystemExit:
            pass
        """, tmp_path)
    assert "docker_ros" in loaded
    assert heavy(loaded) == []


def test_the_probe_sees_an_import() -> None:
    """The check itself works: a module imported is one reported."""
    assert "colorsys" in loaded_after("import colorsys", SRC)
