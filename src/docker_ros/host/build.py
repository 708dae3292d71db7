"""Running image builds with docker buildx (BuildKit): the argv from buildplan (pure), the refs
from refs, the context images from buildcontext; its log: buildlog."""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Dict, List, Mapping, Optional, Sequence, Tuple

from docker_ros.core.errors import BuildError
from docker_ros.core.settings import Settings
from docker_ros.host import builder, buildlog, buildmeta, buildstate, engine, faults, unchanged
from docker_ros.host.buildcontext import (
    _kept,
    additional_files_pattern,
    ensure_imports_image,
    ensure_tools_image,
    extra_ca_bundle,
    left_out,
    remove_superseded_imports,
    scratch_layout,
    stage_dockerfile,
)
from docker_ros.host.buildplan import (
    bake_file,
    bake_grants,
    build_argv,
    build_order,
    definition,
    expand_mount_ids,
    mount_ids,
    plan_bake,
    plan_secrets,
    secret_env,
)
from docker_ros.host.engine import image_exists, image_size
from docker_ros.host.labels import build_labels
from docker_ros.host.lockpins import prepare_pin_secrets, tag_local_base
from docker_ros.host.refs import platform_base


def noted(interruption: KeyboardInterrupt, tagged: Sequence[str]) -> KeyboardInterrupt:
    """A Ctrl-C (or SIGTERM: settingstask.Terminated) after which images of the build stay tagged
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
    digest: str = ""  # buildx's metadata file's (buildmeta), '' unknown
    cached: Tuple[int, int] = (0, 0)  # stage steps of its buildx run: (from the cache, in all)
    reused: bool = False  # the image was up to date: not built again (unchanged, slim)


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
    cli.settingstask.settings_task.)"""
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
        left = additional_files_pattern(settings)
        dockerfile = stage_dockerfile(Path(settings.build_context), Path(tmp),
                                      [left] if left else [])
        expand_mount_ids(dockerfile, mount_ids(settings, platform))
        base, why = platform_base(settings, platform)
        if why:
            print(why, file=out)
        labels = build_labels(settings, environ)
        # a local base image such a builder will not see (named if its lookup fails)
        unseen = [base] if layouts is not None and base and image_exists(base) else []
        specs = {target: definition(settings, target=target, platform=platform,
                                    tools_image=tools, tag=tag,
                                    secrets={**plan_secrets(settings, bundle), **pin_secrets},
                                    push=push, dockerfile=dockerfile, output=output,
                                    extra_build_args={**extra_build_args, **pin_args},
                                    imports_image=imports, base_image=base,
                                    cache_export=export, contexts=contexts,
                                    labels=labels.get(target, {}))
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
        record, inputs = Path(), {}  # type: Tuple[Path, Dict[str, str]]
        job = unchanged.in_job(environ)
        if unchanged.applies(settings, targets, push=push, output=output,
                             own_buildkit=layouts is not None, in_job=job):
            record, inputs = recorded_inputs(settings, specs, platform, dockerfile, environ,
                                             {"base": base, "tools": tools, "imports": imports},
                                             in_job=job)
            kept = up_to_date(record, inputs, {t: targets[t] for t in specs}, platform, out)
            if kept:
                return built + kept, imports
        allow = bake_grants(buildx, settings, tmp) if bake else None
        if allow is not None:
            definition_file = Path(tmp) / "docker-ros.bake.json"
            definition_file.write_text(bake_file(specs))
            metadata = Path(tmp) / "metadata.json"
            runs = [(tuple(specs), metadata,
                     plan_bake(specs, str(definition_file), buildx, allow, str(metadata)))]
        else:
            runs = [((t,), Path(tmp) / f"metadata-{t}.json",
                     build_argv(specs[t], buildx, str(Path(tmp) / f"metadata-{t}.json")))
                    for t in build_order(list(specs), export == "registry")]
        for names, metadata, argv in runs:
            lines: List[str] = []
            try:
                seconds = run_buildx(argv, {t: targets[t] for t in names}, platform,
                                     env=child_env, out=out, environ=environ,
                                     network=settings.build_network or "", unseen=unseen,
                                     kept=lines)
            except BuildError as exc:
                raise with_built(exc, built) from None
            except KeyboardInterrupt as exc:
                raise noted(exc, built_notes(built)) from None
            digests = buildmeta.image_digests(buildmeta.read_metadata(metadata), names)
            cached = buildlog.cached_steps(lines)
            built += [BuiltImage(t, targets[t], platform, seconds, digests.get(t, ""), cached)
                      for t in names]
    if inputs:
        # (not a build state the seed found built from these inputs: it was tagged, not built)
        unchanged.write(record, {image.ref: {"inputs": inputs[image.ref], "digest": image.digest,
                                             "id": image_id(image.ref)}
                                 for image in built if image.ref in inputs})
    return built, imports


def image_id(ref: str) -> str:
    """The id of the local image ref ("" none, or no engine to ask: then the build runs)."""
    try:
        return str((engine.inspect_image(ref) or {}).get("Id", "")) if ref else ""
    except engine.EngineError:
        return ""


def recorded_inputs(settings: Settings, specs: Mapping[str, Dict[str, Any]], platform: str,
                    dockerfile: Path, environ: Mapping[str, str], images: Mapping[str, str],
                    *, in_job: bool = False) -> Tuple[Path, Dict[str, str]]:
    """The record of this repository's builds and each tag's inputs (see unchanged); no inputs
    when an image the build starts from is not in the engine (a base only in a registry: its
    tag may name a newer image there), except in a CI job: there its name stands for it (the
    job's own build pulled it minutes before)."""
    ids = {name: image_id(ref) or (ref if in_job else "") for name, ref in images.items()}
    if not all(ids.values()):
        return Path(), {}
    context = Path(settings.build_context)
    # (stage_dockerfile's two files: the Dockerfile and the dockerignore BuildKit reads)
    staged = b"".join(p.read_bytes() for p in (dockerfile, dockerfile.with_suffix(".dockerignore")))
    # (buildx passes SOURCE_DATE_EPOCH from the environment to the build as an argument)
    ids["SOURCE_DATE_EPOCH"] = environ.get("SOURCE_DATE_EPOCH", "")
    shared = unchanged.shared_inputs(staged, buildstate.inputs_fingerprint(context, {}, left_out),
                                     ids)
    record = unchanged.record_path(engine.cli_host(environ), context, platform, environ)
    return record, {spec["tags"][0]: unchanged.target_inputs(spec, str(dockerfile.parent), shared)
                    for spec in specs.values()}


# How a build says its images were up to date (the bench reads it)
UP_TO_DATE = ": up to date, built from these same inputs"


def up_to_date(record: Path, inputs: Mapping[str, str], targets: Mapping[str, str],
               platform: str, out: IO[str]) -> List[BuiltImage]:
    """The images of targets as they are, when the record says they were built from these
    same inputs (and says so on out); [] when they must be built."""
    kept = unchanged.read(record)
    if not unchanged.up_to_date(kept, inputs, {tag: image_id(tag) for tag in inputs}):
        return []
    print(f"==> docker-ros build ({platform}) {', '.join(targets)}{UP_TO_DATE} "
          f"({', '.join(targets.values())}); not rebuilt (NO_CACHE=true rebuilds)", file=out)
    return [BuiltImage(t, tag, platform, 0.0, kept["images"][tag].get("digest", ""),
                       reused=True) for t, tag in targets.items()]


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
               network: str = "", unseen: Sequence[str] = (),
               kept: Optional[List[str]] = None) -> float:
    """Run one buildx command (targets: target -> tag), its log folded into out; its seconds,
    or a BuildError (network: BUILD_NETWORK, for the hint of a step that found none; unseen:
    local images the builder cannot see, for the hint of a lookup that failed; kept: gets the
    log's lines)."""
    # A plain header, not a group: GitHub cannot nest groups, and the steps are groups.
    header = ", ".join(f"{t} -> {tag}" for t, tag in targets.items())
    out.write(f"==> docker-ros build ({platform}) {header}\n")
    began = time.monotonic()
    lines: List[str] = [] if kept is None else kept
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
        reason = buildlog.failure_reason(lines, errors, network, unseen)
        shown = [] if buildlog.engine_lost(lines) else \
            faults.build_lines(lines, faults.engine_data_root, reason)
        raise BuildError(faults.with_lines(
            f"building {what} {', '.join(repr(t) for t in failed)} ({platform}) {reason}"
            + "".join(f"; {built_note(t, targets[t])}" for t in done), shown),
            code, stage=stage, step=step)
    return time.monotonic() - began


def summary_table(images: Sequence[BuiltImage]) -> str:
    rows = [("IMAGE", "TAG", "PLATFORM", "SIZE", "BUILD TIME")]
    for image in images:
        name, _, tag = image.ref.rpartition(":")
        size = image_size(image.ref)
        rows.append((name, tag, image.platform, f"{size / 1e6:.0f} MB" if size else "-",
                     "up to date" if image.reused else f"{image.seconds:.1f} s"))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)
