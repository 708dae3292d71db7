"""Image references: of each target and platform, of a step's stage, of the base image."""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import Mapping, Optional, Sequence, Tuple

from docker_ros.core.errors import BuildError
from docker_ros.core.settings import Settings
from docker_ros.host import engine
from docker_ros.host.baseimage import arch_ref


def until_ref(settings: Settings, step: str) -> str:
    """Tag of an image built up to a step: <IMAGE_NAME>:<IMAGE_TAG>-until-<step>."""
    return f"{settings.image_name}:{settings.image_tag}-until-{step}"


def image_ref(settings: Settings, target: str) -> str:
    if target == "dev":
        return f"{settings.dev_image_name}:{settings.dev_image_tag}"
    if target == "slim":
        return f"{settings.slim_image_name}:{settings.slim_image_tag}"
    if target == "build-state":  # (BUILD_STATE_REPOSITORY: a repository of its own)
        where = settings.build_state_repository or settings.image_name
        return f"{where}:{settings.image_tag}-build-state"
    return f"{settings.image_name}:{settings.image_tag}"


def platform_ref(ref: str, platform: str, platforms: Sequence[str]) -> str:
    """Several platforms: one local tag per architecture (`-amd64`/`-arm64` postfix)."""
    return ref if len(platforms) <= 1 else f"{ref}-{platform}"


def slim_platforms(platforms: Sequence[str], host: str) -> Tuple[str, ...]:
    """The platforms whose run image is slimmed. Of several, only the runner's: slimming runs
    the image, and docker-ros's single-job multi-arch build also slims only what the runner
    pulls (its own architecture). A lone foreign platform stays, for slim's own error."""
    return (host,) if len(platforms) > 1 and host in platforms else tuple(platforms)


def target_ref(settings: Settings, target: str, platform: str) -> str:
    """The local name of a target's image built for one platform. Per architecture (`-<arch>`)
    are a build state (the jobs of several architectures push one each) and, with
    ENABLE_SINGLEARCH_PUSH, every image, as docker-ros's CI builds them: jobs of two
    architectures on one engine (a shell runner) then never tag, test or push each other's."""
    ref = image_ref(settings, target)
    if target == "build-state" or settings.enable_singlearch_push:
        return f"{ref}-{platform}"
    return platform_ref(ref, platform, settings.platform)


@dataclass(frozen=True)
class LocalBase:
    """What the local image store holds under a base image's name."""

    architecture: str
    from_registry: bool  # pulled or pushed under this name: its registry has it


def choose_base(base_image: str, platform: str,
                local: Mapping[str, Optional[LocalBase]]) -> Tuple[str, str]:
    """The image the build FROMs for platform, and a line saying why when that is not
    BASE_IMAGE's local image ('' when it is). local: the local images of BASE_IMAGE and of its
    arch_ref (None: not local). The classic image store holds one architecture per tag; a
    local image of another architecture is used only as its registry's multi-arch name
    (BuildKit then pulls the platform's image), never as the platform's image."""
    own, tagged = local.get(base_image), local.get(arch_ref(base_image, platform))
    if own is not None and own.architecture == platform:
        return base_image, ""
    if tagged is not None and tagged.architecture == platform:
        return arch_ref(base_image, platform), (
            f"base image ({platform}): {arch_ref(base_image, platform)}, the {platform} image "
            f"of BASE_IMAGE {base_image}")
    if own is None:
        return base_image, ""  # a registry's name: BuildKit pulls the platform's image
    if own.from_registry:
        return base_image, (
            f"base image ({platform}): {base_image} is a local {own.architecture} image; "
            f"BuildKit pulls its {platform} image from its registry")
    raise BuildError(
        f"BASE_IMAGE {base_image} is a local {own.architecture or 'unknown'} image from no "
        f"registry, and no {platform} image is tagged {arch_ref(base_image, platform)}: make "
        f"one with `inv bootstrap-base-image --platform {platform}` (which tags it so), tag "
        f"your {platform} base image {arch_ref(base_image, platform)}, or set BASE_IMAGE to a "
        "multi-arch image in a registry")


def local_base(ref: str) -> Optional[LocalBase]:
    attrs = engine.inspect_image(ref)
    if attrs is None:
        return None
    return LocalBase(str(attrs.get("Architecture") or ""),
                     from_registry(ref, attrs.get("RepoDigests") or []))


def from_registry(ref: str, repo_digests: Sequence[str]) -> bool:
    """Whether ref's own repository holds the image (a digest of that name; the image's digests
    are those of every name it was pulled or pushed as, also under other names)."""
    name = ref.split("@")[0]
    repository = name.rsplit(":", 1)[0] if ":" in name.rsplit("/", 1)[-1] else name
    return any(digest.split("@")[0] == repository for digest in repo_digests)


def closest_image(ref: str, tags: Sequence[str]) -> str:
    """The local image tag that ref, a name no image answers to, most likely misspells, or "":
    close, and not in digits (`ros:notic` is `ros:noetic`; `base:1` is not `base:2`, nor `ros2`
    `ros1`: another version or image)."""
    for close in difflib.get_close_matches(ref, [t for t in tags if t != ref], n=3, cutoff=0.85):
        if not any(ch.isdigit() for ch in edited(ref, close)):
            return close
    return ""


def edited(a: str, b: str) -> str:
    """The characters that differ between a and b (those removed from a and put in b)."""
    edits = difflib.SequenceMatcher(None, a, b).get_opcodes()
    return "".join(a[i1:i2] + b[j1:j2] for op, i1, i2, j1, j2 in edits if op != "equal")


def platform_base(settings: Settings, platform: str) -> Tuple[str, str]:
    """choose_base with what this engine holds; a BASE_IMAGE that is neither local (under
    either name) nor pullable is a BuildError."""
    base = settings.base_image or ""
    names = (base, arch_ref(base, platform))
    local = {name: local_base(name) for name in names}
    if not any(local.values()):
        refused = engine.pull_error(base)
        if refused is not None:
            close = closest_image(base, engine.local_tags())
            check = f"did you mean the local image {close}? Else check" if close else "check"
            raise BuildError(
                f"BASE_IMAGE '{base}' is neither a local image nor pullable ({refused}): {check} "
                "the name; for a private registry set REGISTRY, REGISTRY_USER and "
                "REGISTRY_PASSWORD (docker-ros logs in before the build) or `docker login`; "
                "or make one with `inv bootstrap-base-image`")
        local[base] = local_base(base)
    return choose_base(base, platform, local)


def shown_base(settings: Settings, platform: str) -> str:
    """platform_base as a dry run shows it: from what this engine holds, pulling nothing (a
    BASE_IMAGE that is not local, or no engine, shows BASE_IMAGE)."""
    base = settings.base_image or ""
    try:
        local = {name: local_base(name) for name in (base, arch_ref(base, platform))}
    except engine.EngineError:
        return base
    return choose_base(base, platform, local)[0]
