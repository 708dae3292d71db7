"""The buildx builder a build runs on (BUILDER, BUILDX_BUILDER or the current one): what its
driver can export as cache, where `--load` puts the images, and which engine holds them."""

from __future__ import annotations

import functools
import json
import os
import subprocess
from dataclasses import dataclass
from typing import List, Mapping, Optional, Tuple

from docker_ros.core.errors import DockerRosError
from docker_ros.host import engine

# Drivers whose BuildKit is not an engine's own: --load copies the image into the CLI's engine.
CONTAINER_DRIVERS = ("docker-container", "remote", "kubernetes")
CONTAINERD_STORE = "io.containerd.snapshotter"


class BuilderError(DockerRosError):
    """The builder cannot be found or used: which one and what to do."""


@dataclass(frozen=True)
class Builder:
    name: str  # as buildx names it ("default", a docker context, a `docker buildx create` name)
    driver: str  # docker, docker-container, remote, kubernetes
    endpoint: str  # the node's endpoint: a docker context name or an address
    host: str  # the engine a docker driver builds in ("" for the other drivers)
    containerd_store: bool  # that engine stores images in containerd (docker driver only)


def parse_inspect(text: str) -> Tuple[str, str, str]:
    """(name, driver, first node's endpoint) from `docker buildx inspect` output."""
    fields: dict = {}
    for line in text.splitlines():
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    return fields.get("Name", ""), fields.get("Driver", ""), fields.get("Endpoint", "")


def endpoint_host(endpoint: str, environ: Mapping[str, str]) -> str:
    """The engine address of a docker-driver node's endpoint (a docker context or an address)."""
    if "://" in endpoint:
        return endpoint
    if endpoint == "default":
        return environ.get("DOCKER_HOST") or engine.DEFAULT_HOST
    return engine.context_host(endpoint, environ) or endpoint


def cache_export(builder: Builder) -> str:
    """`registry` when the builder can export a registry cache of every stage (mode=max): a
    BuildKit of its own, or an engine's on the containerd image store; else `inline` (the
    classic store's docker driver answers "Cache export is not supported for the docker
    driver")."""
    if builder.driver in CONTAINER_DRIVERS or builder.containerd_store:
        return "registry"
    return "inline"


def own_buildkit(builder: Builder) -> bool:
    """Whether the builder runs a BuildKit of its own (docker-container, remote, kubernetes):
    it has no image store, so a FROM finds only what a registry or a named context holds."""
    return builder.driver in CONTAINER_DRIVERS


def images_host(builder: Builder, cli_host: str) -> Optional[str]:
    """The engine the built images are in when it is not the CLI's: a docker driver keeps
    them in its own engine. None: the CLI's engine (where --load copies them otherwise)."""
    if builder.driver == "docker" and builder.host and builder.host != cli_host:
        return builder.host
    return None


def images_cli(builder: Builder, cli_host: str) -> List[str]:
    """The docker command that reaches the engine holding the built images (for the `docker
    run`s we run and print): the CLI's own, or `docker --context NAME` for a docker context of
    another engine (`docker --host` if the builder names no context)."""
    host = images_host(builder, cli_host)
    if host is None:
        return ["docker"]
    if builder.name in ("", "default"):
        return ["docker", "--host", host]
    return ["docker", "--context", builder.name]


def describe(builder: Builder, cli_host: str, cache_to: bool) -> str:
    """The one line naming the builder, what --load means there and the cache choice."""
    if builder.driver in CONTAINER_DRIVERS:
        where = (f"built in its own BuildKit ({builder.endpoint}); --load copies each image "
                 f"into the local engine at {cli_host}")
    elif images_host(builder, cli_host):
        where = (f"docker driver of the engine at {builder.host}: --load keeps the images in "
                 "that engine, not the local one; push sends them to the registry from there")
    else:
        where = f"docker driver of the local engine at {builder.host or cli_host}"
    store = ", containerd image store" if builder.containerd_store else ""
    line = f"builder: {builder.name} ({where}{store})"
    if cache_to:
        how = ("registry cache of every stage (mode=max)" if cache_export(builder) == "registry"
               else "inline cache only (the docker driver of an engine on the classic image "
               "store cannot export a registry cache: turn on the engine's containerd image "
               "store, or set BUILDER to a docker-container builder)")
        line += f"; CACHE_TO: {how}"
    return line


