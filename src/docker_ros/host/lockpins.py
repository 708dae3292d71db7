"""What a build reads from docker-ros.lock: the base image by digest, prepare's pins, the lock's
label, the tag of a local base image. Apart from the `inv lock` command (host/lock.py), which
builds images to write the lock."""

import json
from pathlib import Path
from typing import Dict, Tuple

from docker_ros.core.labels import ours
from docker_ros.core.settings import Settings
from docker_ros.host import engine
from docker_ros.in_image.runtime.lockapt import apt_preferences
from docker_ros.in_image.runtime.lockfile import (
    LOCK_FILE,
    LOCKED_ENV,
    LockError,
    base_image_ref,
    load_lock,
    lock_digest,
    locked_target,
    target_key,
)


def lock_path(settings: Settings) -> Path:
    return Path(settings.build_context) / LOCK_FILE


LOCK_LABEL = ours("lock")
IMAGE_TARGETS = ("dev", "run")  # the targets `inv lock` resolves


def locked_build_args(settings: Settings, *, target: str, platform: str) -> Dict[str, str]:
    """Build arguments a locked build overrides (none unless LOCKED): BASE_IMAGE by digest
    and DOCKER_ROS_LOCKED, which makes the image's steps honour the lock."""
    if not settings.locked or target not in IMAGE_TARGETS:
        return {}
    entry = locked_target(load_lock(lock_path(settings)), target, platform)
    record = entry.get("base_image") or {}
    if record.get("ref") != settings.base_image:
        raise LockError(
            f"LOCKED: BASE_IMAGE is {settings.base_image}, docker-ros.lock has {record.get('ref')}:"
            " run `inv lock`"
        )
    return {"BASE_IMAGE": base_image_ref(settings.base_image or "", record), LOCKED_ENV: "true"}


def prepare_pins(settings: Settings, platform: str) -> Dict[str, str]:
    """The lock's pins for the image's prepare, as apt preferences files (file name -> text):
    base.pref, what the base stage's prepare installs (the run entry's), and dev.pref, with
    the dev image's toolchain (the dev entry's); none unless LOCKED."""
    if not settings.locked:
        return {}
    lock = load_lock(lock_path(settings))
    pins: Dict[str, str] = {}
    for target, name in (("run", "base.pref"), ("dev", "dev.pref")):
        entry = locked_target(lock, target, platform)
        if "prepare" not in entry:
            raise LockError(f"LOCKED: docker-ros.lock's {target_key(target, platform)} records "
                            "no prepare packages (an older docker-ros wrote it): run `inv lock`")
        pins[name] = apt_preferences(entry["prepare"])
    return pins


# the BuildKit secret ids that carry prepare's pins (the Dockerfile mounts them where prepare
# reads them: /docker-ros/lock-pins/<file>)
PIN_SECRETS = {"base.pref": "DOCKER_ROS_PINS_BASE", "dev.pref": "DOCKER_ROS_PINS_DEV"}
PINS_ARG = "DOCKER_ROS_PREPARE_PINS"


def prepare_pin_secrets(settings: Settings, platform: str, folder: Path
                        ) -> Tuple[Dict[str, str], Dict[str, str]]:
    """(build arguments, secrets) that bring prepare_pins into a locked build: each file
    (written to folder) as a BuildKit secret, and their digest as DOCKER_ROS_PREPARE_PINS,
    since a secret's content is no part of a cache key and a new lock must run prepare again.
    (Not files in an image the stage mounts: on Engine 26, a registry cache exported by a job
    that took the base stage from it no longer matched the next job's base stage.)"""
    pins = prepare_pins(settings, platform)
    if not pins:
        return {}, {}
    secrets: Dict[str, str] = {}
    for name, text in sorted(pins.items()):
        (folder / name).write_text(text)
        secrets[PIN_SECRETS[name]] = f"src={folder / name}"
    digest = lock_digest("".join(f"{name}\0{text}\0" for name, text in sorted(pins.items())))
    return {PINS_ARG: digest}, secrets


def tag_local_base(settings: Settings, platform: str) -> None:
    """Give a locked local base image (its ID in the lock) the tag base_image_ref names; a
    lock whose local base image is gone stops the build, naming it."""
    if not settings.locked:
        return
    lock = load_lock(lock_path(settings))
    for target in IMAGE_TARGETS:
        record = (lock.get("targets") or {}).get(target_key(target, platform), {}).get(
            "base_image") or {}
        if not record.get("local"):
            continue
        image_id = str(record.get("digest"))
        if engine.inspect_image(image_id) is None:
            raise LockError(f"LOCKED: the local base image {image_id} of docker-ros.lock "
                            f"({record.get('ref')}, never pushed) no longer exists here: "
                            "run `inv lock`")
        engine.tag(image_id, base_image_ref(str(record.get("ref")), record))


def lock_labels(settings: Settings, target: str) -> Dict[str, str]:
    """The label of a locked build's dev and run images: the lock's digest."""
    if not settings.locked or target not in IMAGE_TARGETS:
        return {}
    return {LOCK_LABEL: lock_digest(lock_path(settings).read_text())}


def lock_status(settings: Settings) -> str:
    """One line for the final table and `inv config`: whether a lock is in use."""
    path = lock_path(settings)
    if not settings.locked:
        present = f"; {LOCK_FILE} present" if path.is_file() else ""
        return f"lock: not in use (LOCKED=false{present})"
    if not path.is_file():
        return f"lock: LOCKED=true but {LOCK_FILE} is missing: run `inv lock`"
    text = path.read_text()
    return (f"lock: locked build, {LOCK_FILE} {lock_digest(text)} "
            f"({', '.join(sorted(json.loads(text).get('targets') or {}))})")
