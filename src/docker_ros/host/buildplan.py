"""The build plan, pure: build arguments, bake definitions, caches, secrets and mount ids."""

from __future__ import annotations

import functools
import hashlib
import json
import re
import subprocess
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

from docker_ros.core.display import as_env
from docker_ros.core.settings import FIELDS, Settings, build_secrets, env_name
from docker_ros.host import builder
from docker_ros.host.buildcontext import (
    BUILDX,
    DOCKERFILE,
    IMPORTS_REPOSITORY,
    INPUTS_LABEL,
    TOOLS_REPOSITORY,
    imports_digest_of,
    layout_context,
    source_stages,
)
from docker_ros.host.config import rmw_chosen
from docker_ros.host.labels import build_labels
from docker_ros.host.lockpins import lock_labels, locked_build_args
from docker_ros.host.refs import shown_base

SECRETS = build_secrets()
# The targets that export a registry cache (CACHE_TO); build-state imports run's, test dev's.
CACHED_TARGETS = ("dev", "run")


def dockerfile_args(dockerfile: Path = DOCKERFILE) -> List[str]:
    """Names of the ARGs the Dockerfile declares."""
    names = re.findall(r"^ARG\s+([A-Z_]+)", dockerfile.read_text(), flags=re.MULTILINE)
    return sorted(set(names))


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
    labels: Mapping[str, str] = {},
) -> Dict[str, Any]:
    """One target and platform as a `docker buildx bake` target: the single description behind
    both plan_build (one `buildx build`) and plan_bake (several targets in one BuildKit run).
    `output`: an --output exporter instead of loading or pushing the image; `base_image`: the
    platform's base (platform_base) when it is not BASE_IMAGE; `cache_export`: what CACHE_TO
    exports, `registry` or `inline` (the builder's choice, see builder.py); `contexts`: named
    build contexts (--build-context), the tools and imports images' OCI layouts for a builder
    with a BuildKit of its own (see scratch_layout); `labels`: the image's (labels.py), under
    docker-ros's own. Labels are the final image's metadata: no RUN step's cache key holds
    them."""
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
    labels = {**labels, **lock_labels(settings, target)}
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


def build_argv(spec: Mapping[str, Any], buildx: Sequence[str] = BUILDX,
               metadata_file: str = "") -> List[str]:
    """A bake target's definition as one `docker buildx build` argv (buildx: the command
    reaching the builder, builder.buildx_command; metadata_file: where buildx writes what it
    made, buildmeta.py reads it)."""
    argv = [*buildx, "build", "--progress=plain", "--file", spec["dockerfile"]]
    argv += ["--metadata-file", metadata_file] if metadata_file else []
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
              buildx: Sequence[str] = BUILDX, allow: Sequence[str] = (),
              metadata_file: str = "") -> List[str]:
    """The `docker buildx bake` argv building the targets (bake target name -> definition,
    written as JSON to definition_file) in one BuildKit run: stages they share are built once,
    the others in parallel, from one load of the build context. allow: the entitlements the
    definition needs (bake_allow); metadata_file: as build_argv's, one entry per target."""
    metadata = ["--metadata-file", metadata_file] if metadata_file else []
    return [*buildx, "bake", *(f"--allow={a}" for a in allow), "--progress=plain", *metadata,
            "--file", definition_file, *targets]


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
                      cache_export=builder.cache_export(chosen), contexts=contexts,
                      labels=build_labels(settings).get(target, {}))


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
