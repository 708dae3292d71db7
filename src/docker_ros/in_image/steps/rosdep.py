"""rosdep: resolve every package.xml dependency with rosdep (collect) and install it (apply).

collect writes rosdep.json with two sets, "all" (dev image) and "exec" (run image), each
{"apt": [...], "pip": [...]}. Resolution uses `rosdep resolve`, which does not look at what is
installed, so the result only depends on the sources, the rosdep database and the OS."""

import contextlib
import hashlib
import logging
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Any, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple

from docker_ros.core.settings import Settings, explicitly_set
from docker_ros.in_image.runtime.apt import apt_install
from docker_ros.in_image.runtime.files import repository_path
from docker_ros.in_image.runtime.lock import locked_rosdep_plan
from docker_ros.in_image.runtime.packages import (
    DEPENDENCY_SETS,
    blacklisted_dependents,
    environment_packages,
    find_packages,
    select_keys,
    underlay_packages,
)
from docker_ros.in_image.runtime.pipinstall import pip_install
from docker_ros.in_image.runtime.process import hook_context, privileged, probe, run
from docker_ros.in_image.runtime.rosdeprules import (
    cached_sources,
    os_name,
    overridden_keys,
    override_lines,
    rules_problem,
)
from docker_ros.in_image.runtime.rosenv import ros_distro, ros_setup_files, sourced_env
from docker_ros.in_image.runtime.workspace import (
    StepError,
    Workspace,
    dry,
    format_argv,
    phases,
    step_log,
)
from docker_ros.in_image.steps.blacklist import blacklisted_packages

STEP = "rosdep"
STATE_FILE = "rosdep.json"
ORIGINS_FILE = "rosdep-origins.json"  # apt package -> its rosdep key and the packages needing it
INSTALLERS = ("apt", "pip")
SYSTEM_SOURCES = Path("/etc/ros/rosdep/sources.list.d")
LOG = logging.getLogger(__name__)

Resolution = Dict[str, Dict[str, List[str]]]  # key -> installer -> system packages

_ERROR_PATTERNS = (
    re.compile(r"no rosdep rule for '(?P<key>[^']+)'"),
    re.compile(r"No definition of \[(?P<key>[^\]]+)\] for OS"),
    re.compile(r"rosdep key\s*:\s*(?P<key>\S+)"),
    re.compile(r"Cannot locate rosdep definition for \[(?P<key>[^\]]+)\]"),
)


def parse_resolve_output(text: str, keys: Sequence[str]) -> Resolution:
    """Parse `rosdep resolve` stdout: `#ROSDEP[key]` (absent for a single key), `#installer`,
    then lines of white-space separated system packages."""
    result: Resolution = {}
    key: Optional[str] = keys[0] if len(keys) == 1 else None
    installer: Optional[str] = None
    for raw in text.splitlines():
        line = raw.strip()
        if not line:
            continue
        header = re.match(r"^#ROSDEP\[(.+)\]$", line)
        if header:
            key, installer = header.group(1), None
            result.setdefault(key, {})
        elif line.startswith("#"):
            installer = line[1:].strip()
            if key is not None:
                result.setdefault(key, {}).setdefault(installer, [])
        elif key is not None and installer is not None:
            result.setdefault(key, {}).setdefault(installer, []).extend(line.split())
    return result


def parse_resolve_errors(text: str) -> Dict[str, str]:
    """Keys rosdep could not resolve, with rosdep's reason (its `ERROR: ...` line)."""
    errors: Dict[str, str] = {}
    reason = ""
    for raw in text.splitlines():
        line = raw.strip()
        if line.startswith("ERROR:"):
            reason = line[len("ERROR:") :].strip()
        for pattern in _ERROR_PATTERNS:
            match = pattern.search(line)
            if match and match.group("key") not in errors:
                errors[match.group("key")] = reason or line
                break
    return errors


def rosdep_env(environ: Optional[Mapping[str, str]] = None) -> Dict[str, str]:
    env = dict(os.environ if environ is None else environ)
    env.setdefault("ROS_PYTHON_VERSION", "3")  # rosdep warns and guesses otherwise
    return env


def resolve_argv(keys: Sequence[str], distro: Optional[str]) -> List[str]:
    return ["rosdep", "resolve"] + (["--rosdistro", distro] if distro else []) + list(keys)


