"""Image builds with docker buildx (BuildKit): plan the argv (pure), run it (its log: buildlog)."""

from __future__ import annotations

import contextlib
import difflib
import fcntl
import functools
import hashlib
import json
import os
import re
import shutil
import stat
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple

import docker_ros
from docker_ros.core.display import as_env
from docker_ros.core.settings import FIELDS, Settings, build_secrets, env_name
from docker_ros.host import builder, buildlog, buildstate, engine
from docker_ros.host.baseimage import arch_ref
from docker_ros.host.config import rmw_chosen
from docker_ros.host.engine import image_exists, image_size
from docker_ros.host.lock import lock_labels, locked_build_args, prepare_pin_secrets, tag_local_base
from docker_ros.in_image.runtime.files import walk
from docker_ros.in_image.runtime.inputs import resolve_inputs
from docker_ros.in_image.runtime.lock import LOCK_FILE
from docker_ros.in_image.runtime.workspace import StepError, Workspace

PACKAGE_DIR = Path(docker_ros.__file__).resolve().parent
DOCKERFILE = PACKAGE_DIR / "docker" / "Dockerfile"
TOOLS_REPOSITORY = "docker-ros-tools"
IMPORTS_REPOSITORY = "docker-ros-imports"
IMPORTS_LABEL = "docker-ros.imports-of"  # the repository (imports_owner) that made the image
# the dev image's: the content digest of the files resolving its dependencies read (the
# imports image's), which `inv dev-shell` compares with the repository's (stale_dev_image)
INPUTS_LABEL = "io.github.docker-ros.dependency-inputs"
# Files of the package that the images need (stdlib-only step modules and the image scripts).
TOOLS_PATTERNS = ("__init__.py", "core/*.py", "in_image/*.py", "in_image/*/*.py", "docker/*.sh")
SECRETS = build_secrets()
SCRATCH_FOLDER = ".gitlab-ci-local"  # gitlab-ci-local's copies of the repository
# Names that never reach an image, wherever they are in the repository (see dockerignore);
# the last two, the GitLab template's copy of the tests' results and its dotenv report of the
# image names, are artifacts of an earlier job.
LEFT_OUT = (".env", ".git", ".gitlab-ci-local-variables.yml", "docker-ros-test-results",
            "docker-ros-images.env")
BUILDX = ("docker", "buildx")  # the command reaching the default builder
# The targets that export a registry cache (CACHE_TO); build-state imports run's, test dev's.
CACHED_TARGETS = ("dev", "run")


class BuildError(Exception):
    """A build failed: which target, which step, why."""

    def __init__(self, message: str, returncode: int = 1, *, stage: str = "",
                 step: str = "") -> None:
        super().__init__(message)
        self.returncode = returncode
        self.stage = stage  # the Dockerfile stage and docker-ros step that failed, when known
        self.step = step


def noted(interruption: KeyboardInterrupt, tagged: Sequence[str]) -> KeyboardInterrupt:
    """A Ctrl-C (or SIGTERM: tasks.Terminated) after which images of the build stay tagged
    (BuildKit had finished them): its message names them (`'dev' was built: x:1-dev`)."""
    notes = [*tagged, *([str(interruption)] if str(interruption) else [])]
    interruption.args = ("; ".join(notes),) if notes else ()
    return interruption


@dataclass(frozen=True)
class BuiltImage:
    target: str
    ref: str
    platform: str
    seconds: float


def until_ref(settings: Settings, step: str) -> str:
    """Tag of an image built up to a step: <IMAGE_NAME>:<IMAGE_TAG>-until-<step>."""
    return f"{settings.image_name}:{settings.image_tag}-until-{step}"


def dockerfile_args(dockerfile: Path = DOCKERFILE) -> List[str]:
    """Names of the ARGs the Dockerfile declares."""
    names = re.findall(r"^ARG\s+([A-Z_]+)", dockerfile.read_text(), flags=re.MULTILINE)
    return sorted(set(names))


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


def seed_builds(settings: Settings, specs: Dict[str, Dict[str, Any]], platform: str,
                dockerfile: Path, base: str, registry_cache: bool, out: IO[str]) -> str:
    """Seed the builds of specs from BUILD_STATE_FROM (see buildstate): the run image's by the
    inputs' fingerprint (a build-state target records it and the seed as labels), the test
    stage's by the pulled state. Returns the pulled state that stands as this build's build
    state ("" none)."""
    if not settings.build_state_from:
        return ""
    if "run" in specs:
        base_id = (engine.inspect_image(base) or {}).get("Id", "")
        parts = {**specs["run"]["args"], "platform": platform, "base": base_id,
                 "dockerfile": hashlib.sha256(dockerfile.read_bytes()).hexdigest()}
        fingerprint = buildstate.inputs_fingerprint(Path(settings.build_context), parts,
                                                    left_out)
        seed = buildstate.run_seed(settings, platform, fingerprint, registry_cache, out)
        if "build-state" in specs:
            specs["build-state"]["labels"] = {**specs["build-state"].get("labels", {}),
                                              buildstate.SEED_LABEL: seed.recorded,
                                              buildstate.INPUTS_LABEL: fingerprint}
    elif "test-results" in specs:
        seed = buildstate.seed_for_test(settings, platform, out)
    else:
        return ""
    for spec in specs.values():
        spec["args"].update(seed.build_args())
    return seed.reuse


def build_order(targets: Sequence[str], registry_cache: bool) -> List[str]:
    """The order of targets built one after the other: as given (dev first), but with a
    registry cache of every stage the run image and its build state first. Built after dev,
    the run build found the dev stage in the engine's own cache, and BuildKit then missed the
    colcon RUN's record in the imported registry cache (measured on an empty Engine 26: dev
    first, the colcon RUN ran; run first, every step of run, then of dev, came from the cache)."""
    first = [t for t in ("run", "build-state") if t in targets and registry_cache]
    return first + [t for t in targets if t not in first]


