"""docker-ros.lock: what a locked build installs, and whether the repository still matches it.
Standard library only, Python 3.8+ (runs inside images and on the host).

The lock is JSON with sorted keys (readable, diffable, one record per target and platform):
    {"format": 1,
     "targets": {"run/amd64": {
         "base_image": {"ref": "ros:noetic", "digest": "sha256:...", "local": false},
         "inputs": {"debs": [...], "pip": [...], "rosdep_keys": [...], "repos": {...},
                    "rosdep_rules": "sha256:..."},
         "repos": {"src/upstream/foo": {"url": "...", "commit": "<40 hex>"}},
         "apt": {"name": "version"},
         "prepare": {"name": "version"},
         "pip": {"name": {"version": "1.2", "sha256": "..."}}}}}
`prepare` is what the image's prepare installed over the bare base image (python3, the tools,
ROS when the base lacks it; for dev the toolchain too): a locked build's prepare installs it at
those versions through an apt preferences file (apt_preferences).
`inputs` is what the collect phase resolved when the lock was written: a build whose inputs
differ is stale and stops before installing anything."""

import hashlib
import json
import os
import re
import subprocess
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence

from docker_ros.core.loading import host_platform
from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.apt import (
    DPKG_STATUS,
    apt_env,
    apt_get,
    apt_install,
    apt_lists_present,
)
from docker_ros.in_image.runtime.process import probe
from docker_ros.in_image.runtime.workspace import StepError, Workspace

LOCK_FILE = "docker-ros.lock"
FORMAT = 1
TARGET_ENV = "DOCKER_ROS_LOCK_TARGET"
# set (to true) by the tool in the image stages of a locked build (LOCKED itself is no ARG)
LOCKED_ENV = "DOCKER_ROS_LOCKED"
HOST_TARGET = "host"  # the entry host steps honour (`inv lock --host`)
# `apt-get install -s`: "Inst name [old] (version suite [arch])"
APT_INST = re.compile(r"^Inst (\S+) (?:\[[^\]]*\] )?\((\S+) ([^\[)]*)")
PIP_NAME = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)")


class LockError(Exception):
    """The lock is missing, unreadable, stale, or names what the sources no longer have."""


def target_key(target: str, platform: str) -> str:
    return f"{target}/{platform}"


def dump_lock(lock: Mapping[str, Any]) -> str:
    """The lock's text: sorted keys and a final newline, so the same resolution gives the same
    bytes (and the same digest)."""
    return json.dumps(lock, indent=2, sort_keys=True) + "\n"


def lock_digest(text: str) -> str:
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()


def load_lock(path: Path) -> Dict[str, Any]:
    if not path.is_file():
        raise LockError(f"LOCKED: {path.name} not found: run `inv lock` first")
    try:
        lock = json.loads(path.read_text())
    except ValueError as exc:
        raise LockError(f"LOCKED: {path.name} is not valid JSON ({exc}): run `inv lock`") from None
    if not isinstance(lock, dict) or lock.get("format") != FORMAT:
        raise LockError(f"LOCKED: {path.name} has an unknown format: run `inv lock`")
    return lock


def locked_target(lock: Mapping[str, Any], target: str, platform: str) -> Dict[str, Any]:
    key = target_key(target, platform)
    entry = (lock.get("targets") or {}).get(key)
    if entry is None:
        task = "inv lock --host" if target == HOST_TARGET else "inv lock"
        raise LockError(f"LOCKED: docker-ros.lock has no entry for {key}: run `{task}`")
    return dict(entry)


def apt_name(spec: str) -> str:
    """The package name of an apt spec (`pkg`, `pkg=1.2`, `pkg/bookworm`, `pkg:arm64`)."""
    return re.split(r"[=/]", spec, maxsplit=1)[0]


def pip_name(requirement: str) -> str:
    """The normalised project name of a requirement (PEP 503)."""
    match = PIP_NAME.match(requirement)
    return re.sub(r"[-_.]+", "-", match.group(1)).lower() if match else requirement


def parse_apt_simulation(lines: Sequence[str]) -> Dict[str, str]:
    """name -> version of every package `apt-get install -s` would install (dependencies too)."""
    found: Dict[str, str] = {}
    for line in lines:
        match = APT_INST.match(line)
        if match:
            found[match.group(1)] = match.group(2)
    return found