def resolve(
    keys: Sequence[str],
    distro: Optional[str],
    *,
    step: str = STEP,
    env: Optional[Mapping[str, str]] = None,
) -> Tuple[Resolution, Dict[str, str]]:
    """Resolve keys with as few rosdep calls as possible: rosdep stops at some errors, so the
    failing keys are taken out and the rest resolved again. Returns (resolved, failed)."""
    remaining = sorted(set(keys))
    failed: Dict[str, str] = {}
    resolved: Resolution = {}
    env = rosdep_env(env)
    while remaining:
        argv = resolve_argv(remaining, distro)
        LOG.info(
            "%s: rosdep resolve%s <%d keys>",
            step,
            f" --rosdistro {distro}" if distro else "",
            len(remaining),
        )
        proc = probe(argv, step=step, env=env, hint="install python3-rosdep")
        if proc.returncode == 0:
            resolved.update(parse_resolve_output(proc.stdout, remaining))
            break
        errors = {k: v for k, v in parse_resolve_errors(proc.stderr).items() if k in remaining}
        if not errors:
            lines = proc.stderr.strip().splitlines()
            raise StepError(
                step,
                f"rosdep resolve failed with exit code {proc.returncode}: "
                + (lines[0] if lines else "(no message)"),
                proc.returncode,
            )
        failed.update(errors)
        remaining = [k for k in remaining if k not in errors]
    return resolved, failed


def plan_rosdep(
    selected: Mapping[str, Mapping[str, Sequence[str]]],
    resolved: Resolution,
) -> Dict[str, Dict[str, List[str]]]:
    """rosdep.json: per dependency set, sorted unique packages per installer."""
    plan: Dict[str, Dict[str, List[str]]] = {}
    for types, keys in selected.items():
        sets: Dict[str, set] = {installer: set() for installer in INSTALLERS}
        for key in keys:
            for installer, packages in resolved.get(key, {}).items():
                sets.setdefault(installer, set()).update(packages)
        plan[types] = {installer: sorted(pkgs) for installer, pkgs in sorted(sets.items())}
    return plan


def apt_origins(selected: Mapping[str, Sequence[str]], resolved: Resolution) -> Dict[str, str]:
    """Where each apt package of the resolution comes from (selected: key -> the packages
    needing it), for the error naming one apt does not have: `rosdep key K of pkg_a`."""
    origins: Dict[str, List[str]] = {}
    for key, users in sorted(selected.items()):
        for package in resolved.get(key, {}).get("apt", ()):
            origins.setdefault(package, []).append(f"{key} of {', '.join(users)}")
    return {package: "rosdep key " + "; ".join(keys) for package, keys in origins.items()}


def unsupported_installers(
    plan: Mapping[str, Mapping[str, Sequence[str]]], resolved: Resolution
) -> List[str]:
    """`key -> installer` descriptions for installers we cannot drive (only apt and pip)."""
    bad = []
    for key, by_installer in sorted(resolved.items()):
        for installer, packages in sorted(by_installer.items()):
            if installer not in INSTALLERS and packages:
                bad.append(f"{key} ({installer}: {' '.join(packages)})")
    return bad


def format_failures(failed: Mapping[str, str], needed_by: Mapping[str, Sequence[str]]) -> str:
    parts = [
        f"'{key}' needed by {', '.join(needed_by.get(key, ['?']))}: {reason}"
        for key, reason in sorted(failed.items())
    ]
    return (
        "cannot resolve rosdep key"
        + ("s " if len(parts) > 1 else " ")
        + "; ".join(parts)
        + " (fix the key in package.xml, add a rule to ROSDEP_RULES_FILE (docker/rosdep.yaml),"
        " blacklist the package, or run `rosdep update`)"
    )


def rosdep_ready(environ: Optional[Mapping[str, str]] = None) -> Tuple[bool, bool]:
    """(sources configured?, cache present?) as rosdep sees them."""
    env = os.environ if environ is None else environ
    source_path = env.get("ROSDEP_SOURCE_PATH") or "/etc/ros/rosdep/sources.list.d"
    sources = any(
        p.suffix == ".list"
        for d in source_path.split(os.pathsep)
        if Path(d).is_dir()
        for p in Path(d).iterdir()
    )
    ros_home = Path(env.get("ROS_HOME") or Path.home() / ".ros")
    return sources, (ros_home / "rosdep" / "sources.cache" / "index").is_file()


