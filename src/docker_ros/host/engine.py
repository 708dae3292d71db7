"""The Docker Engine API (docker SDK) for what it does well: ping, inspect, pull, tag, push and
remove. Builds go through the buildx CLI (the SDK drives only the legacy builder: no BuildKit
mounts or secrets) and manifest lists through `docker buildx imagetools` (the Engine API has
none)."""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import re
import shlex
import signal
import threading
from pathlib import Path
from types import ModuleType
from typing import (
    TYPE_CHECKING,
    Any,
    Dict,
    Iterable,
    Iterator,
    List,
    Mapping,
    Optional,
    Sequence,
    Tuple,
)

from docker_ros.core.errors import DockerRosError

if TYPE_CHECKING:
    import docker
    from docker.models.containers import Container


def sdk() -> ModuleType:
    """The docker SDK (its errors, utils and models come with it), imported on first use."""
    # (start-up: the docker SDK and requests/urllib3 cost ~0.1-0.3 s; `--help`, `--list` and
    # the tasks that never reach the engine do not need them)
    import docker
    return docker


def parse_repository_tag(ref: str) -> Tuple[str, Optional[str]]:
    """The docker SDK's split of a reference into repository and tag."""
    repository, name_tag = sdk().utils.parse_repository_tag(ref)
    return repository, name_tag


class EngineError(DockerRosError):
    """The engine refused or failed: what, and docker's reason."""


DEFAULT_HOST = "unix:///var/run/docker.sock"


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Ctrl-C (SIGINT) and SIGTERM wait until the block is done, then arrive as usual. Around
    the creation of a container and the assignment of it to the variable a `finally` removes:
    a signal between the engine's answer and the assignment left the container behind (and
    `sleep infinity` or COMMAND running in it). Held by a Python handler, not the thread's
    signal mask: with another thread running, the kernel gives a signal to a thread that does
    not block it, and Python then raises it in the main thread all the same."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: List[int] = []
    held_signals = (signal.SIGINT, signal.SIGTERM)
    previous = {number: signal.signal(number, lambda number, _frame: held.append(number))
                for number in held_signals}
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, signal.SIG_DFL if handler is None else handler)
        if held:
            signal.raise_signal(held[0])


# The engine the images are in when it is not the CLI's (bind): a docker-driver builder of
# another docker context keeps what it builds there.
_bound: Dict[str, str] = {}


def docker_config_dir(environ: Mapping[str, str]) -> Path:
    return Path(environ.get("DOCKER_CONFIG") or Path.home() / ".docker")


def current_context(environ: Mapping[str, str]) -> str:
    """The docker context the CLI uses: DOCKER_CONTEXT, else config.json's currentContext."""
    if environ.get("DOCKER_CONTEXT"):
        return environ["DOCKER_CONTEXT"]
    try:
        config = json.loads((docker_config_dir(environ) / "config.json").read_text())
    except (OSError, ValueError):
        return "default"
    name = config.get("currentContext") if isinstance(config, dict) else None
    return name if isinstance(name, str) and name else "default"


