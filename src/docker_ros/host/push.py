"""Pushing built images with docker-ros's tag rules: plan (pure, written as the equivalent
docker commands that --dry-run prints) and run."""

from __future__ import annotations

import json
import subprocess
from typing import Any, Collection, Dict, List, Mapping, Optional, Sequence

from docker_ros.core.display import made_images, ref_host, registry_of, server_host
from docker_ros.core.errors import BuildError
from docker_ros.core.loading import host_platform
from docker_ros.core.settings import Settings, env_name
from docker_ros.host import engine
from docker_ros.host.refs import image_ref, slim_platforms, target_ref
from docker_ros.host.slim import LABEL_SOURCE
from docker_ros.in_image.runtime.workspace import format_argv


def also_ref(ref: str, tag: str, target: str, postfix: str = "") -> str:
    """The name pushed for an extra tag (`latest`, a git tag): `<tag>` for run, `<tag>-dev`,
    `<tag>-slim` (docker-ros's ENABLE_PUSH_AS_LATEST and tag-pipeline names); a tag that ends
    in the postfix gets the target before it (`latest-dev_<slug>_ci`, as docker-ros's)."""
    name = ref.rsplit(":", 1)[0] if ":" in ref.rsplit("/", 1)[-1] else ref
    if target not in ("dev", "slim"):
        return f"{name}:{tag}"
    stem = "latest" if postfix and tag == f"latest{postfix}" else tag
    return f"{name}:{stem}-{target}{tag[len(stem):]}"


def push_targets(settings: Settings) -> List[str]:
    """TARGET's images (made_images: slim after run when ENABLE_SLIM, as docker-ros's CI
    pushes it), the build state after run with BUILD_STATE_FROM."""
    targets = made_images(settings)
    if "run" in targets and settings.build_state_from:
        targets.insert(targets.index("run") + 1, "build-state")
    return targets


def official_only_names(settings: Settings, targets: Sequence[str]) -> List[str]:
    """Pushed names with neither registry nor namespace (`my-image`): docker pushes them to
    Docker Hub's `library/`, where only Docker's official images go. One line each, said
    before anything is built (the push failed after the build and the slimming)."""
    names: Dict[str, str] = {}  # name -> its setting (IMAGE_NAME's first: dev's comes from it)
    for target in sorted(targets, key=lambda t: t != "run"):
        field = f"{target}_image_name" if target in ("dev", "slim") else "image_name"
        names.setdefault(str(getattr(settings, field)), env_name(field))
    registry = settings.registry or "registry.example.com"
    out = []
    for name, variable in names.items():
        if "/" in name:
            continue
        # IMAGE sets IMAGE_NAME (and the others' defaults); DEV/SLIM_IMAGE_NAME are their own
        set_as, tag = ("IMAGE", ":tag") if variable == "IMAGE_NAME" else (variable, "")
        out.append(f"{variable} {name!r} names no registry and no namespace: docker would push "
                   f"it to docker.io/library/{name}, which takes Docker's official images only; "
                   f"name your registry ({set_as}={registry}/{name}{tag}) or Docker Hub user "
                   f"({set_as}=<user>/{name}{tag})")
    return out


def pushed_names(settings: Settings, target: str) -> List[str]:
    """The configured name of a target and its extra tags (Settings.push_also_as)."""
    ref = image_ref(settings, target)
    names = [ref] + [also_ref(ref, tag, target, settings.image_postfix or "")
                     for tag in settings.push_also_as]
    return list(dict.fromkeys(names))  # IMAGE_TAG latest and ENABLE_PUSH_AS_LATEST: once


def manifest_commands(names: Sequence[str], arch_refs: Sequence[str]) -> List[List[str]]:
    """One manifest list per name over the per-architecture images (already in the registry).

    `docker buildx imagetools create` works in the registry only: it keeps no local store whose
    stale lists could stand for what the registry holds now (`docker manifest` does), it takes
    per-architecture refs that are themselves image indexes (attestations, the containerd
    image store) and lists their platform images, where `docker manifest create` refuses them,
    and it talks plain http to a loopback registry without flags."""
    return [["docker", "buildx", "imagetools", "create", "--tag", name, *arch_refs]
            for name in names]