def base_source_lists(environ: Optional[Mapping[str, str]] = None) -> List[Path]:
    """The sources lists rosdep uses here (ROSDEP_SOURCE_PATH, else `rosdep init`'s folder)."""
    env = os.environ if environ is None else environ
    source_path = env.get("ROSDEP_SOURCE_PATH") or str(SYSTEM_SOURCES)
    return [p for d in source_path.split(os.pathsep) if Path(d).is_dir()
            for p in sorted(Path(d).iterdir()) if p.suffix == ".list"]


def plan_sources(rules: Optional[Path], base_lists: Sequence[Path]) -> Dict[str, str]:
    """The files of a private sources.list.d: the repository's rules first (earlier sources
    win in rosdep), then the base lists as they are."""
    files = {"00-docker-ros-rules.list": f"yaml {rules.resolve().as_uri()}\n"} if rules else {}
    for index, path in enumerate(base_lists, start=10):
        files[f"{index}-{path.name}"] = path.read_text()
    return files


def unreachable_sources(text: str) -> List[str]:
    """Sources `rosdep update` could not read, with the reason."""
    return [f"{m.group(1)} ({m.group(2).strip()})" for m in re.finditer(
        r"unable to process source \[([^\]]+)\]:\s*\n\s*(.+)", text)]


def private_database(
    home: Path, rules: Optional[Path], distro: Optional[str], *, quiet_reuse: bool = True
) -> Dict[str, str]:
    """A rosdep database of its own in `home` (never /etc, never ~/.ros): the repository's rules
    and the base rules it can reach. Returns the environment for rosdep resolve."""
    files = plan_sources(rules, base_source_lists())
    sources = home / "sources.list.d"
    env = {**rosdep_env(), "ROSDEP_SOURCE_PATH": str(sources), "ROS_HOME": str(home / "home")}
    content = "".join(k + v for k, v in sorted(files.items()))
    content += rules.read_text() if rules else ""
    stamp = home / "inputs.sha256"
    digest = hashlib.sha256(content.encode()).hexdigest()
    cache = home / "home" / "rosdep" / "sources.cache" / "index"
    if quiet_reuse and cache.is_file() and stamp.is_file() and stamp.read_text() == digest:
        return env
    if not files:
        raise StepError(STEP, "no rosdep rules here: neither ROSDEP_RULES_FILE nor any sources "
                        f"list in {SYSTEM_SOURCES} (run `sudo rosdep init`, or add the rules "
                        "your packages need to docker/rosdep.yaml)")
    shutil.rmtree(str(home), ignore_errors=True)
    sources.mkdir(parents=True)
    for name, text in files.items():
        (sources / name).write_text(text)
    argv = ["rosdep", "update"] + (["--rosdistro", distro] if distro else [])
    for attempt in ("index", "no index"):
        LOG.info("%s: %s (own database in %s)", STEP, format_argv(argv), home)
        proc = probe(argv, step=STEP, env=env, hint="install python3-rosdep")
        if proc.returncode == 0 or cache.is_file():
            break
        if attempt == "index":
            # The rosdistro index (GitHub) unreachable: rules files alone still resolve keys.
            LOG.warning("%s: rosdep update failed (%s); trying without the rosdistro index "
                        "(ROS package keys then come from rules files only)", STEP,
                        (proc.stderr.strip().splitlines() or ["no message"])[-1])
            index = home / "index-v4.yaml"
            index.write_text("type: index\nversion: 4\ndistributions: {}\n")
            env["ROSDISTRO_INDEX_URL"] = index.as_uri()
            argv = ["rosdep", "update"]  # (an empty index knows no ROS_DISTRO)
    if not cache.is_file():
        raise StepError(STEP, "rosdep update failed: " + (
            proc.stderr.strip().splitlines() or ["no message"])[-1].strip())
    for source in unreachable_sources(proc.stderr):
        LOG.warning("%s: rules source not reachable, its keys stay unresolved: %s", STEP, source)
    stamp.write_text(digest)
    return env


