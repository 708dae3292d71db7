"""Slim's options: SLIM_BUILD_ARGS and ADDITIONAL_SLIM_BUILD_ARGS (docker-slim's flags) parsed."""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from typing import Dict, List, Sequence, Tuple

from docker_ros.core.errors import DockerRosError
from docker_ros.core.settings import SLIM_BUILD_ARGS_DEFAULT, Settings

SETTLE_SECONDS = 3.0  # --settle's default

# What every image keeps whatever the trace saw: user databases and what maps users, the
# dynamic linker's configuration, CA certificates, the shells and the entrypoint.
ESSENTIAL_PATHS = (
    "/etc/passwd", "/etc/group", "/etc/shadow", "/etc/gshadow", "/etc/subuid", "/etc/subgid",
    "/etc/nsswitch.conf", "/etc/login.defs", "/etc/default/useradd", "/etc/skel",
    "/etc/pam.d", "/etc/security", "/etc/ld.so.conf", "/etc/ld.so.conf.d", "/etc/ld.so.cache",
    "/etc/ssl/certs", "/etc/ca-certificates.conf", "/usr/share/ca-certificates",
    "/usr/local/share/ca-certificates", "/etc/os-release", "/usr/lib/os-release",
    "/etc/hosts", "/etc/hostname", "/etc/resolv.conf", "/etc/localtime", "/etc/environment",
    "/etc/profile", "/etc/bash.bashrc", "/root/.bashrc", "/root/.profile", "/.dockerenv",
    "/docker-ros/entrypoint.sh",
    # Python finds its prefix by the landmark os.py, which it never opens (frozen since 3.11)
    "/usr/lib/python3*/os.py", "/usr/local/lib/python3*/os.py",
)
ESSENTIAL_EXECUTABLES = (
    "sh", "bash", "env", "tini", "setpriv", "useradd", "groupadd", "getent", "chpasswd", "id",
    "cut",
)

# docker-slim options: ours (value kind) and those that do not apply here.
OPTIONS = {
    "--include-path": "path", "--preserve-path": "path", "--exclude-pattern": "path",
    "--include-bin": "path", "--include-exe": "path", "--continue-after": "seconds",
    "--settle": "seconds", "--env": "env", "--exec": "text", "--expect": "text",
}
IGNORED_WITH_VALUE = frozenset({
    "--sensor-ipc-mode", "--sensor-ipc-endpoint", "--http-probe-cmd", "--http-probe-cmd-file",
    "--http-probe-ports", "--http-probe-retry-count", "--http-probe-retry-wait",
    "--http-probe-start-wait", "--http-probe-concurrency", "--http-probe-apispec",
    "--http-probe-apispec-file", "--http-probe-exec", "--http-probe-exec-file",
    "--publish-port", "--image-build-engine", "--image-build-arch", "--report",
    "--copy-meta-artifacts", "--state-path", "--new-label",
})
IGNORED_FLAGS = frozenset({
    "--show-clogs", "--show-blogs", "--http-probe", "--http-probe-off", "--http-probe-full",
    "--include-shell", "--include-cert-all", "--include-cert-bundles-only", "--keep-perms",
    "--include-new", "--remove-file-artifacts", "--keep-tmp-artifacts", "--obfuscate-metadata",
    "--include-oslibs-net", "--publish-exposed-ports", "--continue-after-signal",
})


class SlimError(DockerRosError):
    """Slimming failed: what, which image or option, what to do."""


@dataclass(frozen=True)
class SlimOptions:
    include: Tuple[str, ...] = ()
    exclude: Tuple[str, ...] = ()
    executables: Tuple[str, ...] = ()
    binaries: Tuple[str, ...] = ()  # --include-bin (also in include)
    paths: Tuple[Tuple[str, str], ...] = ()  # (--include-path or --preserve-path, path)
    continue_after: float = 10.0  # the longest window
    settle: float = SETTLE_SECONDS  # the window ends this long after the last new file
    env: Tuple[str, ...] = ()
    execs: Tuple[str, ...] = ()
    expect: Tuple[str, ...] = ()
    ignored: Tuple[str, ...] = ()


