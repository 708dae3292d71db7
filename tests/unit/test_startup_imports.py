"""`docker-ros --help`, `inv --list` and `inv build --help` import nothing they do not need:
the docker SDK (and requests, urllib3 under it), python-dotenv, jsonschema, the host modules
(build, pipeline, ...) and the reading of settings (core.loading, core.ci) come only with a task
that uses them. Asserted on which modules a fresh
interpreter holds after printing the help, never on a time. And the quick copies of tasks and
flags that invoke makes as it loads and parses (settingstask's __deepcopy__) are copies."""

import copy
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import List, Set

from invoke.parser import Parser

from docker_ros.cli.tasks import ns

SRC = Path(__file__).resolve().parents[2] / "src"

# Top-level packages that start-up must not import (each costs tens of ms or more).
DEFERRED = ("docker", "requests", "urllib3", "charset_normalizer", "idna", "certifi",
            "dotenv", "catkin_pkg", "jsonschema")
# Our modules that only a task's run needs (reading the settings, CI variables; the in-image
# entry points' start).
RUN_ONLY = ("docker_ros.core.loading", "docker_ros.core.ci", "docker_ros.in_image.runtime.entry")


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
    """The deferred packages, host modules and RUN_ONLY modules among loaded."""
    return sorted({name for name in loaded if name.split(".")[0] in DEFERRED
                   or name.startswith("docker_ros.host") or name in RUN_ONLY})


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


def inv_loaded(argv: List[str], tmp_path: Path) -> Set[str]:
    """The modules `inv <argv>` imports in a project whose tasks.py is docker-ros's line."""
    (tmp_path / "tasks.py").write_text("from docker_ros.tasks import ns  # noqa: F401\n")
    return loaded_after(f"""
        import sys
        from invoke.main import program
        sys.argv = ["inv", *{argv!r}]
        try:
            program.run()
        except SystemExit:
            pass
        """, tmp_path)


def test_inv_list_imports_no_heavy_module(tmp_path: Path) -> None:
    loaded = inv_loaded(["--list"], tmp_path)
    assert "docker_ros" in loaded
    assert heavy(loaded) == []


def test_inv_task_help_imports_no_heavy_module(tmp_path: Path) -> None:
    loaded = inv_loaded(["build", "--help"], tmp_path)
    assert "docker_ros.cli.tasks" in loaded
    assert heavy(loaded) == []


def test_a_parse_leaves_the_flags_as_they_were() -> None:
    """invoke's parser sets values on copies of the tasks' flags: a second parse starts from
    none, and the flags themselves keep their defaults (a flag shared with its copy would not)."""
    contexts = ns.to_contexts()
    first = Parser(contexts=contexts).parse_argv(["build", "--set", "A=1", "--target", "dev"])
    second = Parser(contexts=contexts).parse_argv(["build", "--set", "B=2"])
    assert (first[0].args["set"].value, first[0].args["target"].value) == (["A=1"], "dev")
    assert (second[0].args["set"].value, second[0].args["target"].value) == (["B=2"], None)
    build = next(context for context in contexts if context.name == "build")
    assert (build.args["set"].value, build.args["target"].value) == ([], None)


def test_a_copied_task_shares_only_its_signature() -> None:
    """`inv` copies each task as it loads tasks.py: the copy has its own help texts and lists
    and the same (immutable) signature, and makes the same flags."""
    task = ns.tasks["build"]
    made = copy.deepcopy(task)
    assert made.__signature__ is task.__signature__
    assert made.help == task.help and made.help is not task.help
    assert made.iterable == task.iterable and made.iterable is not task.iterable
    assert ([vars(arg) for arg in made.get_arguments()]
            == [vars(arg) for arg in task.get_arguments()])


def test_the_probe_sees_an_import() -> None:
    """The check itself works: a module imported is one reported."""
    assert "colorsys" in loaded_after("import colorsys", SRC)