def parse_pip_report(report: Mapping[str, Any]) -> Dict[str, Dict[str, str]]:
    """name -> {version, sha256} from `pip install --dry-run --report` (pip >= 22.2)."""
    found: Dict[str, Dict[str, str]] = {}
    for item in report.get("install") or []:
        meta = item.get("metadata") or {}
        entry = {"version": str(meta.get("version", ""))}
        hashes = ((item.get("download_info") or {}).get("archive_info") or {}).get("hashes") or {}
        if hashes.get("sha256"):
            entry["sha256"] = hashes["sha256"]
        found[pip_name(str(meta.get("name", "")))] = entry
    return found


def require_locked(kind: str, names: Sequence[str], locked: Mapping[str, Any]) -> None:
    missing = sorted(name for name in names if name not in locked)
    if missing:
        raise LockError(
            f"LOCKED: {kind} package(s) {', '.join(missing)} not in docker-ros.lock: "
            "the repository changed since the lock; run `inv lock`"
        )


def apt_pins(packages: Sequence[str], locked: Mapping[str, str]) -> List[str]:
    """`name=version` for the packages and everything the lock recorded apt pulling in with
    them, so that dependencies are held at their locked versions as well."""
    require_locked("apt", [apt_name(p) for p in packages], locked)
    return [f"{name}={version}" for name, version in sorted(locked.items())]


# where a locked build's prepare holds apt to the lock's versions (runtime/prepare.py; removed
# again before the layer ends)
LOCK_PREFERENCES = Path("/etc/apt/preferences.d/docker-ros-lock")


def installed_records(text: str) -> Dict[str, Dict[str, str]]:
    """name -> fields (Version, Depends, Provides...) of every installed package in a dpkg
    status file."""
    installed: Dict[str, Dict[str, str]] = {}
    for paragraph in text.split("\n\n"):
        fields = {key: value.strip() for key, _, value in
                  (line.partition(":") for line in paragraph.splitlines()
                   if ":" in line and not line[:1].isspace())}
        if fields.get("Status", "").endswith(" installed") and "Package" in fields:
            installed[fields["Package"]] = fields
    return installed


def parse_dpkg_status(text: str) -> Dict[str, str]:
    """name -> version of every installed package in a dpkg status file."""
    return {name: fields.get("Version", "") for name, fields in installed_records(text).items()}


def relation_names(field: str) -> List[List[str]]:
    """A Depends-style field's package names: one list of alternatives per relation (version
    constraints and architecture qualifiers left out)."""
    return [[re.split(r"[\s(:]", alternative.strip(), maxsplit=1)[0]
             for alternative in relation.split("|")]
            for relation in field.split(",") if relation.strip()]


def installed_closure(packages: Sequence[str], text: str) -> Dict[str, str]:
    """name -> installed version of the packages and of what they depend on (Depends and
    Pre-Depends, recursively) in a dpkg status file: of alternatives and virtual packages,
    the installed one that satisfies them. Names not installed are left out."""
    records = installed_records(text)
    providers: Dict[str, str] = {}
    for name, fields in sorted(records.items()):
        for (provided, *_) in relation_names(fields.get("Provides", "")):
            providers.setdefault(provided, name)
    found: Dict[str, str] = {}
    queue = [apt_name(package) for package in packages]
    while queue:
        name = queue.pop()
        name = name if name in records else providers.get(name, "")
        if not name or name in found:
            continue
        fields = records[name]
        found[name] = fields.get("Version", "")
        for field in ("Pre-Depends", "Depends"):
            for alternatives in relation_names(fields.get(field, "")):
                chosen = [a for a in alternatives if a in records or a in providers]
                queue.extend(chosen[:1])
    return dict(sorted(found.items()))


def read_dpkg_status(path: Path = DPKG_STATUS) -> Dict[str, str]:
    """The installed packages of a dpkg status file; none when there is no file (no dpkg)."""
    return parse_dpkg_status(path.read_text(errors="replace")) if path.is_file() else {}


def installed_over(before: Mapping[str, str], after: Mapping[str, str]) -> Dict[str, str]:
    """name -> version of each package installed, or at another version, since `before`."""
    return {name: version for name, version in sorted(after.items())
            if before.get(name) != version}