def build_args(settings: Settings, declared: Sequence[str]) -> Dict[str, str]:
    """The value of every declared ARG whose setting is set (docker-ros's add_arg_if_set).
    Secrets are never build arguments (they would stay in the image history)."""
    values = arg_values(settings)
    return {name: values[name] for name in declared if name in values and name.lower() in FIELDS}


def arg_values(settings: Settings) -> Dict[str, str]:
    """The settings as build arguments (as_env), without an RMW_IMPLEMENTATION nobody chose
    (config.rmw_chosen): then a base image's own stays (the Dockerfile's ENV falls back to it,
    then to the default), as with docker-ros's build.sh."""
    values = as_env(settings)
    if not rmw_chosen(settings):
        values.pop("RMW_IMPLEMENTATION", None)
    return values


# BUILDX_ATTESTATIONS (docker-ros's `--provenance` and `--sbom`) for the dev and run images;
# none for the rest (the build state, tests' and lock's results: a local output would get a
# provenance file among the results).
ATTESTATIONS = ("type=provenance,mode=min", "type=sbom")
NO_ATTESTATIONS = ("type=provenance,disabled=true",)


def definition(
    settings: Settings,
    *,
    target: str,
    platform: str,
    tools_image: str,
    tag: str,
    secrets: Mapping[str, str],
    dockerfile: Path = DOCKERFILE,
    push: bool = False,
    output: str = "",
    extra_build_args: Mapping[str, str] = {},
    imports_image: str = f"{IMPORTS_REPOSITORY}:<hash>",
    base_image: str = "",
    cache_export: str = "inline",
    contexts: Mapping[str, str] = {},
) -> Dict[str, Any]:
    """One target and platform as a `docker buildx bake` target: the single description behind
    both plan_build (one `buildx build`) and plan_bake (several targets in one BuildKit run).
    `output`: an --output exporter instead of loading or pushing the image; `base_image`: the
    platform's base (platform_base) when it is not BASE_IMAGE; `cache_export`: what CACHE_TO
    exports, `registry` or `inline` (the builder's choice, see builder.py); `contexts`: named
    build contexts (--build-context), the tools and imports images' OCI layouts for a builder
    with a BuildKit of its own (see scratch_layout)."""
    args = {"BASE_IMAGE": base_image or settings.base_image or "",
            "DOCKER_ROS_TOOLS": tools_image,
            "DOCKER_ROS_IMPORTS": imports_image,
            "DOCKER_ROS_RUN_RESOLUTION": run_resolution(settings),
            "DOCKER_ROS_RUN_BASE": run_base(settings),
            "DOCKER_ROS_SYSTEM": system_stage(settings), **source_stages(settings)}
    args.update(build_args(settings, [a for a in dockerfile_args(dockerfile) if a not in args]))
    args.update(sorted(extra_build_args.items()))
    args.update(locked_build_args(settings, target=target, platform=platform))
    target_def: Dict[str, Any] = {
        "context": str(Path(settings.build_context)),
        "dockerfile": str(dockerfile),
        "target": target,
        "platforms": [f"linux/{platform}"],
        "tags": [tag],
        "args": args,
        "secret": [f"id={i},{source}" for i, source in sorted(secrets.items())],
        "output": [output or ("type=registry" if push else "type=docker")],
    }
    if contexts:
        target_def["contexts"] = dict(contexts)
    labels = lock_labels(settings, target)
    if target == "dev":
        labels[INPUTS_LABEL] = imports_digest_of(imports_image)
    if labels:
        target_def["labels"] = labels
    if settings.build_network:
        target_def["network"] = settings.build_network
    target_def["attest"] = list(ATTESTATIONS if settings.buildx_attestations
                                and target in ("dev", "run") else NO_ATTESTATIONS)
    if settings.no_cache:
        target_def["no-cache"] = True
    if settings.cache_from:
        target_def["cache-from"] = cache_sources(settings.cache_from, target)
        target_def["cache-to"] = ["type=inline"]
    if settings.cache_to:
        cache_from, cache_to = registry_cache(settings, target, platform, tag, cache_export)
        target_def["cache-from"] = list(dict.fromkeys(
            target_def.get("cache-from", []) + cache_from))
        target_def["cache-to"] = cache_to
    return target_def


def cache_ref(settings: Settings, target: str, platform: str) -> str:
    """The registry cache of one target and platform: `<CACHE_TO>-<target>-<arch>`."""
    return f"{settings.cache_to}-{target}-{platform}"


def registry_cache(settings: Settings, target: str, platform: str, tag: str,
                   cache_export: str) -> Tuple[List[str], List[str]]:
    """(--cache-from, --cache-to) of CACHE_TO. `registry`: dev and run export every stage to
    their own cache ref (mode=max) and import it; build-state imports run's, test dev's.
    `inline`: the dev and run images carry their cache and are the cache of their next build."""
    exports = target in CACHED_TARGETS
    if cache_export != "registry":
        return ([tag], ["type=inline"]) if exports else ([], [])
    own = target if exports else "run" if target == "build-state" else "dev"
    ref = f"type=registry,ref={cache_ref(settings, own, platform)}"
    return [ref], ([f"{ref},mode=max"] if exports else [])


def run_resolution(settings: Settings) -> str:
    """The Dockerfile stage resolving the run image's dependencies."""
    return "lean-resolution" if settings.enable_lean_run_image else "resolve"


def has_identification_hook(settings: Settings) -> bool:
    return (Path(settings.build_context) / settings.before_dependency_identification_script
            ).is_file()


def system_stage(settings: Settings) -> str:
    """The Dockerfile stage resolution and the dev image's installs start from: the base, or
    with a before-dependency-identification hook the base with what the hook changed in the
    system (hooked-system), which docker-ros's installs see too. Without a hook the stages
    share nothing with the source stage, which a source edit then leaves cached."""
    return "hooked-system" if has_identification_hook(settings) else "base"


