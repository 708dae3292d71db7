"""What a test run or a bench run leaves on an engine, and its removal at the run's end. The
engine is shared with everything else on the machine, so only what the run made goes:
- the imports images of its repositories (labelled with the repository's path, hashed; the
  run's repositories are below its temporary folder);
- the images its rebuilds untagged (dangling now but not when the run began, built on a base
  image of docker-ros's recipe);
- the images named after a registry it served (a free port of the run)."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Iterator, Set

import docker

from docker_ros.host.baseimage import RECIPE_LABEL
from docker_ros.host.build import IMPORTS_LABEL, imports_owner


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


def untagged(client: docker.DockerClient) -> Set[str]:
    """The IDs of the dangling images (no tag left) built on a base image of docker-ros's
    recipe: taken when a run begins, those stay (they were not made dangling by it)."""
    images = client.api.images(filters={"dangling": True, "label": RECIPE_LABEL})
    return {str(image["Id"]) for image in images}


def remove_run_images(client: docker.DockerClient, root: Path, before: Set[str]) -> None:
    """The imports images of the repositories below root (at most 4 levels down), and the
    images that became dangling since the run began (before: `untagged` then): the run's
    rebuilds untagged them, its own or a previous run's under the same test names. The raw
    lists: images.list() inspects each image and fails when another user of the engine
    removes one meanwhile."""
    owners = {imports_owner(folder) for folder in folders(root, 4)}
    for image in client.api.images(filters={"label": IMPORTS_LABEL}):
        if (image.get("Labels") or {}).get(IMPORTS_LABEL) in owners:
            for tag in image.get("RepoTags") or []:
                remove(client, tag)
    for image_id in sorted(untagged(client) - before):
        remove(client, image_id)


def remove_registry_images(client: docker.DockerClient, address: str) -> None:
    """The images named after the registry at address (tagged, or pulled by digest only)."""
    for image in client.api.images():
        tags = image.get("RepoTags") or []
        for tag in tags:
            if tag.startswith(f"{address}/"):
                remove(client, tag)
        digests = image.get("RepoDigests") or []
        if not tags and digests and all(d.startswith(f"{address}/") for d in digests):
            remove(client, image["Id"])