def lean_entry(entry: Mapping[str, Any], lean: Sequence[str], status_text: str
               ) -> Dict[str, Any]:
    """A locked run entry for ENABLE_LEAN_RUN_IMAGE (made in the lean-resolve stage, the locked
    dev image's state, status_text its dpkg status): rosdep's exec apt set is the lean one,
    and apt installs it and the debs with all they depend on at the versions the dev image
    holds, which are the lock's."""
    inputs = {**(entry.get("inputs") or {}), "rosdep_apt_exec": sorted(lean)}
    wanted = [*lean, *(inputs.get("debs") or [])]
    return {**entry, "inputs": inputs, "apt": installed_closure(wanted, status_text)}


def lock_lean(path: Path, lean: Sequence[str]) -> None:
    """Rewrite the run entry of this platform in the resolution's copy of the lock (path) for
    the lean run image (lean_entry)."""
    lock = load_lock(path)
    entry = locked_target(lock, "run", host_platform())
    lock["targets"][target_key("run", host_platform())] = lean_entry(
        entry, lean, DPKG_STATUS.read_text())
    path.write_text(dump_lock(lock))


PREFERENCES_HEADER = "# docker-ros.lock, what prepare installs at its locked version\n"


def apt_preferences(pins: Mapping[str, str]) -> str:
    """An apt preferences file that holds each package at its locked version, whatever pulls
    it in (priority 1001: also when the sources offer a newer one, or it is installed newer).
    Never empty (a first comment line): an empty file is no lock (a mount's leftover stub)."""
    return PREFERENCES_HEADER + "".join(
        f"Package: {name}\nPin: version {version}\nPin-Priority: 1001\n\n"
        for name, version in sorted(pins.items()))


def parse_apt_preferences(text: str) -> Dict[str, str]:
    """name -> version of the version pins of an apt preferences file (apt_preferences)."""
    pins: Dict[str, str] = {}
    for paragraph in text.split("\n\n"):
        fields = dict(line.split(": ", 1) for line in paragraph.splitlines() if ": " in line)
        if "Package" in fields and fields.get("Pin", "").startswith("version "):
            pins[fields["Package"]] = fields["Pin"][len("version "):]
    return pins


def unlocked_installs(pins: Mapping[str, str], before: Mapping[str, str],
                      after: Mapping[str, str]) -> List[str]:
    """What an install held to the lock (`pins`) did otherwise: each package it installed that
    the lock lacks, each locked package not installed at its locked version."""
    problems = [f"{name} {version} (not in docker-ros.lock)"
                for name, version in installed_over(before, after).items() if name not in pins]
    problems += [f"{name}={version} ({'installed ' + after[name] if name in after else 'missing'})"
                 for name, version in sorted(pins.items()) if after.get(name) != version]
    return problems


def pip_constraints(locked: Mapping[str, Mapping[str, str]]) -> Optional[List[str]]:
    """The constraint lines (`name==version`) under which a locked step installs its pip
    requirements as written: every package pip installs for them, dependencies included, at
    its locked version (a requirement satisfied where the lock was written, so not in its
    report, is left to the locked system). None when the lock recorded no pip version at all
    (no report): the checked requirements are installed unconstrained."""
    lines = [f"{name}=={entry['version']}" for name, entry in sorted(locked.items())
             if entry.get("version")]
    return lines or None


def pin_repos(
    repos: Mapping[str, Mapping[str, str]], locked: Mapping[str, Mapping[str, str]], prefix: str
) -> Dict[str, Dict[str, str]]:
    """A .repos file's repositories with each version replaced by its locked commit
    (`prefix`: where the file's entries land, e.g. `src/upstream`)."""
    pinned: Dict[str, Dict[str, str]] = {}
    for name, repo in repos.items():
        path = f"{prefix}/{name}" if prefix else name
        entry = locked.get(path)
        if entry is None or entry.get("url") != repo.get("url"):
            raise LockError(
                f"LOCKED: repository {path} ({repo.get('url')}) differs from docker-ros.lock: "
                "run `inv lock`"
            )
        pinned[name] = {**repo, "version": entry["commit"]}
    return pinned


def dump_repos(repos: Mapping[str, Mapping[str, str]]) -> str:
    """A .repos file (YAML that vcstool reads) of the given repositories."""
    lines = ["repositories:"]
    for name, repo in sorted(repos.items()):
        lines.append(f"  {json.dumps(name)}:")
        for key in ("type", "url", "version"):
            if repo.get(key):
                lines.append(f"    {key}: {json.dumps(repo[key])}")
    return "\n".join(lines) + "\n"


