"""The metadata file buildx writes for a build (`--metadata-file`): the digest of each image
it made. Pure, but for reading the file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Dict, Mapping, Sequence

# The image's digest: the manifest's (the containerd image store, a push), or on the classic
# image store the configuration's (the image ID).
DIGEST_KEYS = ("containerimage.digest", "containerimage.config.digest")


def read_metadata(path: Path) -> Dict[str, Any]:
    """The metadata file as JSON ({} when buildx wrote none, or none that reads)."""
    try:
        found = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return found if isinstance(found, dict) else {}


def image_digests(metadata: Mapping[str, Any], targets: Sequence[str]) -> Dict[str, str]:
    """target -> digest of what a buildx run made: bake's file has one entry per target, a
    `buildx build` writes its one target's keys at the top."""
    entries = ({t: metadata.get(t) for t in targets} if any(t in metadata for t in targets)
               else {targets[0]: metadata} if len(targets) == 1 else {})
    digests = {}
    for target, entry in entries.items():
        if isinstance(entry, Mapping):
            digest = next((str(entry[k]) for k in DIGEST_KEYS if entry.get(k)), "")
            if digest:
                digests[target] = digest
    return digests