def ref_registry(ref: str) -> str:
    """The registry docker pushes ref to (Docker Hub: `docker.io`)."""
    return registry_of(ref_host(ref))


def registry_warning(settings: Settings, targets: Sequence[str]) -> str:
    """A warning when the login (REGISTRY, Docker Hub when it is unset and REGISTRY_USER and
    REGISTRY_PASSWORD are set) is not where the images go: those pushes get no such credentials
    ('' when they match, or there is no login)."""
    credentials = bool(settings.registry_user and settings.registry_password)
    if not (settings.registry or credentials):
        return ""
    wanted = registry_of(server_host(settings.registry or ""))
    names = [image_ref(settings, t) for t in targets if t != "build-state"]
    elsewhere = [name for name in dict.fromkeys(names) if ref_registry(name) != wanted]
    if not elsewhere:
        return ""
    where = ref_registry(elsewhere[0])
    login = (f"REGISTRY is {wanted} (the login)" if settings.registry
             else "REGISTRY is unset (the login goes to Docker Hub)")
    unsent = (", without REGISTRY_USER/REGISTRY_PASSWORD (only your docker configuration's "
              "own login there counts)" if credentials else "")
    fix = (f"put {wanted}/ in front of IMAGE/IMAGE_NAME to push there" if settings.registry
           else f"set REGISTRY={where} to log in there")
    return (f"warning: {login}, but {', '.join(elsewhere)} "
            f"{'goes' if len(elsewhere) == 1 else 'go'} to "
            f"{'Docker Hub' if where == 'docker.io' else where}{unsent}: {fix}")


def plan_push(settings: Settings, targets: Sequence[str], *, host: str = "") -> List[List[str]]:
    """docker commands that push the built TARGET images for every PLATFORM (slim: those of
    slim_platforms on host, default this machine)."""
    platforms = settings.platform
    commands: List[List[str]] = []
    for target in targets:
        names = pushed_names(settings, target)
        if target == "build-state":
            # one per architecture, under the name the next job pulls (BUILD_STATE_FROM)
            commands += [["docker", "push", target_ref(settings, target, p)] for p in platforms]
            continue
        here = slim_platforms(platforms, host or host_platform()) if target == "slim" else (
            tuple(platforms))
        if settings.enable_singlearch_push or len(here) == 1:
            # ENABLE_SINGLEARCH_PUSH: only `<name>-<arch>`, as docker-ros: the runner of one
            # architecture must not overwrite the multi-arch name (`docker-ros manifest` writes
            # it later). Slim of several platforms: the runner's image under the slim names.
            for platform in here:
                local = target_ref(settings, target, platform)
                for name in names:
                    name = f"{name}-{platform}" if settings.enable_singlearch_push else name
                    if name != local:
                        commands.append(["docker", "tag", local, name])
                    commands.append(["docker", "push", name])
            continue
        # Several platforms: the per-arch images (`-amd64`, `-arm64`) go to the registry, as the
        # manifest list refers to them; then one manifest list per name.
        arch_refs = [target_ref(settings, target, p) for p in platforms]
        commands += [["docker", "push", arch] for arch in arch_refs]
        commands += manifest_commands(names, arch_refs)
    return commands


def plan_manifest(settings: Settings, targets: Sequence[str],
                  left_out: Collection[str] = ()) -> List[List[str]]:
    """Manifest lists over the `<name>-<arch>` images that per-architecture jobs pushed with
    ENABLE_SINGLEARCH_PUSH (one job per PLATFORM entry). The slim lists leave out the slim
    images of left_out (slim_left_out: absent, or an earlier pipeline's)."""
    commands: List[List[str]] = []
    for target in targets:
        ref = image_ref(settings, target)
        arch_refs = [f"{ref}-{platform}" for platform in settings.platform]
        if target == "slim":
            arch_refs = [arch for arch in arch_refs if arch not in left_out]
        if arch_refs:
            commands += manifest_commands(pushed_names(settings, target), arch_refs)
    return commands