def stale_inputs(
    recorded: Mapping[str, Any], current: Mapping[str, Any], kinds: Sequence[str] = ()
) -> List[str]:
    """What changed between the lock's inputs and the repository's now: one line each."""
    changes: List[str] = []
    for kind in kinds or sorted({*recorded, *current}):  # (default: every kind either has)
        old, new = recorded.get(kind), current.get(kind)
        if old == new:
            continue
        if isinstance(old, list) and isinstance(new, list):
            changes += [f"{kind}: added {item}" for item in sorted(set(new) - set(old))]
            changes += [f"{kind}: removed {item}" for item in sorted(set(old) - set(new))]
        elif isinstance(old, dict) and isinstance(new, dict):
            for name in sorted(set(old) | set(new)):
                if old.get(name) != new.get(name):
                    changes.append(f"{kind}: {name} {old.get(name)} -> {new.get(name)}")
        else:
            changes.append(f"{kind}: {old} -> {new}")
    return changes


def check_inputs(entry: Mapping[str, Any], current: Mapping[str, Any]) -> None:
    """Stop a locked build whose repository no longer matches the lock, naming each change."""
    changes = stale_inputs(entry.get("inputs") or {}, current)
    if changes:
        raise LockError(
            "LOCKED: the repository no longer matches docker-ros.lock ("
            + "; ".join(changes)
            + "): run `inv lock`"
        )


def file_digest(path: Optional[Path]) -> Optional[str]:
    """sha256 of a rules file (None when there is none)."""
    if path is None or not path.is_file():
        return None
    return "sha256:" + hashlib.sha256(path.read_bytes()).hexdigest()


def base_image_ref(ref: str, record: Mapping[str, Any]) -> str:
    """BASE_IMAGE by digest: `name@sha256:...` for a registry image; a local image (never
    pushed) by its image ID, which the local engine resolves."""
    digest = str(record.get("digest") or "")
    if not digest:
        raise LockError(f"LOCKED: docker-ros.lock has no digest for BASE_IMAGE {ref}: "
                        "run `inv lock`")
    if record.get("local"):
        return local_base_tag(ref, digest)
    return f"{image_repository(ref)}@{digest}"


def local_base_tag(ref: str, image_id: str) -> str:
    """The tag a locked build gives a local base image (never pushed, no registry digest):
    BuildKit's FROM takes no image ID, so the ID gets a tag of its own (lock.tag_local_base)."""
    return f"{image_repository(ref)}:docker-ros-lock-{image_id.split(':')[-1][:16]}"


def image_repository(ref: str) -> str:
    """An image reference without tag or digest (a registry's port stays)."""
    name = ref.split("@", 1)[0]
    last = name.rsplit("/", 1)[-1]
    if ":" in last:
        name = name[: len(name) - len(last)] + last.split(":", 1)[0]
    return name


def is_locked(settings: Settings, environ: Optional[Mapping[str, str]] = None) -> bool:
    """LOCKED on the host; DOCKER_ROS_LOCKED in an image build's stages."""
    env = os.environ if environ is None else environ
    return bool(getattr(settings, "locked", False)) or env.get(LOCKED_ENV) == "true"


def lock_file(ws: Workspace) -> Path:
    """The repository's docker-ros.lock, or the copy that travels with the resolution
    (.docker-ros/docker-ros.lock: the image's install stages have no repository)."""
    own = ws.target / LOCK_FILE
    return own if own.is_file() or not (ws.state / LOCK_FILE).is_file() else ws.state / LOCK_FILE


def default_target(environ: Optional[Mapping[str, str]] = None) -> str:
    """The entry a step honours: DOCKER_ROS_LOCK_TARGET (the image's install stages set dev or
    run); else dev in an image (its imports and inputs are the run image's too), host on
    the host."""
    env = os.environ if environ is None else environ
    return env.get(TARGET_ENV) or ("dev" if env.get("DOCKER_ROS") else HOST_TARGET)


def active_entry(ws: Workspace, settings: Settings, step: str) -> Optional[Dict[str, Any]]:
    """The lock entry a step honours: None unless locked (is_locked); else the entry of
    default_target and this platform."""
    if not is_locked(settings):
        return None
    try:
        return locked_target(load_lock(lock_file(ws)), default_target(), host_platform())
    except LockError as exc:
        raise StepError(step, str(exc)) from None