def prepare_rosdep(distro: Optional[str], *, dry_run: bool) -> bool:
    """`rosdep init`/`rosdep update` when never done here. Returns whether resolution can run."""
    sources, cache = rosdep_ready()
    if not sources:
        run(privileged(["rosdep", "init"]), step=STEP, dry_run=dry_run)
    if not sources or not cache:
        argv = ["rosdep", "update"] + (["--rosdistro", distro] if distro else [])
        run(argv, step=STEP, dry_run=dry_run, env=rosdep_env())
        return not dry_run
    return True


# A dry run where rosdep was never set up: the database its `rosdep init` and `rosdep update`
# would make does not exist, so nothing is resolved.
UNRESOLVED: Dict[str, str] = {"DOCKER_ROS_ROSDEP": "not set up"}


@contextlib.contextmanager
def rosdep_database(
    ws: Workspace, rules: Optional[Path], distro: Optional[str], *, dry_run: bool
) -> Iterator[Optional[Dict[str, str]]]:
    """The environment rosdep resolves in. With the repository's own rules: a database of our
    own, in the host workspace (kept, updated when its inputs change) or, in images and dry
    runs, in a temporary folder (nothing of it in a layer). Without: rosdep's usual database,
    made with `rosdep init`/`rosdep update` when missing (a dry run shows those and yields
    UNRESOLVED, or uses a temporary one when rosdep has sources lists)."""
    temporary = dry_run or hook_context() == "image"
    # In an image with sources lists (the base's, or a hook's) but no database made from them:
    # a temporary one, which still resolves rules files' keys when the rosdistro index is out
    # of reach (the system's `rosdep update` fails then).
    own = rules is not None or (hook_context() == "image" and rosdep_ready() == (True, False))
    if not own and (not dry_run or all(rosdep_ready())):
        if not prepare_rosdep(distro, dry_run=dry_run):
            raise StepError(STEP, "rosdep database not ready")  # only dry runs get here
        yield None
        return
    if not temporary:
        yield private_database(ws.state / "rosdep", rules, distro)
        return
    if dry_run and not own and not rosdep_ready()[0]:
        prepare_rosdep(distro, dry_run=True)  # what a real run does first: init, update
        yield UNRESOLVED
        return
    with tempfile.TemporaryDirectory(prefix="docker-ros-rosdep-") as tmp:
        if dry_run:
            dry(STEP, f"resolve with a temporary rosdep database in {tmp}"
                + (f" (rules: {rules})" if rules else ""))
        yield private_database(Path(tmp), rules, distro)


def report_overrides(rules: Path, shown: str, env: Mapping[str, str]) -> None:
    """A warning per key of the rules file that the base's rules define otherwise (overriding
    is legitimate, silently dropping the base's packages is not); an own rules file that
    rosdep update could not read is an error (rules_problem has no YAML reader here)."""
    sources = cached_sources(Path(env["ROS_HOME"]))
    own_url = rules.resolve().as_uri()
    written = [line for line in rules.read_text().splitlines()
               if line.strip() and not line.lstrip().startswith("#")]
    if sources and written and own_url not in [url for url, _ in sources]:
        raise StepError(STEP, f"ROSDEP_RULES_FILE {shown}: rosdep update could not read it: "
                        "check that it is valid YAML")
    for line in override_lines(shown, overridden_keys(own_url, sources), os_name()):
        LOG.warning("%s: %s", STEP, line)


