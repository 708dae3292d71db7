"""Host side of docker-ros.lock: the base image's digest and the imported repositories' commits.
What images run (parsing apt's and pip's resolution, pins, stale inputs) is runtime/lock.py."""

import subprocess
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional

from docker_ros import engine
from docker_ros.runtime.lock import (
    FORMAT,
    LOCK_FILE,
    LockError,
    apt_closure,
    base_image_ref,
    dump_lock,
    image_repository,
    load_lock,
    locked_target,
    recorded_inputs,
    stale_inputs,
    target_key,
)
from docker_ros.runtime.workspace import Workspace
from docker_ros.settings import Settings, host_platform


def base_image_record(ref: str, attrs: Optional[Mapping[str, Any]]) -> Dict[str, Any]:
    """The base image's digest from its inspect data: the registry digest of `ref`'s repository
    when it was pulled or pushed, else the local image ID, marked local."""
    if attrs is None:
        raise LockError(f"lock: BASE_IMAGE {ref} not found locally or in its registry")
    repository = image_repository(ref)
    for repo_digest in attrs.get("RepoDigests") or []:
        name, _, digest = str(repo_digest).partition("@")
        if name == repository:
            return {"ref": ref, "digest": digest, "local": False}
    return {"ref": ref, "digest": str(attrs["Id"]), "local": True}


def base_image(ref: str) -> Dict[str, Any]:
    return base_image_record(ref, engine.inspect_image(ref))


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(
        ["git", "-C", str(repo), *args], check=True, capture_output=True, text=True
    ).stdout.strip()


def repository_commits(root: Path) -> Dict[str, Dict[str, str]]:
    """path (relative to `root`'s parent, e.g. `upstream/foo`) -> {url, commit} of every git
    checkout under `root`, nested ones (from nested .repos files) included."""
    commits: Dict[str, Dict[str, str]] = {}
    for marker in sorted(root.rglob(".git")):
        checkout = marker.parent
        url = subprocess.run(
            ["git", "-C", str(checkout), "config", "--get", "remote.origin.url"],
            capture_output=True, text=True,
        ).stdout.strip()
        commits[checkout.relative_to(root.parent).as_posix()] = {
            "url": url, "commit": _git(checkout, "rev-parse", "HEAD"),
        }
    return commits


def lock_path(settings: Settings) -> Path:
    return Path(settings.build_context) / LOCK_FILE


def locked_build_args(settings: Settings, *, target: str, platform: str) -> Dict[str, str]:
    """Build arguments a locked build overrides (none unless LOCKED): BASE_IMAGE by digest."""
    if not settings.locked:
        return {}
    entry = locked_target(load_lock(lock_path(settings)), target, platform)
    record = entry.get("base_image") or {}
    if record.get("ref") != settings.base_image:
        raise LockError(
            f"LOCKED: BASE_IMAGE is {settings.base_image}, docker-ros.lock has {record.get('ref')}:"
            " run `inv lock`"
        )
    return {"BASE_IMAGE": base_image_ref(settings.base_image or "", record)}


def host_entry(settings: Settings) -> Dict[str, Any]:
    """This machine's lock entry (target dev): the repository imported and resolved afresh in a
    throw-away workspace (clone, then the collect phases), then what apt would install for it."""
    from docker_ros.steps import run_step

    unlocked = replace(settings, locked=False)  # resolve afresh, whatever the lock says
    with tempfile.TemporaryDirectory(prefix="docker-ros-lock-") as tmp:
        ws = Workspace(tmp)
        ws.src.mkdir()
        ws.target.symlink_to(Path(settings.build_context).resolve(), target_is_directory=True)
        run_step("clone", ws, unlocked, phase="all", dry_run=False)
        for step in ("rosdep", "debs", "pip"):
            run_step(step, ws, unlocked, phase="collect", dry_run=False)
        return _entry(settings, ws)


def _entry(settings: Settings, ws: Workspace) -> Dict[str, Any]:
    inputs = recorded_inputs(ws, Path(settings.build_context) / settings.rosdep_rules_file)
    apt = sorted({*inputs["debs"], *inputs.get("rosdep_apt_all", [])})
    entry: Dict[str, Any] = {"inputs": inputs, "repos": repository_commits(ws.upstream),
                             "apt": apt_closure(apt), "pip": {}}
    if settings.base_image and engine.inspect_image(settings.base_image) is not None:
        entry["base_image"] = base_image(settings.base_image)
    return entry


def lock_host(settings: Settings, *, check: bool) -> List[str]:
    """Write (or with `check`, compare) docker-ros.lock's entry for this machine; the
    differences from the file's entry, one line each."""
    path, key = lock_path(settings), target_key("dev", host_platform())
    current: Dict[str, Any] = (
        load_lock(path) if path.is_file() else {"format": FORMAT, "targets": {}}
    )
    targets: Dict[str, Any] = dict(current.get("targets") or {})
    old = dict(targets.get(key) or {})
    new = host_entry(settings)
    changes = stale_inputs(old.get("inputs") or {}, new["inputs"])
    changes += [f"repos: {p} {old.get('repos', {}).get(p)} -> {new['repos'].get(p)}"
                for p in sorted({*old.get("repos", {}), *new["repos"]})
                if old.get("repos", {}).get(p) != new["repos"].get(p)]
    if not check:
        targets[key] = new
        path.write_text(dump_lock({**current, "targets": targets}))
    return changes