def remote_image(ref: str, *form: str) -> Optional[Dict[str, Any]]:
    """What the registry holds under ref, as `docker buildx imagetools inspect` prints it with
    form (`--raw`: the manifest as stored; `--format {{json .}}`: its descriptor and image
    configuration); None when it has no such image. LookupError when buildx could not say
    (left to the manifest command, which then says why)."""
    proc = subprocess.run(["docker", "buildx", "imagetools", "inspect", *form, ref],
                          capture_output=True, text=True)
    if proc.returncode != 0 and proc.stderr.rstrip().endswith(": not found"):
        return None
    try:
        found = json.loads(proc.stdout) if proc.returncode == 0 else None
    except ValueError:
        found = None
    if not isinstance(found, dict) or not found:
        raise LookupError(proc.stderr.strip())
    return found


SUMMARY = ("--format", "{{json .}}")


def slimmed_from(slim: Mapping[str, Any], run: Mapping[str, Any],
                 run_raw: Mapping[str, Any]) -> bool:
    """Was the slim image (buildx's summary) made from the run image (summary and stored
    manifest)? Its label names the run image's local ID: the configuration's digest in the
    classic image store, the manifest's (or index's) in the containerd one."""
    image = slim.get("image") or {}
    configs = [image] if "config" in image else list(image.values())
    sources = {(c.get("config") or {}).get("Labels", {}).get(LABEL_SOURCE) for c in configs}
    ids = {(run.get("manifest") or {}).get("digest"), (run_raw.get("config") or {}).get("digest")}
    return bool(sources & ids - {None})


def slim_left_out(settings: Settings) -> Dict[str, str]:
    """The `<slim name>-<arch>` images the slim lists leave out, each with why: absent from the
    registry (a job on a runner of another architecture slims nothing), or slimmed from
    another image than this pipeline's `<run name>-<arch>` (an earlier pipeline's, when this
    one slimmed nothing for that architecture)."""
    slim_ref, run_ref = image_ref(settings, "slim"), image_ref(settings, "run")
    left: Dict[str, str] = {}
    for platform in settings.platform:
        arch, run_arch = f"{slim_ref}-{platform}", f"{run_ref}-{platform}"
        try:
            slim = remote_image(arch, *SUMMARY)
            if slim is None:
                left[arch] = ("is not in the registry (a job on a runner of another "
                              "architecture slims nothing)")
                continue
            run, run_raw = remote_image(run_arch, *SUMMARY), remote_image(run_arch, "--raw")
        except LookupError:
            continue
        if run is not None and run_raw is not None and not slimmed_from(slim, run, run_raw):
            left[arch] = (f"was not slimmed from {run_arch} (it is an earlier pipeline's; "
                          "this one slimmed nothing for it)")
    return left


def plan_outputs(
    settings: Settings, targets: Sequence[str], pushed: Mapping[str, str]
) -> Dict[str, str]:
    """CI outputs naming the pushed images: `images` (all but the build states,
    comma-separated) and per target `image`/`dev-image`/`slim-image`/`build-state-image` (its
    configured name, or `<name>-<arch>` if only that); for those whose digest is known (pushed:
    name -> digest, '' unknown) also `digest`/`dev-digest`/`slim-digest`/`build-state-digest`
    (that image's) and `digests` (JSON: each name of `images` -> its digest)."""
    states = [f"{image_ref(settings, 'build-state')}-{p}" for p in settings.platform]
    outputs = {"images": ",".join(n for n in pushed if n not in states)}
    for target in targets:
        ref = image_ref(settings, target)
        mine = [n for n in [ref] + [f"{ref}-{p}" for p in settings.platform] if n in pushed]
        if mine:
            prefix = "" if target == "run" else f"{target}-"
            outputs[f"{prefix}image"] = mine[0]
            if pushed[mine[0]]:
                outputs[f"{prefix}digest"] = pushed[mine[0]]
    known = {name: digest for name, digest in pushed.items() if name not in states and digest}
    if known:
        outputs["digests"] = json.dumps(known, sort_keys=True)
    return outputs


def write_outputs(outputs: Mapping[str, str], environ: Mapping[str, str]) -> None:
    """As GitHub step outputs (the action's outputs), when GITHUB_OUTPUT names the file."""
    path = environ.get("GITHUB_OUTPUT")
    if not path:
        return
    with open(path, "a", encoding="utf-8") as out:
        for key, value in outputs.items():
            out.write(f"{key}={value}\n")