def locked_arguments(
    ws: Workspace, settings: Settings, *, step: str, kind: str, inputs: Sequence[str],
    key: str = "", dry_run: bool = False,
) -> Optional[List[str]]:
    """After checking `inputs` against the lock's: apt, what a locked step installs instead
    (`name=version` of the whole locked closure); pip, the constraint lines it installs its
    requirements under (pip_constraints). None when not locked: the step is unchanged."""
    entry = active_entry(ws, settings, step)
    if entry is None:
        return None
    key = key or step
    recorded = sorted((entry.get("inputs") or {}).get(key) or [])
    try:
        changes = stale_inputs({key: recorded}, {key: sorted(inputs)}, kinds=(key,))
        if changes:
            raise LockError(
                f"LOCKED: the repository no longer matches docker-ros.lock ({'; '.join(changes)})"
                ": run `inv lock`"
            )
        if kind == "apt":
            pins = apt_pins(inputs, entry.get("apt") or {})
            if not dry_run:  # (a dry run neither updates apt's lists nor asks them)
                check_available(pins, step=step)
            return pins
        constraints = pip_constraints(entry.get("pip") or {})
        if constraints and not dry_run:
            check_pip_available(inputs, constraints, step=step)
        return constraints
    except LockError as exc:
        raise StepError(step, str(exc)) from None


def pinned_repos_file(
    ws: Workspace, step: str, repos_file: Path, repos: Mapping[str, Mapping[str, str]],
    locked: Mapping[str, Mapping[str, str]],
) -> Path:
    """A copy of `repos_file` in the workspace's state folder with every version replaced by its
    locked commit (entries land in src/upstream, recorded as `upstream/<name>`)."""
    try:
        text = dump_repos(pin_repos(repos, locked, "upstream"))
    except LockError as exc:
        raise StepError(step, f"{ws.relative(repos_file)}: {exc}") from None
    pinned = ws.state / f"locked-{hashlib.sha256(str(repos_file).encode()).hexdigest()[:12]}.repos"
    pinned.parent.mkdir(parents=True, exist_ok=True)
    pinned.write_text(text)
    return pinned


def locked_rosdep_plan(
    ws: Workspace, settings: Settings, plan: Mapping[str, Any], dependency_types: str, step: str,
    dry_run: bool = False,
) -> Mapping[str, Any]:
    """rosdep's plan with the chosen set's apt and pip packages replaced by the lock's pins
    (inputs `rosdep_apt_<types>` / `rosdep_pip_<types>`); the plan itself unless LOCKED."""
    chosen = plan.get(dependency_types)
    if not isinstance(chosen, dict):
        return plan
    if not is_locked(settings):
        return plan
    pinned = {
        installer: locked_arguments(ws, settings, step=step, kind=installer,
                                    inputs=list(chosen.get(installer) or []),
                                    key=f"rosdep_{installer}_{dependency_types}",
                                    dry_run=dry_run)
        for installer in ("apt", "pip")
    }
    apt, pip = pinned["apt"], pinned["pip"]
    pinned = {"apt": list(chosen.get("apt") or []) if apt is None else apt,
              "pip": constrained(ws, list(chosen.get("pip") or []), pip, dry_run=dry_run)}
    return {**plan, dependency_types: {**chosen, **pinned}}


def constrained(ws: Workspace, packages: List[str], constraints: Optional[List[str]], *,
                dry_run: bool) -> List[str]:
    """pip argv items: the packages under `-c` of a file of the constraint lines (in the state
    folder); the packages alone without constraints or packages."""
    if not constraints or not packages:
        return packages
    path = ws.state / "locked-pip-constraints.txt"
    if not dry_run:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("\n".join(constraints) + "\n")
    return ["-c", str(path), *packages]


def apt_closure(packages: Sequence[str], *, step: str = "lock", update: bool = False
                ) -> Dict[str, str]:
    """name -> version of the packages and every package apt would install with them, where
    this runs (`--reinstall`: named packages already installed are listed too); `update`:
    fresh package lists first (an image's lists come from a cache mount that may be old)."""
    if not packages:
        return {}
    if update:
        probe(apt_get(["update"]), step=step, env=apt_env())
    argv = ["apt-get", "install", "-s", "--reinstall", "--no-install-recommends", *packages]
    proc = probe(argv, step=step, env={**os.environ, "LC_ALL": "C"})
    if proc.returncode != 0:
        raise StepError(step, f"apt cannot resolve {' '.join(packages)}: "
                        f"{proc.stderr.strip().splitlines()[-1:] or proc.returncode}")
    return parse_apt_simulation(proc.stdout.splitlines())


