"""The step code runs inside base images: standard library only, Python 3.8 syntax and API."""

import ast
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[2] / "src"
# Everything under in_image/ runs in images (the steps, their runtime, the test runner, the
# slim tracer), and so does core/ (settings, CI detection, errors), which they import: the
# folders are the rule, no list of names.
IN_IMAGE = SRC / "docker_ros" / "in_image"
CORE = SRC / "docker_ros" / "core"
CHECKED = sorted([*IN_IMAGE.rglob("*.py"), *CORE.rglob("*.py")])

IMPORT_ALL = """
import importlib, json, pkgutil, sys
import docker_ros.core, docker_ros.in_image
for package in (docker_ros.core, docker_ros.in_image):
    for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
        importlib.import_module(info.name)
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
    # and of this package only in_image and core (and the version in docker_ros/__init__.py)
    ours = [m for m in modules if m.split(".")[0] == "docker_ros"]
    assert [m for m in ours if m != "docker_ros"
            and not m.startswith(("docker_ros.in_image", "docker_ros.core"))] == []
    assert {"docker_ros.in_image.steps.clone", "docker_ros.in_image.slimtrace",
            "docker_ros.core.display"} <= set(ours)


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


def vermin(paths):
    """vermin (PyPI), which knows in which Python version each stdlib module, function and
    argument appeared (the parse above knows only syntax), checking paths against 3.8."""
    argv = [sys.executable, "-c", "import sys, vermin; sys.exit(vermin.main())", "--no-tips",
            "--violations", "--target=3.8-", *map(str, paths)]
    return subprocess.run(argv, capture_output=True, text=True)


def test_uses_no_stdlib_api_newer_than_38():
    """Where a newer API is used behind a check (hasattr), the line says `# novermin`."""
    checked = vermin(CHECKED)
    assert checked.returncode == 0, checked.stdout + checked.stderr


def test_same_check_fails_for_a_39_api(tmp_path):
    newer = tmp_path / "newer.py"
    newer.write_text("import functools\n\n@functools.cache\ndef f():\n    return 1\n")
    checked = vermin([newer])
    assert checked.returncode != 0 and "'functools.cache' member requires !2, 3.9" in checked.stdout


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


def test_runs_on_python_38(tmp_path):
    """Import every step module and run the step CLI (a dry run) under a real Python 3.8: pyenv's
    3.8, which this project's kind of machine has (a developer's, CI's), or python3.8 on PATH.
    A missing one is a failure, in CI or not: vermin (above) checks API versions by name, not
    what 3.8 really runs."""
    python = python38()
    if python is None:
        pytest.fail("no Python 3.8 interpreter (pyenv's 3.8, or python3.8 on PATH): install "
                    "one, e.g. `pyenv install 3.8`")
    code = f"import sys; sys.path.insert(0, {str(SRC)!r})\n" + IMPORT_ALL
    subprocess.run([python, "-I", "-S", "-c", code], check=True, capture_output=True)
    ws = tmp_path / "ws"
    (ws / "src" / "target" / "docker").mkdir(parents=True)
    (ws / "src" / "target" / "docker" / "additional-debs.txt").write_text("jq\n")
    proc = subprocess.run(
        [python, "-m", "docker_ros.in_image.steps", "debs", "--workspace", str(ws), "--dry-run"],
        env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    assert "apt-get install -y --no-install-recommends jq" in proc.stdout
    assert not (ws / ".docker-ros").exists()


# Every module under in_image/ that runs as a program, found by its `__main__` guard (a
# package's __main__.py runs as the package). slimtrace is the one exception: it runs as a file
# of its own in the run image (slimelf beside it), where no docker_ros package is (its docstring).
ENTRY_POINTS = sorted(
    ".".join(path.relative_to(SRC).with_suffix("").parts).removesuffix(".__main__")
    for path in CHECKED
    if (path.name == "__main__.py" or 'if __name__ == "__main__":' in path.read_text())
    and path.name != "slimtrace.py"
)


def test_the_in_image_entry_points_are_found():
    assert {"docker_ros.in_image.steps", "docker_ros.in_image.testing",
            "docker_ros.in_image.runtime.lock"} <= set(ENTRY_POINTS)


@pytest.mark.parametrize("module", ENTRY_POINTS)
def test_every_in_image_entry_point_parses_its_arguments_with_one_parser(module, tmp_path):
    """Each answers --help with the shared parser's usage (its name, --workspace, -v) and a
    wrong call with exit code 2 and that usage, standard library only."""
    code = f"import sys, runpy; sys.path.insert(0, {str(SRC)!r}); " \
           f"runpy.run_module({module!r}, run_name='__main__', alter_sys=True)"
    shown = subprocess.run([sys.executable, "-I", "-S", "-c", code, "--help"],
                           capture_output=True, text=True, cwd=tmp_path)
    assert shown.returncode == 0, shown.stderr
    usage = shown.stdout.split("\n\n")[0]
    assert usage.startswith(f"usage: python3 -m {module}"), usage
    assert "--workspace WORKSPACE" in usage and "[-v]" in usage, usage
    wrong = subprocess.run([sys.executable, "-I", "-S", "-c", code, "--no-such-option"],
                           capture_output=True, text=True, cwd=tmp_path)
    assert wrong.returncode == 2 and f"usage: python3 -m {module}" in wrong.stderr


def test_apt_reason_names_the_packages_apt_does_not_know() -> None:
    from docker_ros.in_image.runtime.apt import apt_reason
    assert apt_reason(["Reading package lists...", "E: Unable to locate package no-such",
                       "E: Package 'gone' has no installation candidate",
                       "E: Version '9' for 'jq' was not found"]) == (
        "; apt has no package no-such, gone, jq=9 (check the name, or the version: "
        "`apt-cache policy jq` lists those apt has, and the apt sources of the base image)")
    assert apt_reason(["E: Could not get lock /var/lib/dpkg/lock"]) == (
        "; apt: Could not get lock /var/lib/dpkg/lock")
    assert apt_reason(["done"]) == ""


def test_apt_reason_names_the_sources_apt_get_update_could_not_reach() -> None:
    """An unreachable mirror: `apt-get update` only warns and exits 0, and install then says
    the package does not exist; the message names the unreachable source instead of only
    blaming the package's name. A failed download is named, not apt's advice to update."""
    from docker_ros.in_image.runtime.apt import apt_reason
    update = ["Err:1 http://127.0.0.1:9/debian bookworm InRelease",
              "  Could not connect to 127.0.0.1:9 (127.0.0.1). - connect (111: Connection "
              "refused)",
              "W: Failed to fetch http://127.0.0.1:9/debian/dists/bookworm/InRelease  Could not "
              "connect to 127.0.0.1:9 (127.0.0.1). - connect (111: Connection refused)",
              "W: Some index files failed to download. They have been ignored, or old ones used "
              "instead."]
    assert apt_reason(["E: Unable to locate package corp-tool"], update) == (
        "; apt has no package corp-tool, and `apt-get update` could not reach "
        "http://127.0.0.1:9/debian/dists/bookworm/InRelease (Could not connect to 127.0.0.1:9 "
        "(127.0.0.1). - connect (111: Connection refused)): check that apt source and the "
        "network (BUILD_NETWORK, a proxy), or the package's name")
    download = ["E: Failed to fetch http://deb.debian.org/debian/pool/main/j/jq/jq_1.6.deb  "
                "Temporary failure resolving 'deb.debian.org'",
                "E: Unable to fetch some archives, maybe run apt-get update or try with "
                "--fix-missing?"]
    assert apt_reason(download) == (
        "; apt: Failed to fetch http://deb.debian.org/debian/pool/main/j/jq/jq_1.6.deb  "
        "Temporary failure resolving 'deb.debian.org'")


def test_apt_reason_says_the_lists_could_not_be_downloaded() -> None:
    """Without network apt-get update only warns, and install then finds no package: the
    reason is the download, not the package name (real lines of an engine without NAT)."""
    from docker_ros.in_image.runtime.apt import apt_reason
    lines = ["Err:1 http://deb.debian.org/debian trixie InRelease",
             "  Temporary failure resolving 'deb.debian.org'",
             "W: Failed to fetch http://deb.debian.org/debian/dists/trixie/InRelease  "
             "Temporary failure resolving 'deb.debian.org'",
             "W: Some index files failed to download. They have been ignored, or old ones used "
             "instead.", "E: Unable to locate package libyaml-cpp-dev"]
    assert apt_reason(lines[-1:], lines[:-1]) == (
        "; apt has no package libyaml-cpp-dev, and `apt-get update` could not reach "
        "http://deb.debian.org/debian/dists/trixie/InRelease (Temporary failure resolving "
        "'deb.debian.org'): check that apt source and the network (BUILD_NETWORK, a proxy), or "
        "the package's name")


def test_an_apt_package_of_a_rosdep_key_apt_does_not_have_names_the_key() -> None:
    """A rosdep rule resolving to a package the base's apt sources lack named only the apt
    package: the key and the package.xml files needing it are named too."""
    from docker_ros.in_image.runtime.apt import apt_reason
    from docker_ros.in_image.steps.rosdep import apt_origins

    origins = apt_origins({"my_sdk": ["driver", "viewer"], "yaml-cpp": ["driver"]},
                          {"my_sdk": {"apt": ["libmy-sdk-dev"]},
                           "yaml-cpp": {"apt": ["libyaml-cpp-dev"]}})
    assert origins == {"libmy-sdk-dev": "rosdep key my_sdk of driver, viewer",
                       "libyaml-cpp-dev": "rosdep key yaml-cpp of driver"}
    lines = ["E: Unable to locate package libmy-sdk-dev",
             "E: Version '1.2' for 'libyaml-cpp-dev' was not found"]
    assert apt_reason(lines, (), origins) == (
        "; apt has no package libmy-sdk-dev (rosdep key my_sdk of driver, viewer), "
        "libyaml-cpp-dev=1.2 (rosdep key yaml-cpp of driver) (check the rosdep rule, or the "
        "version: `apt-cache policy libyaml-cpp-dev` lists those apt has, and the apt sources of "
        "the base image)")