def auth_config(settings: Settings, ref: str) -> Optional[Dict[str, str]]:
    """REGISTRY_USER/REGISTRY_PASSWORD for pushing ref through the Engine API (in memory, per
    request), only when ref goes to REGISTRY (Docker Hub when it is unset), the registry
    `docker login` files them for: the engine would offer them to any registry. A push
    elsewhere gets None, so the docker configuration's own login for that registry counts."""
    if not (settings.registry_user and settings.registry_password):
        return None
    if ref_registry(ref) != registry_of(server_host(settings.registry or "")):
        return None
    auth = {"username": settings.registry_user, "password": settings.registry_password}
    return {**auth, "serveraddress": settings.registry} if settings.registry else auth


def push(settings: Settings, targets: Sequence[str], *, dry_run: bool) -> Dict[str, str]:
    """Push; return the pushed names with their digests. Fails with the command and docker's
    reason."""
    return run_commands(settings, plan_push(settings, targets), dry_run=dry_run, label="push")


def manifest(settings: Settings, targets: Sequence[str], *, dry_run: bool) -> Dict[str, str]:
    """Write the manifest lists (plan_manifest); return their names with their digests."""
    left_out = slim_left_out(settings) if "slim" in targets and not dry_run else {}
    for arch, why in left_out.items():
        print(f"manifest: {arch} {why}: the slim lists leave it out", flush=True)
    commands = plan_manifest(settings, targets, left_out)
    return run_commands(settings, commands, dry_run=dry_run, label="manifest")


def execute(argv: List[str], settings: Settings) -> str:
    """One planned command: tag and push through the Engine API (REGISTRY's credentials in the
    request, auth_config), manifest lists through buildx (the API has none); the digest of
    what it pushed ('' none, or unknown)."""
    try:
        if argv[:2] == ["docker", "tag"]:
            engine.tag(argv[2], argv[3])
            return ""
        if argv[:2] == ["docker", "push"]:
            return engine.push(argv[2], auth_config(settings, argv[2]))
    except engine.EngineError as exc:
        raise BuildError(str(exc) + auth_hint(str(exc))) from None
    proc = subprocess.run(argv, capture_output=True, text=True)
    if proc.returncode != 0:
        reason = (proc.stderr.strip() or proc.stdout.strip()).splitlines()
        last = reason[-1] if reason else "no reason given"
        raise BuildError(f"{format_argv(argv)} failed with exit code {proc.returncode}: "
                         f"{last}{auth_hint(last)}")
    return list_digest(argv[argv.index("--tag") + 1]) if is_manifest(argv) else ""


def list_digest(name: str) -> str:
    """The digest of a manifest list in the registry ('' when buildx cannot say)."""
    try:
        found = remote_image(name, *SUMMARY)
    except LookupError:
        return ""
    return str(((found or {}).get("manifest") or {}).get("digest") or "")


# How registries and the engine say that the request had no (valid) credentials.
AUTH_REFUSALS = ("no basic auth credentials", "unauthorized", "authentication required",
                 "denied")


def auth_hint(reason: str) -> str:
    """What to check when the registry refused the credentials (or got none), else ''."""
    if any(word in reason.lower() for word in AUTH_REFUSALS):
        return ("; the registry wants a login: check REGISTRY, REGISTRY_USER and "
                "REGISTRY_PASSWORD (and that the user may push there)")
    return ""


def is_manifest(argv: Sequence[str]) -> bool:
    return list(argv[:4]) == ["docker", "buildx", "imagetools", "create"]


def run_commands(
    settings: Settings, commands: Sequence[List[str]], *, dry_run: bool, label: str
) -> Dict[str, str]:
    """Run the docker commands in order; return the names pushed to the registry, each with
    its digest ('' unknown)."""
    if dry_run:
        for argv in commands:
            print(f"[dry-run] {label}:", format_argv(argv))
        return {}
    pushed = {}
    for argv in commands:
        print(f"{label}:", format_argv(argv), flush=True)
        digest = execute(argv, settings)
        if argv[1] == "push":
            pushed[argv[-1]] = digest
        elif is_manifest(argv):
            pushed[argv[argv.index("--tag") + 1]] = digest
    return pushed