def parse_slim_args(text: str, additional: str = "") -> SlimOptions:
    """SLIM_BUILD_ARGS (text) + ADDITIONAL_SLIM_BUILD_ARGS (additional), docker-slim syntax ->
    options; an error names the variable the bad option is in."""
    tokens: List[Tuple[str, str]] = []  # (variable, word)
    for variable, words in (("SLIM_BUILD_ARGS", text), ("ADDITIONAL_SLIM_BUILD_ARGS", additional)):
        try:
            tokens += [(variable, word) for word in shlex.split(words)]
        except ValueError as exc:
            raise SlimError(f"{variable}: {exc}") from None
    given: Dict[str, List[Tuple[str, str]]] = {name: [] for name in OPTIONS}
    ignored: List[str] = []
    unknown: List[Tuple[str, str]] = []
    after_unknown = -1
    index = 0
    while index < len(tokens):
        variable, token = tokens[index]
        index += 1
        name, equals, value = token.partition("=")
        if name in OPTIONS or name in IGNORED_WITH_VALUE:
            if not equals:
                if index >= len(tokens):
                    raise SlimError(f"{variable}: {name} needs a value")
                value = tokens[index][1]
                index += 1
            if name in OPTIONS:
                given[name].append((variable, value))
            elif name not in ignored:
                ignored.append(name)
        elif name in IGNORED_FLAGS:
            if name not in ignored:
                ignored.append(name)
        elif name in ("--target", "--tag"):
            raise SlimError(f"{variable}: {name} is set by docker-ros (IMAGE_NAME/IMAGE_TAG,"
                            " SLIM_IMAGE_NAME/SLIM_IMAGE_TAG); remove it")
        elif token.startswith("-") or after_unknown != index - 1:
            unknown.append((variable, token))
            after_unknown = index  # the next word, if no option, is the unknown option's value
    if unknown:
        raise SlimError(
            "/".join(dict.fromkeys(v for v, _ in unknown)) + ": unknown option(s) "
            + ", ".join(t for _, t in unknown) + "; supported: " + ", ".join(OPTIONS)
            + " (see the docs' guide, Slim images)")
    continue_after = seconds_option("--continue-after", given["--continue-after"], 10.0)
    settle = seconds_option("--settle", given["--settle"], SETTLE_SECONDS)
    for variable, pair in given["--env"]:
        if "=" not in pair:
            raise SlimError(f"{variable}: --env {pair!r}: use NAME=VALUE")
    values = {name: [value for _, value in pairs] for name, pairs in given.items()}
    return SlimOptions(
        include=tuple(values["--include-path"] + values["--preserve-path"]
                      + values["--include-bin"]),
        exclude=tuple(values["--exclude-pattern"]),
        executables=tuple(values["--include-exe"]),
        binaries=tuple(values["--include-bin"]),
        paths=tuple((option, value) for option in ("--include-path", "--preserve-path")
                    for value in values[option]),
        continue_after=continue_after,
        settle=settle,
        env=tuple(values["--env"]),
        execs=tuple(values["--exec"]),
        expect=tuple(values["--expect"]),
        ignored=tuple(ignored),
    )


def seconds_option(name: str, given: Sequence[Tuple[str, str]], default: float) -> float:
    """The last value of a seconds option (docker-slim: the last one wins); given: (variable,
    value) pairs."""
    seconds = default
    for variable, raw in given:
        try:
            seconds = float(raw)
        except ValueError:
            seconds = -1.0
        if not seconds >= 0:  # (negative, or not a number at all: NaN too)
            raise SlimError(f"{variable}: {name}={raw!r}: give a number of seconds, 0 or more"
                            " (docker-slim's enter/signal/probe modes do not apply)")
    return seconds


# The paths docker-ros's default SLIM_BUILD_ARGS keeps when they are there: its /opt/ros is
# missing from Debian's ROS images (ROS in /usr), and that must not stop the defaults.
DEFAULT_PATHS = frozenset(path for _, path in parse_slim_args(SLIM_BUILD_ARGS_DEFAULT).paths)
# docker-slim options of that default that do not apply here: not worth a line on every slim
DEFAULT_IGNORED = frozenset(parse_slim_args(SLIM_BUILD_ARGS_DEFAULT).ignored)


def slim_options(settings: Settings) -> SlimOptions:
    return parse_slim_args(settings.slim_build_args, settings.additional_slim_build_args)