def run_docker(argv: list, environ: Mapping[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(argv, capture_output=True, text=True, env=dict(environ))


def containerd_store(host: str, environ: Mapping[str, str]) -> bool:
    """Whether the engine at host keeps images in containerd (docker info's driver-type)."""
    info = run_docker(["docker", "--host", host, "info", "--format", "{{json .DriverStatus}}"],
                      environ)
    return info.returncode == 0 and CONTAINERD_STORE in info.stdout


def inspect(name: str, environ: Mapping[str, str]) -> Builder:
    """The builder buildx would use: name (BUILDER), else BUILDX_BUILDER, else the current."""
    argv = ["docker", "buildx", "inspect"] + ([name] if name else [])
    proc = run_docker(argv, environ)
    if proc.returncode != 0:
        reason = (proc.stderr.strip() or "no reason given").splitlines()[-1]
        which = f"'{name}'" if name else "the current one"
        raise BuilderError(f"buildx builder {which} cannot be used: {reason} (BUILDER names a "
                           "builder of `docker buildx ls` or a docker context)")
    found, driver, endpoint = parse_inspect(proc.stdout)
    host = endpoint_host(endpoint, environ) if driver == "docker" else ""
    return Builder(found or name, driver, endpoint, host,
                   bool(host) and containerd_store(host, environ))


def chosen_elsewhere(environ: Mapping[str, str]) -> bool:
    """Whether anything but BUILDER may pick another builder than the local engine's own:
    BUILDX_BUILDER, a docker context, or `docker buildx use` (buildx's `current` file)."""
    if environ.get("BUILDX_BUILDER") or engine.current_context(environ) != "default":
        return True
    try:
        current = json.loads((engine.docker_config_dir(environ) / "buildx" / "current"
                              ).read_text())
    except (OSError, ValueError):
        return False
    return bool(isinstance(current, dict) and current.get("Name"))


def attestations_dropped(builder: Builder, environ: Mapping[str, str]) -> str:
    """Why the images would lose their attestations (SBOM, provenance) before the push, or ''.
    They are loaded into an engine and pushed from there, and only an engine on the containerd
    image store keeps them (the classic store's docker driver refuses them outright)."""
    host = builder.host if builder.driver == "docker" else engine.cli_host(environ)
    store = builder.containerd_store if builder.driver == "docker" else bool(host) and (
        containerd_store(host, environ))
    if store:
        return ""
    return (f"the images are loaded into the engine at {host} and pushed from there, and its "
            "classic image store keeps no attestations (SBOM, provenance): turn on its "
            'containerd image store (daemon.json: "features": {"containerd-snapshotter": '
            "true}) or set BUILDX_ATTESTATIONS=false")


@functools.lru_cache(maxsize=None)
def selected(name: str, cache_to: bool, attestations: bool = False) -> Builder:
    """The builder of this run, inspected once: the SDK client follows the engine holding the
    images, and one line says which builder, what --load means there and the cache choice.
    A plain local build (no builder chosen anywhere, no CACHE_TO, no attestations: whose image
    store matters) costs no inspection."""
    if not name and not (cache_to or attestations) and not chosen_elsewhere(os.environ):
        return Builder("default", "docker", "default", engine.cli_host(os.environ), False)
    builder = inspect(name, os.environ)
    cli_host = engine.cli_host(os.environ)
    engine.bind(images_host(builder, cli_host))
    print(describe(builder, cli_host, cache_to), flush=True)
    return builder



def buildx_command(builder: Builder, requested: str) -> List[str]:
    """The argv prefix reaching the builder: a docker context's own (docker driver) builder
    only through `docker --context NAME buildx` (buildx refuses `--builder` for a context that
    is not the current one), any other by `--builder` (BUILDER) or by BUILDX_BUILDER."""
    if builder.driver == "docker" and builder.name not in ("", "default"):
        return ["docker", "--context", builder.name, "buildx"]
    return ["docker", "buildx", *(["--builder", requested] if requested else [])]
