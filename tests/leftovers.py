"""What a test run or a bench run leaves on an engine, and its removal at the run's end. The
engine is shared with everything else on the machine, so only what the run made goes:
- the imports images of its repositories (labelled with the repository's path, hashed; the
  run's repositories are below its temporary folder);
- the images its rebuilds untagged (dangling now but not when the run began, built on a base
  image of docker-ros's recipe);
- the images named after a registry it served (a free port of the run), and at its start
  those of an earlier run that was killed before its end."""

from __future__ import annotations

import contextlib
import re
from pathlib import Path
from typing import Callable, Iterable, Iterator, Set

import docker

from docker_ros.host.baseimage import RECIPE_LABEL
from docker_ros.host.buildcontext import IMPORTS_LABEL, imports_owner


def folders(root: Path, depth: int) -> Iterator[Path]:
    """root and the folders below it, at most depth levels down (links not followed)."""
    yield root
    if depth > 0:
        for child in sorted(root.iterdir()) if root.is_dir() else []:
            if child.is_dir() and not child.is_symlink():
                yield from folders(child, depth - 1)


def remove(client: docker.DockerClient, ref: str) -> None:
    """Remove an image the run made; one a container still uses stays, as `docker image rm`
    would leave it, and one another user of the engine removed meanwhile is fine."""
    with contextlib.suppress(docker.errors.APIError):
        client.images.remove(ref)


def untagged(client: docker.DockerClient, label: str = RECIPE_LABEL) -> Set[str]:
    """The IDs of the dangling images (no tag left) built on a base image of docker-ros's
    recipe (label): taken when a run begins, those stay (they were not made dangling by it)."""
    images = client.api.images(filters={"dangling": True, "label": label})
    return {str(image["Id"]) for image in images}


def remove_run_images(client: docker.DockerClient, roots: Iterable[Path], before: Set[str],
                      label: str = RECIPE_LABEL) -> None:
    """The imports images of the repositories below the roots (at most 5 levels down: a run on
    several processes has a folder per process), and the images of label that became dangling
    since the run began (before: `untagged` then): the run's rebuilds untagged them, its own or
    a previous run's under the same test names. Called when the run's builds are over: an image
    being built is dangling until it is tagged. The raw lists: images.list() inspects each
    image and fails when another user of the engine removes one meanwhile."""
    owners = {imports_owner(folder) for root in roots for folder in folders(root, 5)}
    for image in client.api.images(filters={"label": IMPORTS_LABEL}):
        if (image.get("Labels") or {}).get(IMPORTS_LABEL) in owners:
            for tag in image.get("RepoTags") or []:
                remove(client, tag)
    for image_id in sorted(untagged(client, label) - before):
        remove(client, image_id)


def remove_registry_images(client: docker.DockerClient, address: str) -> None:
    """The images named after the registry at address (tagged, or pulled by digest only)."""
    remove_named(client, lambda ref: ref.startswith(f"{address}/"))


# The names the tests give images in a registry they serve: a free port of this machine's
# loopback, the suite's own namespace
SUITE_REGISTRY_REF = re.compile(r"127\.0\.0\.1:\d+/docker-ros-test/")


def remove_killed_runs_images(client: docker.DockerClient) -> None:
    """The images named after a registry of an earlier run that was killed before its end (its
    registries' images stay then). Called while this run holds the suite lock: no other run
    serves a registry, and none of this run's has started."""
    remove_named(client, lambda ref: SUITE_REGISTRY_REF.match(ref) is not None)


def remove_named(client: docker.DockerClient, made: Callable[[str], bool]) -> None:
    """The tags that made says the run made, and the images pulled by digest only whose every
    digest it made."""
    for image in client.api.images():
        tags = image.get("RepoTags") or []
        for tag in tags:
            if made(tag):
                remove(client, tag)
        digests = image.get("RepoDigests") or []
        if not tags and digests and all(made(d) for d in digests):
            remove(client, image["Id"])