# apt's words for a locked version it cannot find
APT_MISSING_VERSION = re.compile(r"Version '([^']+)' for '([^']+)' was not found")


def apt_sources(root: Path = Path("/etc/apt")) -> List[str]:
    """The URIs and suites apt installs from (one-line and deb822 sources)."""
    found: List[str] = []
    for path in [root / "sources.list", *sorted((root / "sources.list.d").glob("*"))]:
        if not path.is_file():
            continue
        text = path.read_text(errors="replace")
        found += [" ".join(line.split()[1:3]) for line in text.splitlines()
                  if line.startswith("deb ")]
        uris = re.findall(r"^URIs:\s*(.+)$", text, flags=re.MULTILINE)
        suites = re.findall(r"^Suites:\s*(.+)$", text, flags=re.MULTILINE)
        found += [f"{u.strip()} {s.strip()}" for u, s in zip(uris, suites)]
    return found


def missing_versions(apt_output: str) -> List[str]:
    """`name=version` of each locked version apt says it cannot find."""
    return [f"{name}={version}" for version, name in APT_MISSING_VERSION.findall(apt_output)]


def check_available(pins: Sequence[str], *, step: str) -> None:
    """Stop before installing when apt's sources no longer hold a locked version, naming each
    package, its version and the sources (after fresh lists: old ones may hide it)."""
    if not pins:
        return
    argv = ["apt-get", "install", "-s", "--no-install-recommends", *pins]
    for attempt in range(2):
        if attempt or not apt_lists_present():
            probe(apt_get(["update"]), step=step, env=apt_env())
        proc = probe(argv, step=step, env={**os.environ, "LC_ALL": "C"})
        missing = missing_versions(proc.stderr + proc.stdout)
        if not missing:
            return
    raise StepError(step, f"LOCKED: {', '.join(missing)} no longer available from apt's "
                    f"sources ({'; '.join(apt_sources()) or 'none configured'}): the archive "
                    "dropped the locked version; run `inv lock` to lock what it has now")


def repository_commits(root: Path) -> Dict[str, Dict[str, str]]:
    """path (relative to `root`'s parent, e.g. `upstream/foo`) -> {url, commit} of every git
    checkout under `root`, nested ones (from nested .repos files) included."""
    commits: Dict[str, Dict[str, str]] = {}
    if not root.is_dir():
        return commits
    for marker in sorted(root.rglob(".git")):
        checkout = marker.parent
        commits[f"{root.name}/{checkout.relative_to(root).as_posix()}"] = {
            "url": _git(checkout, "config", "--get", "remote.origin.url"),
            "commit": _git(checkout, "rev-parse", "HEAD"),
        }
    return commits


def _git(checkout: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(checkout), *args], capture_output=True,
                          text=True).stdout.strip()


def pip_dry_run(requirements: Sequence[str], constraints: Sequence[str], options: Sequence[str],
                *, step: str) -> "subprocess.CompletedProcess[str]":
    """`pip install --dry-run -r` of the requirement lines under the constraint lines, with
    the flags the pip step would use where this runs (PEP 668, --user)."""
    import tempfile

    from docker_ros.in_image.runtime.process import is_root
    from docker_ros.in_image.steps.pip import (
        install_flags,
        probe_python,
        python_command,
        requirement_files,
    )

    python = python_command()
    flags = install_flags(probe_python(python, step=step), root=is_root())
    with tempfile.TemporaryDirectory(prefix="docker-ros-lock-pip-") as tmp:
        path = requirement_files(Path(tmp), requirements, constraints)
        return probe([python, "-m", "pip", "install", "--dry-run", *options, *flags,
                      "-r", str(path)], step=step)