def run_base(settings: Settings) -> str:
    """The Dockerfile stage the run image's dependencies are installed on: with CACHE_FROM a
    copy of base that shares no stage with the dev image, so that on an empty machine the run
    image's registry cache serves its dependency layers too (see the Dockerfile's base-run);
    either with the hook's system changes when there is one (system_stage)."""
    stage = "base-run" if imports_cache(settings) else "base"
    return stage.replace("base", "hooked-system") if system_stage(settings) != "base" else stage


def imports_cache(settings: Settings) -> bool:
    """Whether the build imports a cache from a registry (CACHE_FROM, CACHE_TO)."""
    return bool(settings.cache_from or settings.cache_to)


def cache_sources(refs: Sequence[str], target: str) -> List[str]:
    """The CACHE_FROM refs a target imports: the dev images' (a `-dev` in the tag) for dev, the
    others for run and every other target; all refs when none is of that kind. Each image is
    the cache of its own target: BuildKit takes the first cache that matches a stage both
    targets share, so another image's records would stand for the target's own."""
    dev = [r for r in refs if "-dev" in r.rpartition(":")[2]]
    mine = dev if target == "dev" else [r for r in refs if r not in dev]
    return mine or list(refs)


def plan_build(settings: Settings, **options: Any) -> List[str]:
    """The `docker buildx build` argv for one target and platform (options: see definition)."""
    return build_argv(definition(settings, **options))


def build_argv(spec: Mapping[str, Any], buildx: Sequence[str] = BUILDX) -> List[str]:
    """A bake target's definition as one `docker buildx build` argv (buildx: the command
    reaching the builder, builder.buildx_command)."""
    argv = [*buildx, "build", "--progress=plain", "--file", spec["dockerfile"]]
    argv += ["--target", spec["target"], "--platform", spec["platforms"][0]]
    argv += ["--tag", spec["tags"][0]]
    for name, value in spec["args"].items():
        argv += ["--build-arg", f"{name}={value}"]
    for name, value in spec.get("labels", {}).items():
        argv += ["--label", f"{name}={value}"]
    for name, value in spec.get("contexts", {}).items():
        argv += ["--build-context", f"{name}={value}"]
    for secret in spec["secret"]:
        argv += ["--secret", secret]
    if "network" in spec:
        argv += ["--network", spec["network"]]
    argv += (["--provenance=false"] if list(spec["attest"]) == list(NO_ATTESTATIONS)
             else ["--provenance=mode=min", "--sbom=true"])
    if spec.get("no-cache"):
        argv += ["--no-cache"]
    for ref in spec.get("cache-from", []):
        argv += ["--cache-from", ref]
    for cache in spec.get("cache-to", []):
        argv += ["--cache-to", cache]
    exporter = spec["output"][0]
    loads = {"type=docker": "--load", "type=registry": "--push"}
    argv += [loads[exporter]] if exporter in loads else ["--output", exporter]
    argv.append(spec["context"])
    return argv


def plan_bake(targets: Mapping[str, Dict[str, Any]], definition_file: str,
              buildx: Sequence[str] = BUILDX, allow: Sequence[str] = ()) -> List[str]:
    """The `docker buildx bake` argv building the targets (bake target name -> definition,
    written as JSON to definition_file) in one BuildKit run: stages they share are built once,
    the others in parallel, from one load of the build context. allow: the entitlements the
    definition needs (bake_allow)."""
    return [*buildx, "bake", *(f"--allow={a}" for a in allow), "--progress=plain", "--file",
            definition_file, *targets]


def bake_allow(buildx: Sequence[str], settings: Settings, temporary: str) -> List[str]:
    """The entitlements to grant bake (plan_bake's allow): reading our temporary folder and the
    build context, and network.host with BUILD_NETWORK=host. From buildx 0.20 on, bake refuses
    what it is not granted ("ERROR: additional privileges requested": our Dockerfile, layouts
    and secrets are in a temporary folder, the build context may be elsewhere); a bake without
    --allow (before 0.17: Debian's 0.13) has no such check."""
    if not bake_allows(tuple(buildx)):
        return []
    allow = [f"fs.read={temporary}", f"fs.read={Path(settings.build_context).resolve()}"]
    return allow + (["network.host"] if settings.build_network == "host" else [])


@functools.lru_cache(maxsize=None)
def bake_allows(buildx: Tuple[str, ...]) -> bool:
    """Whether this buildx's bake takes --allow (its help lists it)."""
    proc = subprocess.run([*buildx, "bake", "--help"], capture_output=True, text=True)
    return "--allow" in proc.stdout


def can_bake(settings: Settings, bake_knows_network: bool) -> bool:
    """Whether one bake run can build the targets (bake_knows_network: bake_allows, buildx 0.17
    and later, whose bake has both --allow and a `network` attribute). Not with BUILD_NETWORK
    on an older bake (Debian's 0.13), which knows no `network`. Not with CACHE_FROM: in one bake
    run, which target's dependency layers missed the registry cache on an empty machine varied
    from run to run; built one after the other, dev first, the dev image's always hit
    (measured, issue 13)."""
    return not imports_cache(settings) and (not settings.build_network or bake_knows_network)


def bake_grants(buildx: Sequence[str], settings: Settings, temporary: str) -> Optional[List[str]]:
    """plan_bake's allow (bake_allow) when one bake run of this buildx can build the targets
    (can_bake), else None: one `docker buildx build` per target."""
    if not can_bake(settings, bake_allows(tuple(buildx))):
        return None
    return bake_allow(buildx, settings, temporary)


def bake_file(targets: Mapping[str, Dict[str, Any]]) -> str:
    """The bake definition (JSON). It names secrets' environment variables, never values."""
    return json.dumps({"target": dict(targets)}, indent=2, sort_keys=True) + "\n"


