"""Host side of docker-ros.lock: the base image's digest and the imported repositories' commits.
What images run (parsing apt's and pip's resolution, pins, stale inputs) is runtime/lock.py."""

import subprocess
from pathlib import Path
from typing import Any, Dict, Mapping, Optional

from docker_ros import engine
from docker_ros.runtime.lock import (
    LOCK_FILE,
    LockError,
    base_image_ref,
    image_repository,
    load_lock,
    locked_target,
)
from docker_ros.settings import Settings


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