def pip_report(requirements: Sequence[str], constraints: Sequence[str] = (), *,
               step: str = "lock") -> Dict[str, Dict[str, str]]:
    """name -> {version, sha256} of what `pip install -r` of the requirement lines (under the
    constraint lines) would install where this runs (`--dry-run --report`, pip >= 22.2)."""
    if not requirements:
        return {}
    proc = pip_dry_run(requirements, constraints, ["--quiet", "--report", "-"], step=step)
    try:
        report = json.loads(proc.stdout)
    except ValueError:
        raise StepError(step, f"pip cannot resolve {', '.join(requirements)} (exit code "
                        f"{proc.returncode}): {proc.stderr.strip().splitlines()[-1:]}") from None
    return parse_pip_report(report)


# pip's words for a requirement no version of which it can install
PIP_NO_MATCH = re.compile(r"No matching distribution found for ([A-Za-z0-9][A-Za-z0-9._-]*)")
PIP_SOURCE = re.compile(r"(?:--index-url|--extra-index-url|--find-links|-i|-f)[ =]+(\S+)")


def pip_sources(requirements: Sequence[str], environ: Optional[Mapping[str, str]] = None
                ) -> List[str]:
    """Where pip looks: the requirement files' index and find-links options, pip's environment
    variables, else PyPI."""
    env = os.environ if environ is None else environ
    found = [m for line in requirements if line.startswith("-") for m in PIP_SOURCE.findall(line)]
    found += [env[v] for v in ("PIP_INDEX_URL", "PIP_EXTRA_INDEX_URL", "PIP_FIND_LINKS")
              if env.get(v)]
    if not any("--index-url" in line or line.startswith("-i") or "--no-index" in line
               for line in requirements) and not env.get("PIP_INDEX_URL"):
        found.append("https://pypi.org/simple (pip's default index)")
    return found


# with constraints pip says ResolutionImpossible, naming the constraints it could not meet
PIP_CONSTRAINT = re.compile(r"The user requested \(constraint\) ([A-Za-z0-9][A-Za-z0-9._-]*)==")


def unavailable_pins(pip_stderr: str, constraints: Sequence[str]) -> List[str]:
    """The locked `name==version` lines pip could not meet: no distribution found for the
    requirement, or (under the constraints) no version matching the locked one."""
    pinned = {pip_name(line): line for line in constraints}
    names = PIP_NO_MATCH.findall(pip_stderr)
    if "ResolutionImpossible" in pip_stderr:
        names += PIP_CONSTRAINT.findall(pip_stderr)
    return sorted({pinned[pip_name(n)] for n in names if pip_name(n) in pinned})


def check_pip_available(requirements: Sequence[str], constraints: Sequence[str], *,
                        step: str) -> None:
    """Stop before installing when pip's sources no longer hold a locked version, naming each
    package, its version and the sources (another failure is left to the install to report)."""
    if not requirements or not constraints:
        return
    proc = pip_dry_run(requirements, constraints, [], step=step)
    missing = unavailable_pins(proc.stdout + proc.stderr, constraints) if proc.returncode else []
    if missing:
        raise StepError(step, f"LOCKED: {', '.join(missing)} no longer available from pip's "
                        f"sources ({'; '.join(pip_sources(requirements))}): run `inv lock` to "
                        "lock what they have now")


def recorded_inputs(ws: Workspace, rules_file: Optional[Path]) -> Dict[str, Any]:
    """The resolution the collect phases wrote (debs.json, pip.json, rosdep.json) and the rules
    file's digest: what a locked build compares with the lock."""
    inputs: Dict[str, Any] = {
        "debs": sorted(_state(ws, "debs.json").get("packages") or []),
        "pip": sorted(_state(ws, "pip.json").get("requirements") or []),
        "pip_constraints": sorted(_state(ws, "pip.json").get("constraints") or []),
        "rosdep_rules": file_digest(rules_file),
    }
    for types, chosen in sorted(_state(ws, "rosdep.json").items()):
        if isinstance(chosen, dict):
            for installer in ("apt", "pip"):
                inputs[f"rosdep_{installer}_{types}"] = sorted(chosen.get(installer) or [])
    return inputs


def _state(ws: Workspace, name: str) -> Dict[str, Any]:
    data = ws.read_state(name)
    return dict(data) if isinstance(data, dict) else {}


