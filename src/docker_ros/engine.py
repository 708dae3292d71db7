"""The Docker Engine API (docker SDK) for what it does well: ping, inspect, pull, tag, push and
remove. Builds go through the buildx CLI (the SDK drives only the legacy builder: no BuildKit
mounts or secrets) and manifest lists through `docker buildx imagetools` (the Engine API has
none)."""

from __future__ import annotations

import contextlib
import functools
import os
from typing import Any, Dict, Iterable, Optional

import docker
from docker.errors import DockerException, ImageNotFound, NotFound
from docker.utils import parse_repository_tag


class EngineError(Exception):
    """The engine refused or failed: what, and docker's reason."""


@functools.lru_cache(maxsize=1)
def client() -> docker.DockerClient:
    """A client of the engine DOCKER_HOST (or the local socket) names, checked to answer."""
    try:
        engine = docker.from_env()
        engine.ping()
    except DockerException:
        where = os.environ.get("DOCKER_HOST") or "the default socket"
        raise EngineError(f"no Docker daemon answers at {where}: start it, e.g. with "
                          "scripts/setup.sh") from None
    return engine


def inspect_image(ref: str) -> Optional[Dict[str, Any]]:
    """`docker image inspect` of a local image, or None when there is none."""
    try:
        return dict(client().images.get(ref).attrs)
    except (ImageNotFound, NotFound):
        return None


def image_exists(ref: str) -> bool:
    return inspect_image(ref) is not None


def image_size(ref: str) -> int:
    attrs = inspect_image(ref)
    return int(attrs["Size"]) if attrs else 0


def pull(ref: str) -> bool:
    """Pull ref; False when the registry refuses or cannot be reached."""
    repository, tag = parse_repository_tag(ref)
    try:
        client().images.pull(repository, tag=tag or "latest")
    except DockerException:
        return False
    return True


def local_or_pulled(ref: str) -> bool:
    """ref is a local image, or one pulled now."""
    return image_exists(ref) or pull(ref)


def tag(source: str, target: str) -> None:
    repository, name_tag = parse_repository_tag(target)
    try:
        client().images.get(source).tag(repository, tag=name_tag or "latest")
    except DockerException as exc:
        raise EngineError(f"tagging {source} as {target} failed: {exc}") from None


def push(ref: str, auth: Optional[Dict[str, str]] = None) -> None:
    """Push ref; credentials go to the engine in the request, never to a file or command line."""
    repository, name_tag = parse_repository_tag(ref)
    try:
        events: Iterable[Dict[str, Any]] = client().images.push(
            repository, tag=name_tag or "latest", auth_config=auth, stream=True, decode=True)
        for event in events:
            if "error" in event:
                raise EngineError(f"docker push {ref} failed: {event['error']}")
    except DockerException as exc:
        raise EngineError(f"docker push {ref} failed: {exc}") from None


def remove_image(ref: str) -> None:
    """Remove a tag this tool made; a missing one is fine."""
    with contextlib.suppress(ImageNotFound, NotFound):
        client().images.remove(ref, noprune=False)
