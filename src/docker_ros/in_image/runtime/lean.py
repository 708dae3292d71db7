"""Lean run image (ENABLE_LEAN_RUN_IMAGE): the Debian packages the install space needs at run
time, instead of the `-dev` packages rosdep names for its exec dependencies.

Run in the image's lean-resolve stage (the build stage: every dependency installed, install/
built): `python3 -m docker_ros.in_image.runtime.lean RESOLVED DEST` copies the resolution
RESOLVED (the
resolve stage's .docker-ros) to DEST with the exec apt set of rosdep.json replaced by
  - the declared exec packages that are not `-dev` packages (kept as they are), plus
  - the packages owning the shared-library closure (ldd) of every ELF file in install/, plus
  - the packages owning the modules the Python files in install/ import (in the ROS environment).
Everything else of the run image (additional debs, pip, files, hooks) stays as declared.
Libraries loaded with dlopen (plugins) are not seen: their packages must be non-dev exec
dependencies. In a locked build the resolution's copy of the lock gets a run entry for the lean
set: it and all it depends on at the locked dev image's versions (lock.lean_entry).
Standard library only, Python 3.8+ (runs inside images)."""

import ast
import json
import os
import shutil
import sys
from pathlib import Path
from typing import Dict, Iterable, List, Mapping, Sequence, Set, Tuple, Union

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.entry import image_main
from docker_ros.in_image.runtime.files import is_elf
from docker_ros.in_image.runtime.lockapt import lock_lean
from docker_ros.in_image.runtime.lockfile import LOCK_FILE, LockError
from docker_ros.in_image.runtime.process import probe
from docker_ros.in_image.runtime.rosenv import sourced_env, workspace_setup_files
from docker_ros.in_image.runtime.workspace import LOG, StepError, Workspace

STEP = "lean"
DPKG_INFO = Path("/var/lib/dpkg/info")
USRMERGED = ("/lib/", "/lib32/", "/lib64/", "/libx32/", "/bin/", "/sbin/")
# Where each top-level module is, as the ROS environment's python3 sees it: a file, the folders
# of a namespace package, [] for built-in modules, null when not found.
FIND_MODULES = """
import importlib.util, json, sys
found = {}
for name in sys.argv[1:]:
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        spec = None
    if spec is None:
        found[name] = None
    elif spec.has_location and spec.origin:
        found[name] = [spec.origin]
    else:
        found[name] = list(spec.submodule_search_locations or [])
print(json.dumps(found))
"""


def is_dev_package(name: str) -> bool:
    return name.split(":")[0].endswith("-dev")


def lean_packages(declared: Sequence[str], needed: Iterable[str]) -> List[str]:
    """The lean exec apt set: the declared packages but the `-dev` ones, and what is needed."""
    return sorted({p for p in declared if not is_dev_package(p)} | set(needed))


def canonical(path: str) -> str:
    """One spelling per file on a merged /usr (dpkg may list /lib/..., ldd print /usr/lib/...)."""
    path = os.path.normpath(path)
    for prefix in USRMERGED:
        if path.startswith(prefix):
            return "/usr" + path
    return path


def dpkg_index(info: Path = DPKG_INFO) -> Dict[str, Set[str]]:
    """Installed file (canonical path) -> the packages that list it."""
    index: Dict[str, Set[str]] = {}
    for listing in sorted(info.glob("*.list")):
        package = listing.stem.split(":")[0]
        for line in listing.read_text(errors="replace").splitlines():
            if line and line != "/.":
                index.setdefault(canonical(line), set()).add(package)
    return index


def owners(path: str, index: Mapping[str, Set[str]]) -> Set[str]:
    """The packages owning a file, by its path or (through symlinks) its target."""
    found = set(index.get(canonical(path), ()))
    return found or set(index.get(canonical(os.path.realpath(path)), ()))


def parse_ldd(text: str) -> Tuple[List[str], List[str]]:
    """(paths of the libraries ldd found, names it did not find)."""
    paths: List[str] = []
    missing: List[str] = []
    for raw in text.splitlines():
        line = raw.strip()
        name, arrow, rest = line.partition("=>")
        target = rest.strip() if arrow else line
        if target.startswith("not found"):
            missing.append(name.strip())
        elif target.startswith("/"):
            paths.append(target.split(" (")[0])
    return paths, missing


def is_python(path: Path) -> bool:
    if path.suffix == ".py":
        return True
    with path.open("rb") as handle:
        first = handle.readline(200)
    return first.startswith(b"#!") and b"python" in first


def install_files(install: Path) -> Tuple[List[Path], List[Path]]:
    """(ELF files, Python files) below install/ (regular files, no symlinks, no caches)."""
    elf: List[Path] = []
    python: List[Path] = []
    for directory, dirs, names in os.walk(str(install)):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        for name in sorted(names):
            path = Path(directory) / name
            if path.is_symlink() or not path.is_file():
                continue
            if is_elf(path):
                elf.append(path)
            elif is_python(path):
                python.append(path)
    return elf, python


