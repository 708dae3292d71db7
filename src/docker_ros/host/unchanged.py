"""A rebuild with nothing changed does not start BuildKit (issue 49): after a build of dev
and/or run into the local engine, a small record (in the user's cache folder, one per engine,
repository and platform) keeps each target's inputs and the id of the image built from them.
The next build whose inputs are the same and whose tags still name those images says so and
stops there, as BuildKit's cache would have given the same images, only later.

The inputs are what BuildKit's cache keys follow: the target's bake definition (build
arguments, labels, secrets' ids, the Dockerfile), the build context's files (path, mode,
content, as buildstate.inputs_fingerprint reads them), the ids of the base, tools and
imports images, and SOURCE_DATE_EPOCH (buildx passes it on). A secret's value is not an
input (BuildKit's cache ignores it too). Builds that push, export a cache, seed from a build
state, write an --output, run on a BuildKit of their own or set NO_CACHE always run.

In a CI job (`docker-ros ci`, whose tasks share a record: jobsummary.RECORD_ENV) the record
is the job's own, kept beside it, and also holds builds that export a cache or seed from a
build state, and the build state: the job's `push` after `build`, `test` and `slim` then
pushes the images the job built and tested, not a rebuild of them (an inline cache alone gives
a rebuild new image ids, and slim then ran again)."""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Mapping, Optional

from docker_ros.core.settings import Settings
from docker_ros.host import buildmeta
from docker_ros.host.jobsummary import RECORD_ENV

TARGETS = ("dev", "run")


def applies(settings: Settings, targets: Mapping[str, str], *, push: bool, output: str,
            own_buildkit: bool, in_job: bool = False) -> bool:
    """Whether this build may stand on its record: dev and/or run loaded into an engine, with
    no NO_CACHE or BuildKit of its own, and no cache export or build-state seed unless in a CI
    job (in_job; there the build state too)."""
    allowed = TARGETS + (("build-state",) if in_job else ())
    return (bool(targets) and set(targets) <= set(allowed) and not push and not output
            and not own_buildkit and not settings.no_cache
            and (in_job or not (settings.cache_to or settings.build_state_from)))


def in_job(environ: Mapping[str, str]) -> bool:
    """Whether this task runs in a CI job's `docker-ros ci` (which keeps a record)."""
    return bool(environ.get(RECORD_ENV))


def record_path(host: str, context: Path, platform: str,
                environ: Mapping[str, str]) -> Path:
    """The record of builds of the repository at context for platform in the engine at host:
    $XDG_CACHE_HOME/docker-ros/builds/<digest>.json (~/.cache unless set); in a CI job, the
    job's own, beside its record (gone with it)."""
    cache = Path(environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "docker-ros"
    folder = Path(environ[RECORD_ENV]).parent if in_job(environ) else cache
    key = hashlib.sha256(f"{host}\0{context.resolve()}\0{platform}".encode()).hexdigest()
    return folder / "builds" / f"{key[:32]}.json"


def target_inputs(spec: Mapping[str, Any], temporary: str, shared: str) -> str:
    """One digest of a target's bake definition (the build's temporary folder, a new name each
    run, left out of its paths) and the inputs it shares with the other targets."""
    text = json.dumps(spec, sort_keys=True).replace(temporary, "<temporary>")
    return hashlib.sha256(f"{shared}\0{text}".encode()).hexdigest()


def shared_inputs(dockerfile: bytes, context_digest: str, others: Mapping[str, str]) -> str:
    """The inputs every target of the build has: its Dockerfile, its context's files and the
    others (the ids of the images it starts from: base, tools, imports; SOURCE_DATE_EPOCH)."""
    parts = [hashlib.sha256(dockerfile).hexdigest(), context_digest,
             *(f"{name}={value}" for name, value in sorted(others.items()))]
    return hashlib.sha256("\0".join(parts).encode()).hexdigest()


def up_to_date(record: Mapping[str, Any], inputs: Mapping[str, str],
               current: Mapping[str, Optional[str]]) -> bool:
    """Whether every tag (inputs: tag -> its target's inputs) was built from these inputs
    (record) and still names the image built then (current: tag -> its image id now)."""
    entries = record.get("images", {})
    return bool(inputs) and all(
        isinstance(entries.get(tag), dict) and entries[tag].get("inputs") == digest
        and current.get(tag) and entries[tag].get("id") == current[tag]
        for tag, digest in inputs.items())


# The record at path ({} when there is none or it cannot be read): a JSON object's file, as
# buildx's metadata file.
read = buildmeta.read_metadata


def write(path: Path, images: Mapping[str, Mapping[str, str]]) -> None:
    """Record images (tag -> {inputs, id, digest}) over the record's entries of the same tags,
    atomically (another build of the repository may read it). A record that cannot be
    written only means the next build runs BuildKit."""
    record = read(path)
    record["images"] = {**record.get("images", {}), **images}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=path.parent, delete=False,
                                         suffix=".tmp") as handle:
            json.dump(record, handle, sort_keys=True)
        os.replace(handle.name, path)
    except OSError:
        pass