def shown_definition(settings: Settings, chosen: builder.Builder, *, target: str, platform: str,
                     tag: str, output: str = "", extra_build_args: Mapping[str, str] = {}
                     ) -> Dict[str, Any]:
    """definition as a dry run shows it, before the tools image and CA bundle exist, for the
    chosen builder (selected_builder): its cache export, and for one with a BuildKit of its
    own the named contexts standing for the tools and imports images (build_images_locked)."""
    tools, imports = f"{TOOLS_REPOSITORY}:<hash>", f"{IMPORTS_REPOSITORY}:<hash>"
    contexts = {ref: layout_context(Path("<temporary>/layouts"), ref, "<digest>")
                for ref in (tools, imports)} if builder.own_buildkit(chosen) else {}
    return definition(settings, target=target, platform=platform, tools_image=tools,
                      imports_image=imports, tag=tag, secrets=plan_secrets(settings, None),
                      output=output, extra_build_args=extra_build_args,
                      base_image=shown_base(settings, platform),
                      cache_export=builder.cache_export(chosen), contexts=contexts)


def plan_shown(settings: Settings, chosen: builder.Builder, **options: Any) -> List[str]:
    """plan_build as a dry run shows it, through the chosen builder (see shown_definition)."""
    return build_argv(shown_definition(settings, chosen, **options),
                      builder.buildx_command(chosen, settings.builder or ""))


def secret_env(settings: Settings) -> Dict[str, str]:
    """The environment of the buildx process that carries the secret values."""
    return {f"DOCKER_ROS_SECRET_{env_name(n)}": getattr(settings, n) for n in SECRETS
            if getattr(settings, n)}


def plan_secrets(settings: Settings, ca_bundle: Optional[Path]) -> Dict[str, str]:
    """BuildKit secret id -> source. Values come from the environment (secret_env), so the
    argv (and a dry run printing it) holds only variable names, never a secret."""
    secrets = {env_name(n): f"env=DOCKER_ROS_SECRET_{env_name(n)}" for n in SECRETS
               if getattr(settings, n)}
    if settings.extra_ca_certs:
        secrets["EXTRA_CA_CERTS"] = f"src={ca_bundle or '<bundle of EXTRA_CA_CERTS>'}"
    return secrets


def cache_id(settings: Settings, platform: str) -> str:
    """Build caches (colcon build/) are per repository and platform: object files of another
    workspace or architecture must never be reused."""
    key = f"{Path(settings.build_context).resolve()}\0{settings.image_name}\0{platform}"
    return hashlib.sha256(key.encode()).hexdigest()[:16]


def apt_cache_id(settings: Settings, platform: str) -> str:
    """apt lists and archives are shared by the builds on one base image and platform."""
    return hashlib.sha256(f"{settings.base_image}\0{platform}".encode()).hexdigest()[:16]


def mount_ids(settings: Settings, platform: str) -> Dict[str, str]:
    """The ARGs the Dockerfile uses in cache mount ids, with their values."""
    return {
        "DOCKER_ROS_CACHE_ID": cache_id(settings, platform),
        "DOCKER_ROS_APT_CACHE_ID": apt_cache_id(settings, platform),
    }


def expand_mount_ids(dockerfile: Path, ids: Mapping[str, str]) -> None:
    """Write the cache mount ids into the staged Dockerfile. The Dockerfile frontend built into
    Engine 20.10 (BuildKit v0.8) does not expand ARGs in RUN --mount options (the log shows them
    expanded, the cache id stays the literal `docker-ros-build-${DOCKER_ROS_CACHE_ID}`), so every
    repository and platform would share one build/ cache and its change record."""
    text = dockerfile.read_text()
    for name, value in ids.items():
        text = text.replace("${" + name + "}", value)
    dockerfile.write_text(text)


def _kept(lines: List[str], line: str) -> str:
    lines.append(line)
    return line


def tools_tree(destination: Path) -> str:
    """Copy the in-image modules to destination/docker-ros/lib; return their content hash."""
    digest = hashlib.sha256()
    lib = destination / "docker-ros" / "lib" / "docker_ros"
    for pattern in TOOLS_PATTERNS:
        for path in sorted(PACKAGE_DIR.glob(pattern)):
            rel = path.relative_to(PACKAGE_DIR)
            digest.update(str(rel).encode() + b"\0" + path.read_bytes() + b"\0")
            (lib / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, lib / rel)
            if path.suffix == ".sh":  # a wheel install may not keep the executable bit
                (lib / rel).chmod(0o755)
    return digest.hexdigest()[:16]


def dockerignore(context: Path) -> str:
    """The user's .dockerignore plus ours: what may hold credentials stays out of every image
    (`.env` files; git's folders, whose config may carry a CI job token or a checkout's
    authorization header; gitlab-ci-local's variables file), and so do gitlab-ci-local's
    scratch folder (copies of the repository made inside it) and the CI template's test
    results (left in a checkout a shell runner reuses). A build reads none of them."""
    user = context / ".dockerignore"
    lines = user.read_text().splitlines() if user.is_file() else []
    ours = ["# added by docker-ros", *[f"{w}{name}" for name in LEFT_OUT for w in ("", "**/")],
            SCRATCH_FOLDER]
    return "\n".join([*lines, *ours]) + "\n"


def left_out(rel: str) -> bool:
    """Whether our own .dockerignore lines (dockerignore) leave the relative path out."""
    parts = rel.split("/")
    return any(part in LEFT_OUT for part in parts) or parts[0] == SCRATCH_FOLDER


def with_run_base(text: str) -> str:
    """The Dockerfile with base-run: its base stage again, `ENV DOCKER_ROS_RUN_CHAIN=1` first, so
    that no step of it is one of base's (see run_base and the Dockerfile's DOCKER_ROS_RUN_BASE).
    Made here rather than written twice in the Dockerfile."""
    start = text.index("FROM ${BASE_IMAGE} AS base\n")
    end = text.index("\n# ----", start)
    copy = text[start:end].replace(" AS base\n", " AS base-run\nENV DOCKER_ROS_RUN_CHAIN=1\n", 1)
    return text[:end] + "\n\n" + copy + text[end:]