def import_names(node: ast.AST) -> List[str]:
    """Top-level names an import statement imports absolutely (none for other nodes)."""
    if isinstance(node, ast.Import):
        return [alias.name.split(".")[0] for alias in node.names]
    if isinstance(node, ast.ImportFrom) and not node.level and node.module:
        return [node.module.split(".")[0]]
    return []


def imported_modules(source: Union[str, ast.AST]) -> Set[str]:
    """Top-level names of the absolute imports anywhere in a Python source (or its tree)."""
    tree = ast.parse(source) if isinstance(source, str) else source
    return {name for node in ast.walk(tree) for name in import_names(node)}


# Handlers that make an import in their `try` optional (the code goes on without the module).
_IMPORT_GUARDS = ("ImportError", "ModuleNotFoundError", "Exception", "BaseException")


def _guards_imports(node: ast.Try) -> bool:
    for handler in node.handlers:
        if any(isinstance(n, ast.Raise) for part in handler.body for n in ast.walk(part)):
            continue  # (`except ImportError: raise RuntimeError("need x")`: still required)
        if handler.type is None:
            return True
        types = handler.type.elts if isinstance(handler.type, ast.Tuple) else [handler.type]
        if any(isinstance(t, ast.Name) and t.id in _IMPORT_GUARDS for t in types):
            return True
    return False


def optional_modules(source: Union[str, ast.AST]) -> Set[str]:
    """Top-level names a Python source imports only in a `try` (or its handlers) that catches
    ImportError: fallbacks such as setuptools' console-script wrapper's
    `from importlib_metadata import distribution`."""
    guarded: Set[str] = set()
    plain: Set[str] = set()

    def visit(node: ast.AST, inside: bool) -> None:
        if isinstance(node, ast.Try) and _guards_imports(node):
            for guarded_child in [*node.body, *node.handlers]:
                visit(guarded_child, True)
            for other_child in [*node.orelse, *node.finalbody]:
                visit(other_child, inside)
            return
        (guarded if inside else plain).update(import_names(node))
        for child in ast.iter_child_nodes(node):
            visit(child, inside)

    visit(ast.parse(source) if isinstance(source, str) else source, False)
    return guarded - plain


def local_names(path: Path) -> Set[str]:
    """Modules a script can import from its own folder."""
    return {p.stem if p.suffix == ".py" else p.name for p in path.parent.iterdir()}


def runtime_env(ws: Workspace, settings: Settings) -> Dict[str, str]:
    """The run image's environment (ROS, then install/), without our own PYTHONPATH entry."""
    base = dict(os.environ)
    base.pop("PYTHONPATH", None)
    return sourced_env(workspace_setup_files(settings, ws.install, step=STEP), step=STEP,
                       base_env=base)


def library_needs(elf: Sequence[Path], env: Mapping[str, str], install: Path
                  ) -> Tuple[Dict[str, Set[str]], Set[str]]:
    """(library path outside install/ -> ELF files needing it, libraries not found)."""
    library_dirs = sorted({str(p.parent) for p in elf if ".so" in p.name})
    env = dict(env)
    env["LD_LIBRARY_PATH"] = os.pathsep.join(
        library_dirs + [d for d in env.get("LD_LIBRARY_PATH", "").split(os.pathsep) if d])
    needs: Dict[str, Set[str]] = {}
    missing: Set[str] = set()
    for path in elf:
        proc = probe(["ldd", str(path)], step=STEP, env=env, hint="install libc-bin")
        if proc.returncode != 0:  # static, or not loadable here (kept as it is)
            continue
        found, absent = parse_ldd(proc.stdout)
        missing.update(f"{name} (needed by {path.relative_to(install)})" for name in absent)
        for library in found:
            if not library.startswith(str(install) + "/"):
                needs.setdefault(library, set()).add(str(path.relative_to(install)))
    return needs, missing


def module_needs(python: Sequence[Path], env: Mapping[str, str], install: Path
                 ) -> Tuple[Dict[str, Set[str]], Set[str], Set[str]]:
    """(module file or folder outside install/ -> Python files importing it, modules not found
    by the ROS environment's python3, those of them every file imports only optionally)."""
    importers: Dict[str, Set[str]] = {}
    required: Set[str] = set()
    for path in python:
        try:
            tree = ast.parse(path.read_text(errors="replace"))  # (parsed once for both)
            names = imported_modules(tree)
            optional = optional_modules(tree)
        except SyntaxError as exc:
            LOG.warning("%s: %s is not Python 3 (%s): its imports are not followed", STEP,
                        path.relative_to(install), exc.msg)
            continue
        for name in names - local_names(path):
            importers.setdefault(name, set()).add(str(path.relative_to(install)))
            if name not in optional:
                required.add(name)
    if not importers:
        return {}, set(), set()
    proc = probe(["python3", "-c", FIND_MODULES, *sorted(importers)], step=STEP, env=env)
    if proc.returncode != 0:
        raise StepError(STEP, "finding the imported Python modules failed: "
                        + (proc.stderr.strip().splitlines() or ["no message"])[-1])
    needs: Dict[str, Set[str]] = {}
    missing: Set[str] = set()
    optional_missing: Set[str] = set()
    for name, places in json.loads(proc.stdout).items():
        if places is None:
            (missing if name in required else optional_missing).add(
                f"{name} (imported by {', '.join(sorted(importers[name]))})")
        for place in places or []:
            if not place.startswith(str(install) + "/"):
                needs.setdefault(place, set()).update(importers[name])
    return needs, missing, optional_missing


