"""The build state a build starts from (BUILD_STATE_FROM): which seed the colcon step's empty
build cache gets, and what the build state it makes records about it.

Any seed gives a correct build (colcon compares the sources, arguments and dependencies with
the state's record and compiles what differs); the seed only decides what is compiled and, as
the seed's content is part of the colcon RUN's cache key, whether a registry cache can serve
that RUN. A build state records, as labels, the seed it was built from and a fingerprint of the
build's inputs (inputs_fingerprint). A build with the same inputs is seeded as that build was:
its colcon RUN then has that build's cache key, and the pulled state stands as its own build
state. Otherwise the build starts from the pulled state (only what changed compiles)."""

from __future__ import annotations

import hashlib
import os
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Callable, Dict, Mapping, Optional

from docker_ros.core.labels import ours
from docker_ros.core.settings import Settings
from docker_ros.host import engine

SEED_ARG = "DOCKER_ROS_BUILD_STATE"
SEED_LABEL = ours("build-state.seed")
INPUTS_LABEL = ours("build-state.inputs")
# the names of docker-ros before one namespace: a build state an earlier pipeline pushed
OLD_LABELS = {SEED_LABEL: "io.github.docker-ros.build-state.seed",
              INPUTS_LABEL: "io.github.docker-ros.build-state.inputs"}
EMPTY = "none"  # the recorded seed of a build that started from the empty seed
DIGEST_REF = re.compile(r"^(?P<repository>[^@\s]+)@sha256:[0-9a-f]{64}$")


@dataclass(frozen=True)
class Seed:
    """ref: the seed image ("" the empty seed); recorded: what the build state made from it
    records (EMPTY, `<repository>@sha256:...`, or "" when unknown: no later build seeds as this
    one); reuse: a pulled state of this build's inputs, which stands as its build state; why:
    the line saying which seed and why."""

    ref: str
    recorded: str
    reuse: str = ""
    why: str = ""

    def build_args(self) -> Dict[str, str]:
        return {SEED_ARG: self.ref} if self.ref else {}


def repository(ref: str) -> str:
    """An image reference's repository: without `@digest` and without `:tag`."""
    name = ref.split("@", 1)[0]
    return name.rsplit(":", 1)[0] if ":" in name.rsplit("/", 1)[-1] else name


def repo_digest(ref: str, attrs: Mapping[str, Any]) -> str:
    """ref's registry name by digest (`<repository>@sha256:...`, from an image inspect's
    RepoDigests), or "" when unknown."""
    own = repository(ref)
    return next((d for d in attrs.get("RepoDigests") or []
                 if DIGEST_REF.match(d) and repository(d) == own), "")


def inputs_fingerprint(context: Path, parts: Mapping[str, str],
                       left_out: Callable[[str], bool]) -> str:
    """One digest of what a build starts from: parts (the build arguments but the seed, the
    platform, the Dockerfile, the base image's id) and every file of the build context that
    left_out keeps (path, mode, content). Equal fingerprints, the same
    build, as far as the registry cache is concerned: what the context's .dockerignore leaves
    out only makes the fingerprint change more often than the build."""
    digest = hashlib.sha256()
    for key, value in sorted(parts.items()):
        if key != SEED_ARG:
            digest.update(f"{key}={value}\0".encode())
    for dirpath, dirnames, filenames in os.walk(context):
        folder = Path(dirpath)
        dirnames[:] = sorted(d for d in dirnames
                             if not left_out((folder / d).relative_to(context).as_posix()))
        for name in sorted(filenames):
            path = folder / name
            rel = path.relative_to(context).as_posix()
            if left_out(rel):
                continue
            mode = path.lstat().st_mode
            if path.is_symlink():
                data = os.readlink(path).encode()
            elif path.is_file():
                data = path.read_bytes()
            else:
                data = b""
            digest.update(f"{rel}\0{mode:o}\0".encode() + data + b"\0")
    return digest.hexdigest()


def foreign_architecture(attrs: Mapping[str, Any], platform: str) -> str:
    """An image's architecture (image inspect attrs) when it is not platform's, else ""."""
    architecture = attrs.get("Architecture") or ""
    return architecture if architecture not in ("", platform.split("/")[0]) else ""