def stage_dockerfile(context: Path, destination: Path) -> Path:
    """Our Dockerfile beside a Dockerfile.dockerignore (BuildKit reads it instead of the
    context's .dockerignore), so the user's repository is never modified."""
    dockerfile = destination / "Dockerfile"
    dockerfile.write_text(with_run_base(DOCKERFILE.read_text()))
    (destination / "Dockerfile.dockerignore").write_text(dockerignore(context))
    return dockerfile


def ensure_tools_image(platform: str, buildx: Sequence[str] = BUILDX,
                       layouts: Optional[Path] = None) -> str:
    """A FROM-scratch image with the step modules, tagged by their content hash (one per
    docker-ros version that built here, shared by every repository: never removed by us).
    layouts: made as an OCI layout there instead (see scratch_image)."""
    with tempfile.TemporaryDirectory(prefix="docker-ros-tools-") as tmp:
        digest = tools_tree(Path(tmp))
        return scratch_image(Path(tmp), "docker-ros", f"{TOOLS_REPOSITORY}:{digest}-{platform}",
                             platform, buildx=buildx, layouts=layouts)


# The time every file of a scratch image has (SOURCE_DATE_EPOCH's usual value)
SCRATCH_MTIME = 0


def reproducible(folder: Path) -> None:
    """Give every file and folder under folder (itself too) the same time, and modes as git
    keeps them (755 for folders and executables, else 644), so that the same content makes
    the same image layer on any machine. A pip install or a temporary copy gives files the
    time they were written, so each CI runner made a tools image of other layers (measured:
    two installs of one wheel, two layer digests), and BuildKit's key for a FROM of it (the
    layers' chain) could then match no registry cache record of another runner's build."""
    for path in sorted(folder.rglob("*"), reverse=True) + [folder]:
        if not path.is_symlink():
            executable = path.is_dir() or path.stat().st_mode & 0o100
            path.chmod(0o755 if executable else 0o644)
        os.utime(path, (SCRATCH_MTIME, SCRATCH_MTIME), follow_symlinks=False)


