"""The step code runs inside base images: standard library only, Python 3.8 syntax and API."""

import ast
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[2] / "src"
STEP_FILES = sorted((SRC / "docker_ros" / "steps").glob("*.py")) + sorted(
    (SRC / "docker_ros" / "runtime").glob("*.py"))
# testing.py runs in the image's test stage, slimtrace.py in the run image being slimmed,
# ci.py with settings.py
IN_IMAGE = [SRC / "docker_ros" / name
            for name in ("settings.py", "ci.py", "testing.py", "slimtrace.py")]
CHECKED = STEP_FILES + IN_IMAGE

IMPORT_ALL = """
import importlib, json, pkgutil, sys
import docker_ros.settings, docker_ros.slimtrace, docker_ros.steps, docker_ros.testing
import docker_ros.runtime
for package in (docker_ros.steps, docker_ros.runtime):
    for info in pkgutil.iter_modules(package.__path__):
        importlib.import_module(package.__name__ + "." + info.name)
print(json.dumps(sorted(sys.modules)))
"""


@pytest.mark.parametrize("path", CHECKED, ids=lambda p: p.name)
def test_parses_as_python_38(path):
    ast.parse(path.read_text(), filename=str(path), feature_version=(3, 8))


def test_imports_only_the_standard_library():
    # -I -S: no PYTHONPATH, no user site, no site-packages (nor their .pth hooks): only src.
    code = f"import sys; sys.path.insert(0, {str(SRC)!r})\n" + IMPORT_ALL
    out = subprocess.run(
        [sys.executable, "-I", "-S", "-c", code], capture_output=True, text=True, check=True
    ).stdout
    modules = json.loads(out)
    stdlib = set(sys.stdlib_module_names) | set(sys.builtin_module_names)
    foreign = sorted(
        m
        for m in modules
        if m.split(".")[0] not in stdlib and m.split(".")[0] != "docker_ros" and m != "__main__"
    )
    assert foreign == []
    assert "docker_ros.steps.clone" in modules and "docker_ros.steps.rosdep" in modules


def test_same_check_fails_for_a_third_party_import(tmp_path):
    """The check above is real: a module importing yaml is caught."""
    pkg = tmp_path / "docker_ros_probe"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("import yaml\n")
    site = Path(__import__("yaml").__file__).parents[1]
    code = (
        f"import sys; sys.path[:0] = [{str(tmp_path)!r}, {str(site)!r}]\n"
        "import json, docker_ros_probe; print(json.dumps(sorted(sys.modules)))"
    )
    modules = json.loads(
        subprocess.run(
            [sys.executable, "-I", "-S", "-c", code], capture_output=True, text=True, check=True
        ).stdout
    )
    stdlib = set(sys.stdlib_module_names) | set(sys.builtin_module_names)
    assert "yaml" in [m for m in modules if m.split(".")[0] not in stdlib]


def python38():
    """A real Python 3.8 (pyenv's or the system's), or None."""
    pyenv = Path.home() / ".pyenv" / "versions"
    candidates = (
        [str(p) for p in sorted(pyenv.glob("3.8*/bin/python3.8"))] if pyenv.is_dir() else []
    )
    candidates += [p for p in [shutil.which("python3.8")] if p]
    for candidate in candidates:
        proc = subprocess.run(
            [candidate, "-c", "import sys; print(sys.version_info[:2])"],
            capture_output=True,
            text=True,
        )
        if proc.returncode == 0 and proc.stdout.strip() == "(3, 8)":
            return candidate
    return None


@pytest.mark.skipif(python38() is None, reason="no Python 3.8 interpreter on this machine")
def test_runs_on_python_38(tmp_path):
    """Import every step module and run the step CLI (a dry run) under a real Python 3.8."""
    python = python38()
    code = f"import sys; sys.path.insert(0, {str(SRC)!r})\n" + IMPORT_ALL
    subprocess.run([python, "-I", "-S", "-c", code], check=True, capture_output=True)
    ws = tmp_path / "ws"
    (ws / "src" / "target" / "docker").mkdir(parents=True)
    (ws / "src" / "target" / "docker" / "additional-debs.txt").write_text("jq\n")
    proc = subprocess.run(
        [python, "-m", "docker_ros.steps", "debs", "--workspace", str(ws), "--dry-run"],
        env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    assert "apt-get install -y --no-install-recommends jq" in proc.stdout
    assert not (ws / ".docker-ros").exists()