def resolved_entry(ws: Workspace, settings: Settings, dependency_types: str, upstream: Path,
                   bare: Path) -> Dict[str, Any]:
    """One image target's lock entry, where its installs run (the resolved-dev or resolved-run
    state, resolution in .docker-ros): the collect phases' inputs, the imported commits (the
    source stage's src/upstream at `upstream`), what prepare installed over the bare base image
    (its root at `bare`), what apt and pip would install now (fresh apt lists). The base
    image's digest is the host's to add."""
    inputs = recorded_inputs(ws, rules_path(ws, settings))
    chosen = _state(ws, "rosdep.json").get(dependency_types) or {}
    apt = sorted({*inputs["debs"], *(chosen.get("apt") or [])})
    pip = [*inputs["pip"], *(chosen.get("pip") or [])]
    constraints = _state(ws, "pip.json").get("constraints") or []
    prepare = installed_over(read_dpkg_status(bare / "var/lib/dpkg/status"), read_dpkg_status())
    closure = apt_closure(apt, update=True)
    if pip:
        install_python_debs(closure)
    return {"inputs": inputs, "repos": repository_commits(upstream), "prepare": prepare,
            "apt": closure, "pip": pip_report(pip, constraints)}


def python_debs(closure: Mapping[str, str]) -> List[str]:
    """`name=version` of the Python packages (python3-*, python-*) of an apt closure."""
    return [f"{name}={version}" for name, version in sorted(closure.items())
            if name.startswith(("python3-", "python-"))]


def install_python_debs(closure: Mapping[str, str]) -> None:
    """Install the closure's Python packages where the lock stage resolves pip, as the image's
    apt installs come before its pip step: a requirement a Debian package satisfies is then
    none of pip's, in the lock as in an unlocked build (else the lock would hold the index's
    newest version, and a locked build would install it over Debian's)."""
    debs = python_debs(closure)
    if debs:
        apt_install(debs, step="lock", dry_run=False,
                    what="installing the apt closure's Python packages (for pip's dry run)")


def rules_path(ws: Workspace, settings: Settings) -> Optional[Path]:
    name = getattr(settings, "rosdep_rules_file", None)
    return ws.target / name if name else None


def check_resolution(ws: Workspace, settings: Settings) -> None:
    """In a locked build's resolve stage, after the collect phases: stop when what they
    resolved differs from the lock's inputs (before anything is installed, naming each
    change); then put the lock next to the resolution, where the install stages read it."""
    entry = active_entry(ws, settings, "lock")
    if entry is None:
        return
    try:
        check_inputs(entry, recorded_inputs(ws, rules_path(ws, settings)))
    except LockError as exc:
        raise StepError("lock", str(exc)) from None
    ws.state.mkdir(parents=True, exist_ok=True)
    (ws.state / LOCK_FILE).write_text(lock_file(ws).read_text())


def main(argv: List[str]) -> int:
    """`python3 -m docker_ros.in_image.runtime.lock check` (resolve stage) or `... resolve OUT
    TYPES UPSTREAM BARE` (the lock stages: OUT/<target>.json)."""
    from docker_ros.in_image.runtime.workspace import entry_parser, image_main

    if argv[:1] not in (["check"], ["resolve"]):  # --help, or no command: say which there are
        parser = entry_parser("runtime.lock", "LOCKED builds: check a resolution against "
                              "docker-ros.lock, or write an image's lock entry.")
        parser.add_argument("command", choices=["check", "resolve"],
                            help="check | resolve OUT DEPENDENCY_TYPES UPSTREAM BARE")
        parser.parse_args(argv)
        parser.error("the command comes first: check ... or resolve ...")
    if argv[:1] == ["check"]:
        return image_main(argv[1:], module="runtime.lock check", step="lock",
                          description="LOCKED: stop when the resolution differs from "
                          "docker-ros.lock.", arguments=[],
                          action=lambda ws, settings, _: check_resolution(ws, settings))

    def write(ws: Workspace, settings: Settings, args: List[str]) -> None:
        out, types, upstream, bare = Path(args[0]), args[1], Path(args[2]), Path(args[3])
        entry = resolved_entry(ws, settings, types, upstream, bare)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(dump_lock(entry))

    return image_main(argv[1:], module="runtime.lock resolve", step="lock",
                      description="Write the lock entry of one image (what prepare installed "
                      "over the base image at BARE, apt and pip closure, imported commits) to "
                      "OUT.", arguments=["OUT", "DEPENDENCY_TYPES", "UPSTREAM", "BARE"],
                      action=write)


if __name__ == "__main__":
    import sys

    sys.exit(main(sys.argv[1:]))
