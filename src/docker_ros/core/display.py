"""Showing settings and what they require: values, environment, registries, the reference table."""

from __future__ import annotations

import re
from typing import Dict, Iterable, List, Mapping, Optional

from docker_ros.core.settings import (
    FIELDS,
    MASKED,
    Settings,
    SettingsError,
    env_name,
    flag_name,
    is_secret,
    text_of,
)


def missing_required(settings: Settings, names: Iterable[str]) -> str:
    """One line naming every required value that is missing ('' when none is)."""
    missing = [env_name(n) + ("" if settings.source_of(n) == "default"
                              else f" (empty, from {settings.source_of(n)})")
               for n in names if not getattr(settings, n)]
    if not missing:
        return ""
    pronoun = "it" if len(missing) == 1 else "them"
    return (f"missing required configuration: {', '.join(missing)} (set {pronoun} in .env, the "
            "environment, invoke.yaml under docker_ros: or as flags)")


def require(settings: Settings, names: Iterable[str]) -> None:
    """Fail with one message listing every required value that is missing."""
    message = missing_required(settings, names)
    if message:
        raise SettingsError(message)


def made_images(settings: Settings) -> List[str]:
    """The images TARGET makes: dev and run as listed, then slim when the run image is slimmed
    (ENABLE_SLIM, which a `slim` target sets)."""
    images = [t for t in settings.target if t != "slim"]
    return images + ["slim"] if settings.enable_slim and "run" in images else images


def required_for_build(settings: Settings) -> List[str]:
    return ["base_image"] + (["command"] if "run" in settings.target else [])


# The names of Docker Hub's registry.
DOCKER_HUB_HOSTS = ("docker.io", "index.docker.io", "registry-1.docker.io")


def ref_host(ref: str) -> str:
    """The registry host an image reference names: its first part when that is a host name
    (`reg.example/`, `reg:5000/`, `localhost/`), else '' (a Docker Hub name)."""
    first, slash, _ = ref.partition("/")
    return first if slash and ("." in first or ":" in first or first == "localhost") else ""


def registry_of(host: str) -> str:
    """A registry host as docker means it: Docker Hub's names (and none) as `docker.io`."""
    return "docker.io" if host in ("", *DOCKER_HUB_HOSTS) else host


def server_host(address: str) -> str:
    """The host[:port] of a server setting (GIT_HTTPS_SERVER, REGISTRY): scheme and path
    dropped."""
    return re.sub(r"^[a-z]+://", "", address).split("/")[0]


def display_value(settings: Settings, name: str) -> str:
    value = getattr(settings, name)
    if is_secret(name) and value:
        return MASKED
    return text_of(value)


def as_env(settings: Settings, *, include_secrets: bool = False) -> Dict[str, str]:
    """The settings that are set, as docker-ros environment variables (unset stay unset)."""
    out: Dict[str, str] = {}
    for name in FIELDS:
        if is_secret(name) and not include_secrets:
            continue
        value = getattr(settings, name)
        if value is None or value == () or value == "":
            continue
        out[env_name(name)] = text_of(value)
    return out


def default_doc(name: str) -> str:
    f = FIELDS[name]
    if f.metadata["default_doc"]:
        return str(f.metadata["default_doc"])
    default = f.default
    if default is None or default == "":
        return ""
    if isinstance(default, bool):
        return "`true`" if default else "`false`"
    if isinstance(default, tuple):
        return "`" + ",".join(default) + "`"
    return f"`{default}`"


def markdown_table(flag_tasks: Optional[Mapping[str, str]] = None) -> str:
    """The configuration reference table, derived from the declarations; flag_tasks says which
    tasks have a setting as a flag, in words (others are reached with --set NAME=VALUE)."""
    flag_tasks = flag_tasks or {}
    rows = ["| variable | flag | default | description |", "|---|---|---|---|"]
    for name, f in FIELDS.items():
        if is_secret(name):
            flag = "none: environment or `.env` only"
        elif f.metadata["group"] == "ci":
            flag = "none: read by the CI integrations only"
        elif flag_tasks.get(name):
            flag = f"`{flag_name(name)}` ({flag_tasks[name]})"
        else:
            flag = f"`--set {env_name(name)}=...`"
        help_text = str(f.metadata["help"])
        extras = []
        if f.metadata["choices"]:
            extras.append("values: " + ", ".join(f"`{c}`" for c in f.metadata["choices"]))
        if f.metadata["secret"]:
            extras.append("secret: masked, never passed as build argument")
        if extras:
            help_text += " (" + "; ".join(extras) + ")"
        cells = [f"`{env_name(name)}`", flag, default_doc(name), help_text]
        rows.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(rows)