def scratch_image(context: Path, folder: str, ref: str, platform: str, into: str = "",
                  buildx: Sequence[str] = BUILDX, labels: Mapping[str, str] = {},
                  layouts: Optional[Path] = None) -> str:
    """ref: FROM scratch with context/folder at /folder (or its contents at into), built
    (on the builder of the build, where its FROM finds it) unless it exists already.
    layouts: a builder with a BuildKit of its own (docker-container, remote) has no image
    store, so a FROM of ref would look for it on Docker Hub: it is exported as an OCI layout
    under layouts instead, which the build gets as a named context (scratch_layout)."""
    if layouts is None and image_exists(ref):
        return ref
    (context / "Dockerfile").write_text(f"FROM scratch\nCOPY {folder} {into or '/' + folder}\n")
    reproducible(context / folder)
    # The same content makes the same image, digest included (the containerd store keys a FROM
    # by it): fixed times (SOURCE_DATE_EPOCH, Engine 26's BuildKit; 20.10 keys by the layers)
    # and no provenance. So it is made afresh (--no-cache): a cache record of an earlier image
    # of this content whose layer went with that image (a superseded imports image removed,
    # then the cache pruned in part) failed the build ("layer does not exist", Engine 20.10).
    output = (["--output", f"type=oci,tar=false,dest={layout_folder(layouts, ref)}"]
              if layouts is not None else ["--load"])
    argv = [*buildx, "build", "--quiet", *output, "--no-cache", "--provenance=false",
            "--build-arg", "SOURCE_DATE_EPOCH=0", "--platform", f"linux/{platform}",
            *[a for k, v in labels.items() for a in ("--label", f"{k}={v}")],
            "--tag", ref, str(context)]
    proc = subprocess.run(argv, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(f"building {ref} failed: {proc.stderr.strip()}")
    return ref


def layout_folder(layouts: Path, ref: str) -> Path:
    """Where scratch_image puts ref's OCI layout under layouts (a folder per image)."""
    return layouts / ref.replace("/", "_").replace(":", "_")


def scratch_layout(layouts: Path, ref: str) -> str:
    """The named build context standing for ref (pinned to the image scratch_image exported
    there): `FROM ref` then reads that image, with the same digest an image store would give
    it, so cache keys stay those of a loaded image."""
    index = json.loads((layout_folder(layouts, ref) / "index.json").read_text())
    return layout_context(layouts, ref, index["manifests"][0]["digest"])


def layout_context(layouts: Path, ref: str, digest: str) -> str:
    """`oci-layout://<folder>:<tag>@<digest>`: the digest chooses the image; the tag (ref's, as
    the layout's index names it) is there for buildx 0.33.0, which turned a reference of a
    digest alone into `<store>:@<digest>` and failed ("invalid reference format",
    docker/buildx#3793); every other buildx takes the digest."""
    return f"oci-layout://{layout_folder(layouts, ref)}:{ref.rpartition(':')[2]}@{digest}"


def import_inputs(settings: Settings, repository: Path) -> List[str]:
    """What the image's upstream stage imports from: the repository's .repos files (relative
    paths), as the clone step finds them there, and with LOCKED docker-ros.lock (the commits
    it imports at). None when a before-dependency-identification hook exists: it runs first
    and may change them, so the source stage imports instead (the lock still comes along: the
    clone step of a locked build reads it, even when it imports nothing)."""
    found = [LOCK_FILE] if settings.locked and (repository / LOCK_FILE).is_file() else []
    if (repository / settings.before_dependency_identification_script).is_file():
        return found
    top = repository / settings.vcs_import_file
    if top.is_file():
        found.append(settings.vcs_import_file)
    if settings.enable_recursive_vcs_import:
        for directory in walk(repository):
            for entry in sorted(directory.glob("*.repos")):
                rel = entry.relative_to(repository).as_posix()
                if entry.is_file() and rel not in found:
                    found.append(rel)
    return found


def reads_whole_context(settings: Settings, repository: Path) -> bool:
    """Whether the image's source stage (clone, blacklist) must start from the whole build
    context: with a before-dependency-identification hook, which may change any file, or a
    .dockerignore, whose patterns skeleton_files (read here) would not apply."""
    return ((repository / settings.before_dependency_identification_script).is_file()
            or (repository / ".dockerignore").is_file())


def skeleton_files(settings: Settings, repository: Path) -> Optional[List[str]]:
    """The repository's files the source stage reads when no hook runs (the .repos files and
    what resolving reads, runtime.inputs), relative paths; None when it must read them all
    (reads_whole_context), or when a path setting is wrong: then the skeleton is empty and the
    source stage's own step reports the setting, as it would on the whole context."""
    if reads_whole_context(settings, repository):
        return None
    with tempfile.TemporaryDirectory(prefix="docker-ros-skeleton-") as tmp:
        ws = Workspace(tmp)
        ws.src.mkdir()
        ws.target.symlink_to(repository.resolve(), target_is_directory=True)
        try:
            found = resolve_inputs(ws, settings)
        except StepError:
            return None
        inputs = {p.relative_to(ws.target).as_posix() for p in found if ws.target in p.parents}
    return sorted(r for r in inputs | set(import_inputs(settings, repository)) if not left_out(r))


def source_stages(settings: Settings) -> Dict[str, str]:
    """The build arguments choosing where the source stage starts and what the dev image's
    sources come from: the skeleton (only the files clone and blacklist read, so a source edit
    runs neither, nor resolve) and the checkout with the source stage's ignore markers, unless
    the source stage must read the whole context (reads_whole_context). The dev image's sources
    lose ADDITIONAL_FILES_DIR in a stage of their own (tree-pruned), which runs on every source
    edit: only when the repository has that folder, or a hook may make it."""
    repository = Path(settings.build_context)
    if reads_whole_context(settings, repository):
        return {"DOCKER_ROS_SOURCE_START": "checkout", "DOCKER_ROS_TREE": "source",
                "DOCKER_ROS_DEV_TREE": "tree-pruned"}
    files = repository / settings.additional_files_dir
    pruned = (files.is_dir() or files.is_symlink()) and files.resolve() != repository.resolve()
    return {"DOCKER_ROS_SOURCE_START": "skeleton", "DOCKER_ROS_TREE": "marked",
            "DOCKER_ROS_DEV_TREE": "tree-pruned" if pruned else "tree-marked"}


def ensure_imports_image(settings: Settings, platform: str,
                         buildx: Sequence[str] = BUILDX, layouts: Optional[Path] = None) -> str:
    """A FROM-scratch image with the repository's .repos files at /repository and its
    skeleton_files at /inputs, tagged by their content. Each is COPY'd by the stage that
    needs it (content-addressed): the import stays cached while the .repos files do, and the
    source stage while the skeleton does. layouts: see scratch_image."""
    repository = Path(settings.build_context)
    with tempfile.TemporaryDirectory(prefix="docker-ros-imports-") as tmp:
        folders = imports_folders(settings, repository)
        for folder, files in folders.items():
            root = Path(tmp) / "context" / folder
            root.mkdir(parents=True)
            for rel in files:
                source, copy = repository / rel, root / rel
                copy.parent.mkdir(parents=True, exist_ok=True)
                copy.write_bytes(source.read_bytes())
                shutil.copymode(source, copy)  # hooks keep their executable bit
        # the repository is part of the tag too: it removes only images no other one uses
        mine = imports_owner(repository)
        ref = f"{IMPORTS_REPOSITORY}:{imports_digest(repository, folders)}-{mine[:8]}-{platform}"
        if layouts is None and image_exists(ref):
            return ref
        owner = {IMPORTS_LABEL: mine}
        scratch_image(Path(tmp), "context", ref, platform, into="/", buildx=buildx,
                      labels=owner, layouts=layouts)
    return ref


def imports_folders(settings: Settings, repository: Path) -> Dict[str, List[str]]:
    """The imports image's folders and the repository's files in each (relative paths)."""
    return {"repository": import_inputs(settings, repository),
            "inputs": skeleton_files(settings, repository) or []}


def imports_digest(repository: Path, folders: Mapping[str, Sequence[str]]) -> str:
    """The content digest of the imports image's files (16 hex digits): paths, modes (a hook's
    executable bit), contents; the layout is part of it (another version's image holds other
    folders)."""
    digest = hashlib.sha256()
    for folder, files in folders.items():
        digest.update(f"/{folder}/\0".encode())
        for rel in files:
            source = repository / rel
            mode = stat.S_IFREG | stat.S_IMODE(source.stat().st_mode)
            digest.update(f"{folder}/{rel}\0{mode:o}\0".encode() + source.read_bytes())
    return digest.hexdigest()[:16]


def imports_digest_of(ref: str) -> str:
    """The content digest in an imports image's tag (`<digest>-<owner>-<arch>`)."""
    return ref.rpartition(":")[2].split("-")[0]


def stale_dev_image(labels: Mapping[str, str], current: str, ref: str) -> str:
    """A warning when the dev image was built from other dependency inputs than the
    repository has now (a package.xml, a list file, the rosdep rules, a hook or a .repos file
    changed since), else "" (also for an image without the label: made by an older version)."""
    built = labels.get(INPUTS_LABEL, "")
    if not built or built == current:
        return ""
    return (f"docker-ros dev-shell: {ref} was built before the repository's dependency inputs "
            "changed (package.xml files, the list files, rosdep rules, hooks or .repos files): "
            "its dependencies may be out of date; `inv dev-shell --rebuild` builds it again "
            "first (from cache: only what changed)")


def remove_superseded_imports(settings: Settings, current: str) -> None:
    """The repository's other imports images of the platform go (see build_images: after a
    build, when no other build of the repository runs)."""
    owner = {IMPORTS_LABEL: imports_owner(Path(settings.build_context))}
    engine.remove_quietly(superseded_imports(engine.tags_labelled(owner), current))


def imports_owner(repository: Path) -> str:
    """The label value of a repository's imports images (its absolute path, hashed)."""
    return hashlib.sha256(str(repository.resolve()).encode()).hexdigest()[:16]


def superseded_imports(tags: Iterable[str], current: str) -> List[str]:
    """The imports images of the same repository and platform as current, which replaces
    them (one per repository and platform stays; an edit back makes its image again, a few
    KB, and its steps stay cached by content)."""
    platform = current.rpartition("-")[2]
    return sorted(t for t in tags if t != current and t.startswith(f"{IMPORTS_REPOSITORY}:")
                  and t.rpartition("-")[2] == platform)


def ca_bundle(path: Path, destination: Path) -> Path:
    """EXTRA_CA_CERTS (one PEM file or a folder of them) as one file for a BuildKit secret."""
    if not path.exists():
        raise BuildError(f"EXTRA_CA_CERTS '{path}' not found: give a PEM file or a folder of them")
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    # (the PEM blocks are ASCII: a comment in another encoding stays out of the way)
    texts = [p.read_text(errors="ignore") for p in files]
    pems = [text for text in texts if "BEGIN CERTIFICATE" in text]
    if not pems:
        raise BuildError(f"EXTRA_CA_CERTS '{path}' holds no PEM certificate")
    destination.write_text("\n".join(pems))
    destination.chmod(0o600)
    return destination


def extra_ca_bundle(settings: Settings, folder: Path, name: str = "ca.pem") -> Optional[Path]:
    """EXTRA_CA_CERTS as one file `name` in folder (ca_bundle); None when it is not set."""
    if not settings.extra_ca_certs:
        return None
    return ca_bundle(Path(settings.extra_ca_certs).expanduser(), folder / name)


def check_engine(settings: Optional[Settings] = None) -> None:
    """A Docker daemon that answers and the buildx plugin, or one message saying what to do;
    with settings, the builder too (selected_builder)."""
    try:
        buildx = subprocess.run(["docker", "buildx", "version"], capture_output=True)
    except FileNotFoundError:
        raise BuildError("no `docker` command: install Docker (scripts/setup.sh)") from None
    if buildx.returncode != 0:
        raise BuildError("the docker buildx plugin is missing: install it (scripts/setup.sh)")
    if settings is not None:
        selected_builder(settings)
    try:
        engine.client()
    except engine.EngineError as exc:
        raise BuildError(str(exc)) from None


def selected_builder(settings: Settings) -> builder.Builder:
    """The builder of this run (BUILDER, BUILDX_BUILDER or the current one), inspected once.
    (buildx exports a registry cache with the CLI's credentials: the task's login, see
    cli.tasks.settings_task.)"""
    try:
        return builder.selected(settings.builder or "", bool(settings.cache_to),
                                settings.buildx_attestations)
    except builder.BuilderError as exc:
        raise BuildError(str(exc)) from None




def build_images(settings: Settings, **options: Any) -> List[BuiltImage]:
    """Build the targets (target -> tag) for one platform, by default in one `docker buildx
    bake` run (bake=False or not can_bake: one `docker buildx build` per target, one after the
    other, as docker-ros does); raise BuildError naming the failed step. Then the repository's
    other imports images of the platform go, unless another build of the repository is running:
    its BuildKit may not have read its own yet (removed, it looked for it on Docker Hub). Each
    build holds a shared lock on the build context folder (flock: nothing written) meanwhile."""
    folder = os.open(str(Path(settings.build_context).expanduser().resolve()), os.O_RDONLY)
    try:
        with contextlib.suppress(OSError):  # (a file system without flock: no lock)
            fcntl.flock(folder, fcntl.LOCK_SH)
        built, imports = build_images_locked(settings, **options)
        try:
            fcntl.flock(folder, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return built  # (the last build of the repository to end removes them)
        except OSError:
            pass
        remove_superseded_imports(settings, imports)
        return built
    finally:
        os.close(folder)


def build_images_locked(
    settings: Settings,
    *,
    targets: Mapping[str, str],
    platform: str,
    out: IO[str] = sys.stdout,
    environ: Optional[Mapping[str, str]] = None,
    push: bool = False,
    output: str = "",
    extra_build_args: Mapping[str, str] = {},
    bake: bool = True,
) -> Tuple[List[BuiltImage], str]:
    """build_images' builds; (the images, the imports image they used)."""
    environ = os.environ if environ is None else environ
    chosen = selected_builder(settings)
    attested = settings.buildx_attestations and not output and bool({"dev", "run"} & set(targets))
    dropped = attested and builder.attestations_dropped(chosen, environ)
    if dropped:
        raise BuildError(f"BUILDX_ATTESTATIONS=true: {dropped}")
    export = builder.cache_export(chosen)
    buildx = builder.buildx_command(chosen, settings.builder or "")
    child_env = dict(environ)
    child_env.setdefault("DOCKER_BUILDKIT", "1")
    with tempfile.TemporaryDirectory(prefix="docker-ros-build-") as tmp:
        layouts = Path(tmp) / "layouts" if builder.own_buildkit(chosen) else None
        tools = ensure_tools_image(platform, buildx, layouts=layouts)
        imports = ensure_imports_image(settings, platform, buildx, layouts=layouts)
        contexts = ({ref: scratch_layout(layouts, ref) for ref in (tools, imports)}
                    if layouts is not None else {})
        tag_local_base(settings, platform)
        # Passed by environment to buildx only: never argv, never a file, never a log.
        child_env.update(secret_env(settings))
        bundle = extra_ca_bundle(settings, Path(tmp))
        pin_args, pin_secrets = prepare_pin_secrets(settings, platform, Path(tmp))
        dockerfile = stage_dockerfile(Path(settings.build_context), Path(tmp))
        expand_mount_ids(dockerfile, mount_ids(settings, platform))
        base, why = platform_base(settings, platform)
        if why:
            print(why, file=out)
        # a local base image such a builder will not see (named if its lookup fails)
        unseen = [base] if layouts is not None and base and image_exists(base) else []
        specs = {target: definition(settings, target=target, platform=platform,
                                    tools_image=tools, tag=tag,
                                    secrets={**plan_secrets(settings, bundle), **pin_secrets},
                                    push=push, dockerfile=dockerfile, output=output,
                                    extra_build_args={**extra_build_args, **pin_args},
                                    imports_image=imports, base_image=base,
                                    cache_export=export, contexts=contexts)
                 for target, tag in targets.items()}
        built: List[BuiltImage] = []
        reused = seed_builds(settings, specs, platform, dockerfile, base,
                             export == "registry", out)
        if reused and "build-state" in specs:
            try:
                engine.tag(reused, targets["build-state"])
            except engine.EngineError as exc:
                raise BuildError(str(exc)) from None
            del specs["build-state"]
            built.append(BuiltImage("build-state", targets["build-state"], platform, 0.0))
        allow = bake_grants(buildx, settings, tmp) if bake else None
        if allow is not None:
            definition_file = Path(tmp) / "docker-ros.bake.json"
            definition_file.write_text(bake_file(specs))
            runs = [(tuple(specs), plan_bake(specs, str(definition_file), buildx, allow))]
        else:
            runs = [((t,), build_argv(specs[t], buildx))
                    for t in build_order(list(specs), export == "registry")]
        for names, argv in runs:
            try:
                seconds = run_buildx(argv, {t: targets[t] for t in names}, platform,
                                     env=child_env, out=out, environ=environ,
                                     network=settings.build_network or "", unseen=unseen)
            except BuildError as exc:
                raise with_built(exc, built) from None
            except KeyboardInterrupt as exc:
                raise noted(exc, built_notes(built)) from None
            built += [BuiltImage(t, targets[t], platform, seconds) for t in names]
    return built, imports


def with_built(error: BuildError, built: Sequence[BuiltImage]) -> BuildError:
    """error, naming also the images that earlier buildx runs of the same build tagged (one
    run per target: CACHE_FROM, BUILD_NETWORK on an old bake), as run_buildx names those of its
    own run."""
    if not built:
        return error
    return BuildError("; ".join([str(error), *built_notes(built)]),
                      error.returncode, stage=error.stage, step=error.step)


def with_sources(error: BuildError, settings: Settings) -> BuildError:
    """error, saying where a setting it names came from when the build cannot tell: a step
    that names `ROS_DISTRO=noetic` is not told that the value is the shell's (a sourced ROS
    setup exports it), which the user may not know they gave."""
    name = "ros_distro"
    value, source = getattr(settings, name), settings.source_of(name)
    if not value or source == "default" or f"ROS_DISTRO={value}" not in str(error):
        return error
    where = {"environment": "the environment, where a sourced ROS setup file exports it",
             "flag": "a flag"}.get(source, source)
    return BuildError(f"{error} (ROS_DISTRO={value} comes from {where})", error.returncode,
                      stage=error.stage, step=error.step)


def built_note(target: str, ref: str) -> str:
    """How a message names an image that was built and tagged before a failure or Ctrl-C."""
    return f"{target!r} was built: {ref}"


def built_notes(built: Sequence[BuiltImage]) -> List[str]:
    return [built_note(image.target, image.ref) for image in built]


def build_image(settings: Settings, *, target: str, platform: str, tag: str,
                **options: Any) -> BuiltImage:
    """Build one target for one platform (options: see build_images)."""
    return build_images(settings, targets={target: tag}, platform=platform, bake=False,
                        **options)[0]


def run_buildx(argv: Sequence[str], targets: Mapping[str, str], platform: str, *,
               env: Mapping[str, str], out: IO[str], environ: Mapping[str, str],
               network: str = "", unseen: Sequence[str] = ()) -> float:
    """Run one buildx command (targets: target -> tag), its log folded into out; its seconds,
    or a BuildError (network: BUILD_NETWORK, for the hint of a step that found none; unseen:
    local images the builder cannot see, for the hint of a lookup that failed)."""
    # A plain header, not a group: GitHub cannot nest groups, and the steps are groups.
    header = ", ".join(f"{t} -> {tag}" for t, tag in targets.items())
    out.write(f"==> docker-ros build ({platform}) {header}\n")
    began = time.monotonic()
    lines: List[str] = []
    # (with: the pipe is closed however the build ends)
    with subprocess.Popen(list(argv), env=dict(env), stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, bufsize=1) as proc:
        assert proc.stdout is not None
        log = (_kept(lines, line) for line in iter(proc.stdout.readline, ""))
        try:
            errors = buildlog.stream_build(log, out, environ)
            code = proc.wait()
        except KeyboardInterrupt as exc:
            # buildx got the same Ctrl-C: let it cancel the build and end (what it had named
            # by then stays tagged: said in the message)
            proc.terminate()
            proc.wait()
            raise noted(exc, [built_note(t, tag) for t, tag in targets.items()
                              if buildlog.tagged_in_log(lines, tag)]) from None
    done = [t for t, tag in targets.items() if buildlog.tagged_in_log(lines, tag)]
    if code != 0 and buildlog.cancelled(lines) and not buildlog.engine_lost(lines):
        # as if we had seen the Ctrl-C that stopped buildx
        raise noted(KeyboardInterrupt(), [built_note(t, targets[t]) for t in done])
    if code != 0:
        stage, step = buildlog.failed_step(lines)
        failed = [t for t in targets if t not in done]
        what = "target" if len(failed) == 1 else "targets"
        raise BuildError(f"building {what} {', '.join(repr(t) for t in failed)} ({platform}) "
                         f"{buildlog.failure_reason(lines, errors, network, unseen)}"
                         + "".join(f"; {built_note(t, targets[t])}" for t in done),
                         code, stage=stage, step=step)
    return time.monotonic() - began


def summary_table(images: Sequence[BuiltImage]) -> str:
    rows = [("IMAGE", "TAG", "PLATFORM", "SIZE", "BUILD TIME")]
    for image in images:
        name, _, tag = image.ref.rpartition(":")
        size = image_size(image.ref)
        rows.append((name, tag, image.platform, f"{size / 1e6:.0f} MB" if size else "-",
                     f"{image.seconds:.1f} s"))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)
