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
         "pip": {"name": {"version": "1.2", "sha256": "..."}}}}}
`inputs` is what the collect phase resolved when the lock was written: a build whose inputs
differ is stale and stops before installing anything."""

import hashlib
import json
import os
import re
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence

from docker_ros.runtime.process import probe
from docker_ros.runtime.workspace import StepError, Workspace
from docker_ros.settings import host_platform

LOCK_FILE = "docker-ros.lock"
FORMAT = 1
INPUT_KINDS = ("debs", "pip", "rosdep_keys", "repos", "rosdep_rules")
TARGET_ENV = "DOCKER_ROS_LOCK_TARGET"
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
        raise LockError(f"LOCKED: docker-ros.lock has no entry for {key}: run `inv lock`")
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


def pip_pins(requirements: Sequence[str], locked: Mapping[str, Mapping[str, str]]) -> List[str]:
    """`name==version` for every locked pip package (options lines are kept out)."""
    wanted = [r for r in requirements if not r.startswith("-")]
    require_locked("pip", [pip_name(r) for r in wanted], locked)
    return [f"{name}=={entry['version']}" for name, entry in sorted(locked.items())]


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
    recorded: Mapping[str, Any], current: Mapping[str, Any], kinds: Sequence[str] = INPUT_KINDS
) -> List[str]:
    """What changed between the lock's inputs and the repository's now: one line each."""
    changes: List[str] = []
    for kind in kinds:
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
        return digest
    return f"{image_repository(ref)}@{digest}"


def image_repository(ref: str) -> str:
    """An image reference without tag or digest (a registry's port stays)."""
    name = ref.split("@", 1)[0]
    last = name.rsplit("/", 1)[-1]
    if ":" in last:
        name = name[: len(name) - len(last)] + last.split(":", 1)[0]
    return name


def active_entry(ws: Workspace, settings: Any, step: str) -> Optional[Dict[str, Any]]:
    """The lock entry a step honours: None unless LOCKED; the repository's docker-ros.lock,
    target DOCKER_ROS_LOCK_TARGET (dev: its packages include the run image's), this platform."""
    if not getattr(settings, "locked", False):
        return None
    target = os.environ.get(TARGET_ENV) or "dev"
    try:
        return locked_target(load_lock(ws.target / LOCK_FILE), target, host_platform())
    except LockError as exc:
        raise StepError(step, str(exc)) from None


def locked_arguments(
    ws: Workspace, settings: Any, *, step: str, kind: str, inputs: Sequence[str], key: str = ""
) -> Optional[List[str]]:
    """What a locked step installs instead of `inputs` (apt: `name=version` of the whole
    locked closure, pip: `name==version`), after checking `inputs` against the lock's; None
    when not locked (the step installs its inputs as before)."""
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
            return apt_pins(inputs, entry.get("apt") or {})
        return pip_pins(inputs, entry.get("pip") or {})
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
    ws: Workspace, settings: Any, plan: Mapping[str, Any], dependency_types: str, step: str
) -> Mapping[str, Any]:
    """rosdep's plan with the chosen set's apt and pip packages replaced by the lock's pins
    (inputs `rosdep_apt_<types>` / `rosdep_pip_<types>`); the plan itself unless LOCKED."""
    chosen = plan.get(dependency_types)
    if not isinstance(chosen, dict) or not getattr(settings, "locked", False):
        return plan
    pinned = {
        installer: locked_arguments(ws, settings, step=step, kind=installer,
                                    inputs=list(chosen.get(installer) or []),
                                    key=f"rosdep_{installer}_{dependency_types}") or []
        for installer in ("apt", "pip")
    }
    return {**plan, dependency_types: {**chosen, **pinned}}


def apt_closure(packages: Sequence[str], *, step: str = "lock") -> Dict[str, str]:
    """name -> version of the packages and every package apt would install with them, where
    this runs (`--reinstall`: named packages already installed are listed too)."""
    if not packages:
        return {}
    argv = ["apt-get", "install", "-s", "--reinstall", "--no-install-recommends", *packages]
    proc = probe(argv, step=step, env={**os.environ, "LC_ALL": "C"})
    if proc.returncode != 0:
        raise StepError(step, f"apt cannot resolve {' '.join(packages)}: "
                        f"{proc.stderr.strip().splitlines()[-1:] or proc.returncode}")
    return parse_apt_simulation(proc.stdout.splitlines())


def recorded_inputs(ws: Workspace, rules_file: Optional[Path]) -> Dict[str, Any]:
    """The resolution the collect phases wrote (debs.json, pip.json, rosdep.json) and the rules
    file's digest: what a locked build compares with the lock."""
    inputs: Dict[str, Any] = {
        "debs": sorted(_state(ws, "debs.json").get("packages") or []),
        "pip": sorted(_state(ws, "pip.json").get("requirements") or []),
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
