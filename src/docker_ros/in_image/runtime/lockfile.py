"""docker-ros.lock's format and entries: reading and writing it, which entry a step honours,
what no longer matches it. Standard library only, Python 3.8+ (runs inside images and on the
host).

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
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence

from docker_ros.core.errors import DockerRosError
from docker_ros.core.loading import host_platform
from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.workspace import StepError, Workspace

LOCK_FILE = "docker-ros.lock"
FORMAT = 1
TARGET_ENV = "DOCKER_ROS_LOCK_TARGET"
# set (to true) by the tool in the image stages of a locked build (LOCKED itself is no ARG)
LOCKED_ENV = "DOCKER_ROS_LOCKED"
HOST_TARGET = "host"  # the entry host steps honour (`inv lock --host`)


class LockError(DockerRosError):
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


def require_locked(kind: str, names: Sequence[str], locked: Mapping[str, Any]) -> None:
    missing = sorted(name for name in names if name not in locked)
    if missing:
        raise LockError(
            f"LOCKED: {kind} package(s) {', '.join(missing)} not in docker-ros.lock: "
            "the repository changed since the lock; run `inv lock`"
        )


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