def context_host(name: str, environ: Mapping[str, str]) -> Optional[str]:
    """The Docker endpoint of a docker context (its meta.json in the CLI's context store), or
    None for `default` and for a context this store does not hold."""
    if name == "default":
        return None
    meta = (docker_config_dir(environ) / "contexts" / "meta"
            / hashlib.sha256(name.encode()).hexdigest() / "meta.json")
    try:
        host = json.loads(meta.read_text())["Endpoints"]["docker"]["Host"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return str(host) if host else None


def cli_host(environ: Mapping[str, str]) -> str:
    """The engine the docker CLI talks to: DOCKER_HOST, else the current docker context's
    endpoint, else the local socket (the docker SDK alone reads only DOCKER_HOST)."""
    return (environ.get("DOCKER_HOST") or context_host(current_context(environ), environ)
            or DEFAULT_HOST)


def bind(host: Optional[str]) -> None:
    """Talk to the engine at host from now on (None: the CLI's, cli_host)."""
    if _bound.get("host") != host:
        _bound.pop("host", None)
        if host:
            _bound["host"] = host
        client.cache_clear()


@functools.lru_cache(maxsize=1)
def client() -> docker.DockerClient:
    """A client of the engine the CLI talks to (cli_host: DOCKER_HOST or the current docker
    context, so that both reach the same engine) or the one bound, checked to answer."""
    host = _bound.get("host")
    docker_sdk = sdk()
    try:
        if host is None and os.environ.get("DOCKER_HOST"):
            engine = docker_sdk.from_env()  # with DOCKER_TLS_VERIFY/DOCKER_CERT_PATH
        else:
            host = host or cli_host(os.environ)
            engine = docker_sdk.DockerClient(base_url=host, use_ssh_client=host.startswith("ssh:"))
        engine.ping()
    except docker_sdk.errors.DockerException:
        where = host or os.environ.get("DOCKER_HOST") or "the default socket"
        raise EngineError(f"no Docker daemon answers at {where}: start it, e.g. with "
                          "scripts/setup.sh") from None
    return engine


def answered() -> bool:
    """Whether an engine answered in this process (client() holds a client that pinged)."""
    return client.cache_info().currsize > 0


def inspect_image(ref: str) -> Optional[Dict[str, Any]]:
    """`docker image inspect` of a local image, or None when there is none; an EngineError
    when the engine refuses (an invalid reference)."""
    try:
        return dict(client().images.get(ref).attrs)
    except (sdk().errors.ImageNotFound, sdk().errors.NotFound):
        return None
    except sdk().errors.APIError as exc:
        raise EngineError(f"docker image inspect {ref}: {exc.explanation or exc}") from None


def image_exists(ref: str) -> bool:
    return inspect_image(ref) is not None


def tags_labelled(labels: Mapping[str, str]) -> List[str]:
    """The tags of the local images that carry all these labels (none if the engine cannot
    say: housekeeping)."""
    with contextlib.suppress(sdk().errors.DockerException):
        found = client().images.list(filters={"label": [f"{k}={v}" for k, v in labels.items()]})
        return [tag for image in found for tag in image.tags]
    return []


def local_tags() -> List[str]:
    """The tags of every local image (none if the engine cannot say: a hint, not a check). The
    raw list: images.list() inspects each image and fails when one is removed meanwhile."""
    with contextlib.suppress(sdk().errors.DockerException):
        return [tag for image in client().api.images() for tag in image.get("RepoTags") or []
                if tag != "<none>:<none>"]
    return []


def remove_quietly(refs: Iterable[str], *, force: bool = False) -> None:
    """Remove tags (or images) this tool made, as housekeeping: whatever the engine says is not
    an error."""
    for ref in refs:
        with contextlib.suppress(sdk().errors.DockerException):
            client().images.remove(ref, force=force, noprune=False)


def image_size(ref: str) -> int:
    attrs = inspect_image(ref)
    return int(attrs["Size"]) if attrs else 0


def pull(ref: str) -> bool:
    """Pull ref; False when the registry refuses or cannot be reached."""
    return pull_error(ref) is None


def pull_error(ref: str) -> Optional[str]:
    """Pull ref; None when it was pulled, else the engine's answer (the registry's refusal)."""
    repository, tag = parse_repository_tag(ref)
    try:
        client().images.pull(repository, tag=tag or "latest")
    except sdk().errors.DockerException as exc:
        explanation = getattr(exc, "explanation", None)
        return str(explanation or exc).strip() or type(exc).__name__
    return None


def local_or_pulled(ref: str) -> bool:
    """ref is a local image, or one pulled now."""
    return image_exists(ref) or pull(ref)


def tag(source: str, target: str) -> None:
    repository, name_tag = parse_repository_tag(target)
    try:
        client().images.get(source).tag(repository, tag=name_tag or "latest")
    except sdk().errors.DockerException as exc:
        raise EngineError(f"tagging {source} as {target} failed: {exc}") from None


# The push's last status line (`1: digest: sha256:... size: 855`): the only place an engine on
# the containerd image store (Engine 26) names the digest; the classic store also sends it as
# the `aux` event's Digest.
PUSHED_DIGEST = re.compile(r": digest: (sha256:[0-9a-f]{64}) size: \d+")


def pushed_digest(event: Mapping[str, Any]) -> str:
    """The digest a push's progress event names, or ''."""
    aux = (event.get("aux") or {}).get("Digest")
    if aux:
        return str(aux)
    match = PUSHED_DIGEST.search(str(event.get("status") or ""))
    return match.group(1) if match else ""


def push(ref: str, auth: Optional[Dict[str, str]] = None) -> str:
    """Push ref; the digest of its manifest in the registry ('' if the engine named none).
    Credentials go to the engine in the request, never to a file or command line."""
    repository, name_tag = parse_repository_tag(ref)
    digest = ""
    try:
        events: Iterable[Dict[str, Any]] = client().images.push(
            repository, tag=name_tag or "latest", auth_config=auth, stream=True, decode=True)
        for event in events:
            if "error" in event:
                raise EngineError(f"docker push {ref} failed: {event['error']}")
            digest = pushed_digest(event) or digest
    except sdk().errors.DockerException as exc:
        raise EngineError(f"docker push {ref} failed: {exc}") from None
    return digest


def remove_image(ref: str) -> None:
    """Remove a tag this tool made; a missing one is fine."""
    with contextlib.suppress(sdk().errors.ImageNotFound, sdk().errors.NotFound):
        client().images.remove(ref, noprune=False)


# Containers (slim's trace, check and probes)
@contextlib.contextmanager
def engine_errors(doing: str) -> Iterator[None]:
    """An Engine API error while `doing` something becomes an EngineError saying what and why."""
    try:
        yield
    except sdk().errors.DockerException as exc:
        raise EngineError(f"{doing} failed: {getattr(exc, 'explanation', None) or exc}") from None


def container(name: str) -> Container:
    with engine_errors(f"inspecting container {name}"):
        return client().containers.get(name)


def remove_container(name: str) -> None:
    with contextlib.suppress(sdk().errors.DockerException):
        client().containers.get(name).remove(force=True)


def container_state(name: str) -> Tuple[bool, int]:
    state = container(name).attrs["State"]
    return bool(state["Running"]), int(state["ExitCode"])


def logs(name: str) -> str:
    with engine_errors(f"reading the logs of {name}"):
        return bytes(container(name).logs(stdout=True, stderr=True)).decode(errors="replace")


def run_once(image: str, argv: Sequence[str], env: Sequence[str]) -> Tuple[int, str]:
    """`docker run --rm`: a container of image running argv; (exit status, its output)."""
    with engine_errors(f"running {shlex.join(argv)[:100]} in {image}"):
        once = None
        try:
            with signals_held():
                once = client().containers.create(image, list(argv), environment=list(env))
            once.start()
            code = int(once.wait(timeout=300)["StatusCode"])
            return code, bytes(once.logs(stdout=True, stderr=True)).decode(errors="replace")
        finally:
            if once is not None:
                once.remove(force=True)
