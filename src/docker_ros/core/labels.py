"""Image labels: docker-ros's own namespace and the user's LABELS (parsed here, where the
settings are loaded, so that bad input is one error among the configuration's)."""

from __future__ import annotations

import re
from typing import Dict

# The one prefix of the labels docker-ros reads back (reverse DNS, as the OCI annotation rules
# ask; `org.opencontainers.image.*` are the ecosystem's own, see host/labels.py).
NAMESPACE = "org.docker-ros"
# A label key as the OCI rules and `docker build --label` take it: letters, digits, `.`, `-`,
# `_`, `/`, starting and ending with a letter or digit.
KEY = re.compile(r"[A-Za-z0-9](?:[A-Za-z0-9._/-]*[A-Za-z0-9])?")


class LabelsError(ValueError):
    """LABELS holds an entry that is no `key=value` label."""


def ours(name: str) -> str:
    """One of docker-ros's own labels: `org.docker-ros.<name>`."""
    return f"{NAMESPACE}.{name}"


def parse_labels(raw: str) -> Dict[str, str]:
    """LABELS -> {key: value}: `key=value` entries one a line, or comma-separated when the
    value holds no newline (a value with a comma then needs a line of its own). Blank entries
    are skipped; a key given twice keeps the last value, as `docker build --label` does."""
    entries = raw.splitlines() if "\n" in raw.strip() else raw.split(",")
    labels: Dict[str, str] = {}
    for entry in (e.strip() for e in entries):
        if not entry:
            continue
        key, sep, value = entry.partition("=")
        key = key.strip()
        if not sep or not KEY.fullmatch(key):
            raise LabelsError(
                f"{entry!r} is no `key=value` label (keys: letters, digits, `.`, `-`, `_`, `/`):"
                " give `key=value` entries, comma-separated or one a line")
        if key == NAMESPACE or key.startswith(NAMESPACE + "."):
            raise LabelsError(f"{key!r}: labels under {NAMESPACE}. are docker-ros's own: choose "
                              "a key of your own namespace")
        labels[key] = value.strip()
    return labels
