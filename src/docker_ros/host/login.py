"""Registry login for a task that reaches a registry (CI jobs and local builds alike): `docker
login` before the build (a private BASE_IMAGE, CACHE_FROM and BUILD_STATE_FROM need it, as in
docker-ros), into a DOCKER_CONFIG private to the task that is removed when it ends, so no
credential stays on a shared or self-hosted runner or in the user's own docker config."""

from __future__ import annotations

import contextlib
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Dict, Iterator, List, Mapping, MutableMapping, Optional

from docker_ros.core.display import registry_of, server_host
from docker_ros.core.errors import DockerRosError
from docker_ros.core.settings import Settings
from docker_ros.host.engine import docker_config_dir

# Set while a job's login is in force: the registry and user it logged in as.
LOGGED_IN = "DOCKER_ROS_LOGGED_IN"
# Set once a task said that only half of the credentials are set (the job's later tasks do not).
HALF_WARNED = "DOCKER_ROS_HALF_CREDENTIALS_WARNED"
# How long a login that is not required may take (a registry out of reach, e.g. behind a VPN,
# must not hold up a build from local images for docker's own connection timeouts).
OPTIONAL_LOGIN_SECONDS = 20.0


DOCKER_HUB_INDEX = "https://index.docker.io/v1/"  # where docker files a Docker Hub login


class LoginError(DockerRosError):
    """`docker login` refused the credentials or could not reach the registry."""


def plan_login(settings: Settings) -> Optional[List[str]]:
    """`docker login` argv (the password goes to standard input); None without credentials."""
    if not (settings.registry_user and settings.registry_password):
        return None
    argv = ["docker", "login", "--username", settings.registry_user, "--password-stdin"]
    return argv + [settings.registry] if settings.registry else argv


def half_credentials(settings: Settings) -> str:
    """A line saying which of REGISTRY_USER/REGISTRY_PASSWORD is missing when only one is set
    (no login then: a CI variable that is empty on this branch, e.g. a protected one), else ''."""
    user, password = bool(settings.registry_user), bool(settings.registry_password)
    if user == password:
        return ""
    given, missing = (("REGISTRY_USER", "REGISTRY_PASSWORD") if user
                      else ("REGISTRY_PASSWORD", "REGISTRY_USER"))
    return (f"{given} is set but {missing} is empty: no docker login to "
            f"{settings.registry or 'Docker Hub'} (only the docker configuration's own logins "
            f"count); set {missing} (in CI: is the variable protected or masked away on this "
            "branch?) or leave both empty")


def private_config(config: Mapping[str, Any], registry: str) -> Dict[str, Any]:
    """The user's config.json for the job: their logins, credential store and settings, but the
    registry's credentials in the file (an empty credential helper means the file to docker):
    `docker login` would put the password in the store, outside the job's folder."""
    helpers = {**(config.get("credHelpers") or {}), **{k: "" for k in credential_keys(registry)}}
    return {**config, "credHelpers": helpers}


def credential_keys(registry: str) -> List[str]:
    """The names docker's CLI may file the registry's login under: as given, its host name
    (scheme and path dropped), and Docker Hub's index address for Docker Hub."""
    host = server_host(registry)
    hub = registry_of(host) == "docker.io"
    keys = [registry, host] + ([DOCKER_HUB_INDEX] if hub else [])
    return list(dict.fromkeys(k for k in keys if k))


def mirror_docker_config(source: Path, target: Path, registry: str) -> None:
    """A copy of the user's config.json (their other logins, current context) and links to the
    rest (cli-plugins such as buildx, buildx's current builder, contexts): login writes to the
    copy only."""
    target.mkdir(parents=True, exist_ok=True)
    if not source.is_dir():
        return
    for entry in source.iterdir():
        if entry.name == "config.json":
            try:
                config = json.loads(entry.read_text())
            except (OSError, ValueError):
                config = {}  # docker's own login would fail on it alike; start afresh
            config = config if isinstance(config, dict) else {}
            (target / entry.name).write_text(json.dumps(private_config(config, registry)))
        else:
            (target / entry.name).symlink_to(entry)


def docker_login(argv: List[str], password: str, registry: str,
                 timeout: Optional[float] = None) -> None:
    try:
        proc = subprocess.run(argv, input=password, capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        raise LoginError(f"docker login to {registry or 'Docker Hub'} as {argv[3]} got no "
                         f"answer in {timeout:.0f} s") from None
    if proc.returncode != 0:
        reason = proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "no reason given"
        # docker echoes no password; the reason is the registry's or the daemon's
        raise LoginError(f"docker login to {registry or 'Docker Hub'} as {argv[3]} failed: "
                         f"{reason}; check REGISTRY, REGISTRY_USER and REGISTRY_PASSWORD")


@contextlib.contextmanager
def job_login(
    settings: Settings, environ: MutableMapping[str, str], *, label: str, required: bool = True
) -> Iterator[None]:
    """Log in for the duration of a task: DOCKER_CONFIG in environ (which the task's docker
    commands and subprocesses inherit) names a private folder, removed afterwards. A login that
    is not `required` (the task may need no registry: a build from local images, offline) and
    fails is a warning, and the task goes on with the user's own docker configuration."""
    argv = plan_login(settings)
    login = f"{settings.registry} {settings.registry_user}"
    if argv is None and half_credentials(settings) and not environ.get(HALF_WARNED):
        print(f"{label}: warning: {half_credentials(settings)}", file=sys.stderr, flush=True)
        environ[HALF_WARNED] = "1"  # once a job: `ci` runs its tasks as processes
    # A task of a job that logged in (`ci` runs `push` as a process) uses that login.
    if argv is None or environ.get(LOGGED_IN) == login:
        yield
        return
    folder = Path(tempfile.mkdtemp(prefix="docker-ros-login-"))
    previous = {name: environ.get(name) for name in ("DOCKER_CONFIG", LOGGED_IN)}
    try:
        mirror_docker_config(docker_config_dir(environ), folder / "config",
                             settings.registry or "https://index.docker.io/v1/")
        environ["DOCKER_CONFIG"] = str(folder / "config")
        try:
            docker_login(argv, settings.registry_password or "", settings.registry or "",
                         timeout=None if required else OPTIONAL_LOGIN_SECONDS)
        except LoginError as exc:
            if required:
                raise
            print(f"{label}: {exc}; going on without it (a private image of that registry "
                  "will not be pullable)", file=sys.stderr, flush=True)
            restore(environ, previous)
        else:
            environ[LOGGED_IN] = login
            print(f"{label}: logged in to {settings.registry or 'Docker Hub'} as "
                  f"{settings.registry_user} (task-private DOCKER_CONFIG, removed at the end)",
                  flush=True)
        yield
    finally:
        restore(environ, previous)
        shutil.rmtree(folder, ignore_errors=True)


def restore(environ: MutableMapping[str, str], previous: Mapping[str, Optional[str]]) -> None:
    for name, value in previous.items():
        if value is None:
            environ.pop(name, None)
        else:
            environ[name] = value
