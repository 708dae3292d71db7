"""Host side of docker-ros.lock: `inv lock` resolves each target and platform in image stages
(lock-results, exported to the host: no image is built) and adds the base image's digest;
`--host` resolves this machine's entry for the host steps. What images run (apt's and pip's
resolution, pins, stale inputs) is runtime/lock.py."""

import json
import tempfile
import uuid
from dataclasses import replace
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional

from docker_ros.core.loading import host_platform
from docker_ros.core.settings import Settings
from docker_ros.host import engine
from docker_ros.host.build import build_images
from docker_ros.host.lockpins import IMAGE_TARGETS, lock_path
from docker_ros.host.refs import platform_base
from docker_ros.in_image.runtime.lock import recorded_inputs, repository_commits
from docker_ros.in_image.runtime.lockapt import apt_closure
from docker_ros.in_image.runtime.lockfile import (
    FORMAT,
    HOST_TARGET,
    LockError,
    dump_lock,
    image_repository,
    load_lock,
    stale_inputs,
    target_key,
)
from docker_ros.in_image.runtime.lockpip import pip_report
from docker_ros.in_image.runtime.workspace import Workspace
from docker_ros.in_image.steps import run_step


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


def host_entry(settings: Settings) -> Dict[str, Any]:
    """This machine's lock entry (target host): the repository imported and resolved afresh in a
    throw-away workspace (clone, then the collect phases), then what apt would install for it."""
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
    pip = [*inputs["pip"], *inputs.get("rosdep_pip_all", [])]
    entry: Dict[str, Any] = {"inputs": inputs, "repos": repository_commits(ws.upstream),
                             "apt": apt_closure(apt),
                             "pip": pip_report(pip, pip_plan_constraints(ws))}
    if settings.base_image and engine.inspect_image(settings.base_image) is not None:
        entry["base_image"] = base_image(settings.base_image)
    return entry


def pip_plan_constraints(ws: Workspace) -> List[str]:
    """The constraint lines (nested -c files) the pip step's collect phase read."""
    plan = ws.read_state("pip.json")
    return list(plan.get("constraints") or []) if isinstance(plan, dict) else []


def image_entries(settings: Settings, platform: str, out: Any) -> Dict[str, Dict[str, Any]]:
    """The dev and run entries of one platform, resolved in the image's lock stages (their
    lock-results exported to a folder here: no image is built or tagged), with the base
    image's digest added."""
    unlocked = replace(settings, locked=False)  # resolve afresh, whatever the lock says
    with tempfile.TemporaryDirectory(prefix="docker-ros-lock-") as tmp:
        build_images(unlocked, targets={"lock-results": "docker-ros-lock:unused"},
                     platform=platform, out=out, output=f"type=local,dest={tmp}",
                     extra_build_args={"DOCKER_ROS_LOCK_RUN": uuid.uuid4().hex}, bake=False)
        entries = {target_key(t, platform): json.loads((Path(tmp) / f"{t}.json").read_text())
                   for t in IMAGE_TARGETS}
    # the digest of the image this platform builds from (BASE_IMAGE or its -<arch> image)
    built_from, _ = platform_base(settings, platform)
    record = base_image_record(settings.base_image or "", engine.inspect_image(built_from))
    return {key: {**entry, "base_image": record} for key, entry in entries.items()}


def entry_changes(key: str, old: Mapping[str, Any], new: Mapping[str, Any]) -> List[str]:
    """What differs between two entries of one key, one line each (inputs, commits, the apt
    and pip versions, the base image)."""
    changes = [f"{key}: {line}" for line in stale_inputs(old.get("inputs") or {},
                                                       new.get("inputs") or {})]
    for kind in ("repos", "prepare", "apt", "pip"):
        before, after = old.get(kind) or {}, new.get(kind) or {}
        changes += [f"{key}: {kind} {name} {before.get(name)} -> {after.get(name)}"
                    for name in sorted({*before, *after}) if before.get(name) != after.get(name)]
    if old.get("base_image") != new.get("base_image"):
        changes.append(f"{key}: base_image {(old.get('base_image') or {}).get('digest')} -> "
                       f"{(new.get('base_image') or {}).get('digest')}")
    return changes


def lock(settings: Settings, *, check: bool, host: bool, out: Any) -> List[str]:
    """Write (or with `check`, compare) docker-ros.lock's entries: dev and run of every
    PLATFORM (images), or with `host` this machine's host entry; the differences from the
    file's entries, one line each."""
    path = lock_path(settings)
    if check and not path.is_file():  # (nothing to compare: resolve nothing)
        raise LockError(f"{path} does not exist: `inv lock` writes it (--check compares a "
                        "build's resolution with it)")
    current: Dict[str, Any] = (
        load_lock(path) if path.is_file() else {"format": FORMAT, "targets": {}}
    )
    targets: Dict[str, Any] = dict(current.get("targets") or {})
    if host:
        new = {target_key(HOST_TARGET, host_platform()): host_entry(settings)}
    else:
        new = {}
        for platform in settings.platform:
            new.update(image_entries(settings, platform, out))
    changes = [line for key, entry in sorted(new.items())
               for line in entry_changes(key, targets.get(key) or {}, entry)]
    if not check:
        targets.update(new)
        path.write_text(dump_lock({**current, "targets": targets}))
    return changes
