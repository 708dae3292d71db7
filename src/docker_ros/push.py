"""Pushing built images with docker-ros's tag rules: plan (pure, written as the equivalent
docker commands that --dry-run prints) and run."""

from __future__ import annotations

import subprocess
from typing import Dict, List, Optional, Sequence

from docker_ros import engine
from docker_ros.build import BuildError, image_ref, platform_ref
from docker_ros.settings import Settings
from docker_ros.steps.common import format_argv

LOCAL_REGISTRIES = ("localhost", "127.0.0.1")


def latest_ref(ref: str, target: str) -> str:
    """ENABLE_PUSH_AS_LATEST: `latest` for run, `latest-dev` for dev, `latest-slim` for slim."""
    name = ref.rsplit(":", 1)[0] if ":" in ref.rsplit("/", 1)[-1] else ref
    return f"{name}:latest" if target == "run" else f"{name}:latest-{target}"


def push_targets(settings: Settings) -> List[str]:
    """TARGET, plus slim after run when ENABLE_SLIM (as docker-ros's CI pushes it)."""
    targets = list(settings.target)
    return targets + ["slim"] if settings.enable_slim and "run" in targets else targets


def insecure(ref: str) -> List[str]:
    """`docker manifest` talks plain http to a loopback registry only with --insecure."""
    host = ref.split("/", 1)[0].split(":")[0]
    return ["--insecure"] if "/" in ref and host in LOCAL_REGISTRIES else []


def plan_push(settings: Settings, targets: Sequence[str]) -> List[List[str]]:
    """docker commands that push the built TARGET images for every PLATFORM."""
    platforms = settings.platform
    commands: List[List[str]] = []
    for target in targets:
        ref = image_ref(settings, target)
        names = [ref] + ([latest_ref(ref, target)] if settings.enable_push_as_latest else [])
        if len(platforms) == 1:
            if settings.enable_singlearch_push:  # for a manifest made later from arch runners
                names.append(f"{ref}-{platforms[0]}")
            for name in names:
                if name != ref:
                    commands.append(["docker", "tag", ref, name])
                commands.append(["docker", "push", name])
            continue
        # Several platforms: the per-arch images (`-amd64`, `-arm64`) go to the registry, as the
        # manifest list refers to them; then one manifest list per name.
        arch_refs = [platform_ref(ref, p, platforms) for p in platforms]
        commands += [["docker", "push", arch] for arch in arch_refs]
        for name in names:
            commands.append(["docker", "manifest", "create", *insecure(name), "--amend", name,
                             *arch_refs])
            commands.append(["docker", "manifest", "push", *insecure(name), name])
    return commands


def auth_config(settings: Settings) -> Optional[Dict[str, str]]:
    """REGISTRY_USER/REGISTRY_PASSWORD for the Engine API (in memory, per request)."""
    if not (settings.registry_user and settings.registry_password):
        return None
    auth = {"username": settings.registry_user, "password": settings.registry_password}
    return {**auth, "serveraddress": settings.registry} if settings.registry else auth


def login(settings: Settings) -> None:
    """`docker login` with the password on standard input (never a command line or log), for
    `docker manifest push`, which reads the CLI's credentials: only multi-platform pushes."""
    if not (settings.registry_user and settings.registry_password):
        return
    argv = ["docker", "login", "--username", settings.registry_user, "--password-stdin"]
    argv += [settings.registry] if settings.registry else []
    proc = subprocess.run(argv, input=settings.registry_password, capture_output=True, text=True)
    if proc.returncode != 0:
        reason = proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "no reason given"
        raise BuildError(f"docker login to {settings.registry or 'Docker Hub'} as "
                         f"{settings.registry_user} failed: {reason}")


def execute(argv: List[str], auth: Optional[Dict[str, str]]) -> None:
    """One planned command: tag and push through the Engine API (credentials in the request),
    manifest lists through the CLI (the API has none)."""
    try:
        if argv[:2] == ["docker", "tag"]:
            engine.tag(argv[2], argv[3])
            return
        if argv[:2] == ["docker", "push"]:
            engine.push(argv[2], auth)
            return
    except engine.EngineError as exc:
        raise BuildError(str(exc)) from None
    proc = subprocess.run(argv, capture_output=True, text=True)
    if proc.returncode != 0:
        reason = (proc.stderr.strip() or proc.stdout.strip()).splitlines()
        raise BuildError(f"{format_argv(argv)} failed with exit code {proc.returncode}: "
                         f"{reason[-1] if reason else 'no reason given'}")


def push(settings: Settings, targets: Sequence[str], *, dry_run: bool) -> List[str]:
    """Push; return the pushed names. Fails with the command and docker's reason."""
    commands = plan_push(settings, targets)
    if dry_run:
        for argv in commands:
            print("[dry-run] push:", format_argv(argv))
        return []
    if any(argv[:2] == ["docker", "manifest"] for argv in commands):
        login(settings)
    auth = auth_config(settings)
    pushed = []
    for argv in commands:
        print("push:", format_argv(argv), flush=True)
        execute(argv, auth)
        if argv[1] == "push" or argv[:3] == ["docker", "manifest", "push"]:
            pushed.append(argv[-1])
    return pushed