def providers(needs: Mapping[str, Set[str]], index: Mapping[str, Set[str]]
              ) -> Tuple[Dict[str, Set[str]], List[str]]:
    """(package -> what it provides, files no package owns)."""
    by_package: Dict[str, Set[str]] = {}
    unowned: List[str] = []
    for path in sorted(needs):
        found = owners(path, index)
        if not found:
            unowned.append(path)
        for package in found:
            by_package.setdefault(package, set()).add(path)
    return by_package, unowned


def lean_resolution(ws: Workspace, settings: Settings, resolved: Path,
                    destination: Path) -> Dict[str, object]:
    """Copy the resolution with the lean exec apt set; returns the report (also written to
    DESTINATION.json)."""
    elf, python = install_files(ws.install)
    env = runtime_env(ws, settings)
    libraries, missing_libraries = library_needs(elf, env, ws.install)
    modules, missing_modules, optional_missing = module_needs(python, env, ws.install)
    index = dpkg_index()
    for_libraries, unowned_libraries = providers(libraries, index)
    for_modules, unowned_modules = providers(modules, index)
    if destination.exists():
        shutil.rmtree(str(destination))
    shutil.copytree(str(resolved), str(destination))
    plan_file = destination / "rosdep.json"
    plan = json.loads(plan_file.read_text()) if plan_file.is_file() else {}
    exec_set = plan.setdefault("exec", {"apt": [], "pip": []})
    declared = list(exec_set.get("apt") or [])
    exec_set["apt"] = lean_packages(declared, set(for_libraries) | set(for_modules))
    plan_file.write_text(json.dumps(plan, indent=2, sort_keys=True) + "\n")
    if (destination / LOCK_FILE).is_file():  # a locked build (the resolve stage put it there)
        try:
            lock_lean(destination / LOCK_FILE, exec_set["apt"])
        except LockError as exc:
            raise StepError(STEP, str(exc)) from None
    dropped = sorted(set(declared) - set(exec_set["apt"]))
    unowned = sorted(unowned_libraries + unowned_modules)
    missing = sorted(missing_libraries | missing_modules)
    report: Dict[str, object] = {
        "declared": declared,
        "lean": exec_set["apt"],
        "dropped": dropped,
        "for_libraries": {p: sorted(v) for p, v in sorted(for_libraries.items())},
        "for_modules": {p: sorted(v) for p, v in sorted(for_modules.items())},
        "not_from_packages": unowned,
        "not_found": missing,
        "optional_not_found": sorted(optional_missing),
    }
    # the report beside the resolution, not in it: the run image's dependency layer is keyed by
    # the resolution's content, which must change only when the packages do
    destination.with_name(destination.name + ".json").write_text(
        json.dumps(report, indent=2) + "\n")
    LOG.info("%s: %d ELF and %d Python files in install/; exec apt packages: %d declared, "
             "%d lean", STEP, len(elf), len(python), len(declared), len(exec_set["apt"]))
    LOG.info("%s: dropped: %s", STEP, " ".join(dropped) or "(none)")
    LOG.info("%s: for libraries: %s", STEP, " ".join(sorted(for_libraries)) or "(none)")
    LOG.info("%s: for Python modules: %s", STEP, " ".join(sorted(for_modules)) or "(none)")
    for what in unowned:
        LOG.info("%s: %s is not from a Debian package (left to pip, files and hooks)", STEP, what)
    for what in missing:
        LOG.warning("%s: not found in the dev image either: %s", STEP, what)
    for what in sorted(optional_missing):
        LOG.info("%s: optional import (in a try that catches ImportError) not found in the dev "
                 "image either: %s", STEP, what)
    return report


def main(argv: List[str]) -> int:
    return image_main(argv, module="runtime.lean", step=STEP,
                      description="ENABLE_LEAN_RUN_IMAGE: the run image's dependencies found "
                      "from what the built install space needs, RESOLVED's resolution narrowed "
                      "to them in DESTINATION.", arguments=["RESOLVED", "DESTINATION"],
                      action=lambda ws, settings, args: lean_resolution(
                          ws, settings, Path(args[0]), Path(args[1])))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