def choose_seed(pulled: str, attrs: Mapping[str, Any], platform: str, fingerprint: str,
                registry_cache: bool) -> Seed:
    """The seed of a build for platform whose inputs have fingerprint, given the pulled build
    state and its image inspect attrs:
    - a state of another architecture: none (the empty seed);
    - without a registry cache of every stage: the state (the colcon RUN cannot come from a
      cache on an empty runner; over the state it compiles what changed);
    - a state of other inputs, or recording no usable seed: the state;
    - a state of these same inputs: the seed it was built from (`none`: the empty one), so
      that the colcon RUN has that build's cache key, and the state is reused as this build's.
    A recorded seed must be a digest in the state's own repository: a label never sends a
    build elsewhere."""
    architecture = foreign_architecture(attrs, platform)
    if architecture:
        return Seed("", EMPTY, why=f"{pulled} is a build state for {architecture}, not "
                                   f"{platform}: not used")
    over = Seed(pulled, repo_digest(pulled, attrs))
    given = (attrs.get("Config") or {}).get("Labels") or {}
    labels = {new: given.get(new, given.get(old)) for new, old in OLD_LABELS.items()}
    if not registry_cache:
        return Seed(over.ref, over.recorded, why="building over it (without a registry cache"
                    " of every stage the colcon step runs on an empty runner)")
    if labels.get(INPUTS_LABEL) != fingerprint:
        return Seed(over.ref, over.recorded,
                    why="its inputs differ from this build's: building over it")
    recorded = labels.get(SEED_LABEL) or ""
    match = DIGEST_REF.match(recorded)
    if recorded != EMPTY and not (match and match["repository"] == repository(pulled)):
        return Seed(over.ref, over.recorded,
                    why="it records no seed in its repository: building over it")
    return Seed("" if recorded == EMPTY else recorded, recorded, reuse=pulled,
                why=f"built from these same inputs: seeding as that build was "
                    f"({'empty' if recorded == EMPTY else recorded}), so that the registry "
                    "cache can serve the colcon step; it stands as this build's build state")


def pull_state(settings: Settings, platform: str, out: IO[str]) -> Optional[str]:
    """The first pullable BUILD_STATE_FROM image of this platform (pulled now), one line per
    candidate tried; None when none can be pulled."""
    for candidate in settings.build_state_from:
        ref = f"{candidate}-{platform}"
        start = time.monotonic()
        if engine.pull(ref):
            print(f"build state: {ref} pulled in {time.monotonic() - start:.1f} s"
                  f" ({engine.image_size(ref) / 1e6:.0f} MB)", file=out)
            return ref
        print(f"build state: {ref} could not be pulled (none pushed yet?)", file=out)
    return None


def run_seed(settings: Settings, platform: str, fingerprint: str, registry_cache: bool,
             out: IO[str]) -> Seed:
    """The seed of a build of the run image (choose_seed over the pulled state; the recorded
    seed pulled, else the state itself). No pullable state: the empty seed (colcon then builds
    everything and says why)."""
    pulled = pull_state(settings, platform, out)
    if pulled is None:
        return Seed("", EMPTY)
    attrs = engine.inspect_image(pulled) or {}
    seed = choose_seed(pulled, attrs, platform, fingerprint, registry_cache)
    if seed.ref and seed.ref != pulled and not (
            engine.pull(seed.ref)
            and not foreign_architecture(engine.inspect_image(seed.ref) or {}, platform)):
        seed = Seed(pulled, repo_digest(pulled, attrs),
                    why=f"the seed it was built from, {seed.ref}, cannot be pulled for "
                        f"{platform}: building over it")
    if seed.why:
        print(f"build state: {seed.why}", file=out)
    return seed


def seed_for_test(settings: Settings, platform: str, out: IO[str]) -> Seed:
    """The seed of the test stage's build: the pulled state itself (the test RUN runs every
    time; over a state of the same sources its colcon build compiles nothing)."""
    pulled = pull_state(settings, platform, out)
    if pulled is None:
        return Seed("", EMPTY)
    seed = choose_seed(pulled, engine.inspect_image(pulled) or {}, platform, "", False)
    if not seed.ref:  # another architecture's
        print(f"build state: {seed.why}", file=out)
    return seed