def collect(
    ws: Workspace, settings: Settings, *, dry_run: bool
) -> Optional[Dict[str, Dict[str, List[str]]]]:
    distro = ros_distro(settings)
    packages = find_packages(ws, settings, step=STEP)
    blacklist = blacklisted_packages(ws, settings)
    # the packages of the ROS environment the build sources (the base image's), as
    # `rosdep install --ignore-src` after sourcing it (docker-ros)
    installed = environment_packages(sourced_env(ros_setup_files(settings), step=STEP))
    underlay = sorted({*underlay_packages(), *installed})
    found = sorted({key for package in packages for tag in DEPENDENCY_SETS["all"]
                    for key in package.depends.get(tag, ())}.intersection(installed))
    if found:
        LOG.info("%s: installed in the base image's ROS environment, so not rosdep keys: %s",
                 STEP, ", ".join(found))
    selected = {
        types: select_keys(packages, types, blacklist, underlay) for types in DEPENDENCY_SETS
    }
    all_keys = selected["all"]
    for name, users in blacklisted_dependents(packages, "all", blacklist).items():
        LOG.warning("%s: %s depend%s on the blacklisted package %s: not installed, not built "
                    "(blacklist %s too if it cannot do without)", STEP, ", ".join(users),
                    "s" if len(users) == 1 else "", name, "it" if len(users) == 1 else "them")
    LOG.info(
        "%s: %d packages (%d blacklisted), %d rosdep keys (%d exec)",
        STEP,
        len(packages),
        len(blacklist),
        len(all_keys),
        len(selected["exec"]),
    )
    rules_path = repository_path(ws, settings, "rosdep_rules_file", step=STEP)
    rules = rules_path if rules_path.is_file() else None
    if rules is None and explicitly_set(settings, "rosdep_rules_file"):
        raise StepError(STEP, f"ROSDEP_RULES_FILE '{settings.rosdep_rules_file}' not found "
                        "in the repository, but set explicitly: fix the path or unset it")
    problem = rules_problem(rules, settings.rosdep_rules_file) if rules else None
    if problem:
        raise StepError(STEP, problem)
    # No keys, no rosdep: a workspace without dependencies needs no rosdep database.
    resolved: Resolution = {}
    failed: Dict[str, str] = {}
    if all_keys:
        with rosdep_database(ws, rules, distro, dry_run=dry_run) as env:
            if env is UNRESOLVED:  # nothing resolved: what apply would install is unknown
                dry(STEP, f"resolve {len(all_keys)} key{'s' if len(all_keys) > 1 else ''} in the"
                    " database those commands make")
                return None
            if rules and env:
                report_overrides(rules, settings.rosdep_rules_file, env)
            resolved, failed = resolve(sorted(all_keys), distro, env=env)
    if failed:
        raise StepError(STEP, format_failures(failed, all_keys))
    for key in sorted(all_keys):
        shown = "; ".join(f"{i}: {' '.join(p)}" for i, p in sorted(resolved.get(key, {}).items()))
        LOG.info("%s: %s -> %s", STEP, key, shown or "(nothing to install)")
    plan = plan_rosdep(selected, resolved)
    bad = unsupported_installers(plan, resolved)
    if bad:
        raise StepError(
            STEP,
            "keys resolve to installers docker-ros cannot use (only apt and pip): "
            + ", ".join(bad),
        )
    ws.save_plan(STEP, STATE_FILE, plan, dry_run=dry_run)
    ws.save_plan(STEP, ORIGINS_FILE, apt_origins(all_keys, resolved), dry_run=dry_run)
    return plan


def apply(plan: Mapping[str, Any], dependency_types: str, *, dry_run: bool,
          origins: Optional[Mapping[str, str]] = None) -> None:
    chosen = plan.get(dependency_types)
    if not isinstance(chosen, dict):
        raise StepError(STEP, f"{STATE_FILE} has no {dependency_types!r} set: re-run collect")
    what = f"installing rosdep dependencies ({dependency_types})"
    apt_install(list(chosen.get("apt") or []), step=STEP, dry_run=dry_run, what=what,
                origins=origins)
    pip_install(list(chosen.get("pip") or []), step=STEP, dry_run=dry_run, what=what)


def main(
    ws: Workspace,
    settings: Settings,
    *,
    phase: str = "all",
    dry_run: bool = False,
    **options: object,
) -> None:
    """collect: resolve keys into rosdep.json; apply: install the `dependency_types` set."""
    do_collect, do_apply = phases(STEP, phase)
    dependency_types = str(options.get("dependency_types") or "all")
    if dependency_types not in DEPENDENCY_SETS:
        raise StepError(STEP, f"unknown dependency types {dependency_types!r}; use all or exec")
    with step_log(STEP):
        plan: Optional[Mapping[str, Any]] = None
        if do_collect:
            plan = collect(ws, settings, dry_run=dry_run)
        if do_apply:
            if not do_collect:
                plan = ws.load_plan(STEP, STATE_FILE)
            if plan is None:
                dry(STEP, f"install the resolved {dependency_types!r} dependencies")
                return
            plan = locked_rosdep_plan(ws, settings, plan, dependency_types, STEP,
                                      dry_run=dry_run)
            origins = ws.read_state(ORIGINS_FILE)
            apply(plan, dependency_types, dry_run=dry_run,
                  origins=origins if isinstance(origins, dict) else None)
