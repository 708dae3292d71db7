"""`inv dev-shell`: the `docker run` of the dev image for daily work (pure argv planning), X11
and GPU detection, and the X authority cookie handed to the container."""

from __future__ import annotations

import json
import os
import re
import struct
import subprocess
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple

from docker_ros.core.errors import DockerRosError
from docker_ros.core.settings import FALSE_WORDS, TRUE_WORDS, Settings
from docker_ros.in_image.runtime.files import read_list_file
from docker_ros.in_image.runtime.workspace import StepError
from docker_ros.in_image.steps.blacklist import listed_names

TARGET = "/docker-ros/ws/src/target"
X11_SOCKETS = Path("/tmp/.X11-unix")
XAUTH_IN_CONTAINER = "/tmp/.docker-ros.xauth"
COLCON_DEFAULTS_IN_CONTAINER = "/tmp/.docker-ros.colcon-defaults.yaml"
# colcon verbs that take --packages-ignore
COLCON_SELECTING_VERBS = ("build", "test", "list", "graph")
FAMILY_WILD = 0xFFFF  # an X authority entry valid for any host name (the container's too)


class DevShellError(DockerRosError):
    """A dev-shell option that cannot work (one line for the user)."""


@dataclass(frozen=True)
class ShellOptions:
    command: str = ""  # `bash -c COMMAND` instead of an interactive shell
    volumes: Sequence[str] = ()
    env: Sequence[str] = ()
    network: str = ""
    name: str = ""
    privileged: bool = False
    devices: Sequence[str] = ()
    gpus: str = ""  # a `docker run --gpus` value; empty: none
    x11_display: str = ""  # DISPLAY to forward; empty: no X11
    xauthority: str = ""  # host file with the cookie for x11_display (may be empty)
    colcon_defaults: str = ""  # host file of colcon defaults ignoring blacklisted packages


@dataclass(frozen=True)
class HostUser:
    uid: int
    gid: int
    name: str
    tty: bool = False
    cwd: Path = field(default_factory=Path.cwd)


def parse_display(display: str) -> Optional[Tuple[str, str]]:
    """DISPLAY -> (host, number): ':1' -> ('', '1'), 'localhost:10.0' (ssh -X) ->
    ('localhost', '10'); None when it is not a display name."""
    match = re.fullmatch(r"([\w.\-]*):(\d+)(?:\.\d+)?", display)
    return (match.group(1), match.group(2)) if match else None


def select_x11(mode: str, display: str, sockets: Path = X11_SOCKETS) -> bool:
    """--x11 auto: on when DISPLAY names a local display whose socket exists in
    /tmp/.X11-unix; true/false force it (true without DISPLAY is an error; a TCP display such
    as ssh -X's needs --network host)."""
    if mode == "auto":
        parsed = parse_display(display)
        if parsed is None or parsed[0] not in ("", "unix"):
            return False
        return (sockets / f"X{parsed[1]}").exists()
    if mode.lower() not in TRUE_WORDS + FALSE_WORDS:
        raise DevShellError(f"--x11 {mode!r}: use auto, true or false")
    wanted = mode.lower() in TRUE_WORDS
    if wanted and not display:
        raise DevShellError("--x11 true: DISPLAY is not set; run it from a graphical session")
    return wanted


def select_gpus(mode: str, runtimes: Sequence[str]) -> str:
    """--gpus auto: `all` when the nvidia runtime is registered with the Docker daemon
    (`docker info` lists it), else none; `none` disables; anything else goes to docker."""
    if mode == "auto":
        return "all" if "nvidia" in runtimes else ""
    return "" if mode in ("", "none") else mode


def docker_runtimes() -> List[str]:
    try:
        proc = subprocess.run(["docker", "info", "--format", "{{json .Runtimes}}"],
                              capture_output=True, text=True)
    except FileNotFoundError:
        raise DevShellError("no `docker` command: install Docker (scripts/setup.sh)") from None
    try:
        return sorted(json.loads(proc.stdout or "{}"))
    except ValueError:
        return []


def xauth_entries(data: bytes) -> Iterator[Tuple[int, bytes, bytes, bytes, bytes]]:
    """The entries of an Xauthority file: (family, address, number, name, data)."""
    pos = 0
    while pos + 2 <= len(data):
        (family,) = struct.unpack_from(">H", data, pos)
        pos += 2
        fields = []
        for _ in range(4):
            if pos + 2 > len(data):
                return
            (length,) = struct.unpack_from(">H", data, pos)
            if pos + 2 + length > len(data):  # a truncated file: keep the whole entries
                return
            fields.append(data[pos + 2:pos + 2 + length])
            pos += 2 + length
        yield (family, fields[0], fields[1], fields[2], fields[3])


def wildcard_cookies(data: bytes, number: str) -> bytes:
    """The cookies of display `number` from an Xauthority file, made valid for any host name
    (the container has its own), as rocker does with `xauth nlist | sed 's/^..../ffff/'`."""
    out = b""
    for _family, address, entry_number, name, cookie in xauth_entries(data):
        if entry_number.decode(errors="replace") != number:
            continue
        out += struct.pack(">H", FAMILY_WILD)
        for value in (address, entry_number, name, cookie):
            out += struct.pack(">H", len(value)) + value
    return out


def host_xauthority(environ: Mapping[str, str]) -> Optional[Path]:
    path = Path(environ.get("XAUTHORITY") or Path.home() / ".Xauthority")
    return path if path.is_file() else None


# docker run -v HOST:CONTAINER[:MODE]: the mode words docker accepts (comma-separated).
VOLUME_MODES = ("ro", "rw", "z", "Z", "shared", "rshared", "slave", "rslave", "private",
                "rprivate", "nocopy", "consistent", "cached", "delegated")
VOLUME_NAME = re.compile(r"^[a-zA-Z0-9][a-zA-Z0-9_.-]+$")  # docker's named volume names
VOLUME_FORM = "use HOST:CONTAINER[:MODE], e.g. ./data:/data:ro or a volume name, ccache:/ccache"


def volume_problem(spec: str) -> str:
    """Why `docker run -v spec` would fail ('' when it would not), in the words of --volume."""
    parts = spec.split(":")
    if len(parts) not in (2, 3):
        count = "no ':'" if len(parts) == 1 else f"{len(parts) - 1} ':' (one or two belong)"
        return f"--volume {spec!r}: {count}; {VOLUME_FORM}"
    host, container = parts[0], parts[1]
    if not host:
        return f"--volume {spec!r}: the host side (before ':') is empty; {VOLUME_FORM}"
    if not host.startswith(("/", ".", "~")) and not VOLUME_NAME.match(host):
        return (f"--volume {spec!r}: {host!r} is neither a path (/, ./, ~/) nor a volume name; "
                f"{VOLUME_FORM}")
    if not container.startswith("/"):
        return (f"--volume {spec!r}: the container side {container!r} must be an absolute "
                f"path; {VOLUME_FORM}")
    bad = [m for m in parts[2].split(",") if m not in VOLUME_MODES] if len(parts) == 3 else []
    if bad:
        return (f"--volume {spec!r}: unknown mode {', '.join(map(repr, bad))}; use "
                f"{', '.join(VOLUME_MODES[:4])} ... (comma-separated)")
    return ""


def env_problem(spec: str) -> str:
    """What is wrong with an --env value (NAME=VALUE, or NAME to pass this machine's), '' if
    nothing (docker passed `-e =x` on, and its error came after the dev image's build)."""
    name = spec.partition("=")[0]
    if name and not re.search(r"\s", name):  # (docker takes my-var and a.b names too)
        return ""
    return f"--env {spec!r}: give NAME=VALUE (or NAME), NAME not empty and without spaces"


def check_shell_options(specs: Sequence[str], env: Sequence[str] = ()) -> None:
    """Every --volume and --env checked before the dev image is built (docker would say
    `invalid spec` only after it)."""
    problems = [p for p in [*map(volume_problem, specs), *map(env_problem, env)] if p]
    if problems:
        raise DevShellError("; ".join(problems))


def host_path(spec: str, cwd: Path) -> str:
    """The host side of a --volume made absolute (docker takes a relative one for the name of
    a named volume); a name without a slash stays a named volume."""
    host, sep, rest = spec.partition(":")
    if host.startswith(("/", ".", "~")):
        host = str((cwd / Path(host).expanduser()).resolve())
    return host + sep + rest


def run_options(settings: Settings, options: ShellOptions, user: HostUser
                ) -> List[Tuple[str, str]]:
    """What `docker run` of the dev image gets besides the image and command, as (flag, value)
    pairs in order ('' for a flag without value): repository at /docker-ros/ws/src/target, the
    host user mapped by the entrypoint (root stays root), the shell's options. dev-shell's argv
    and devcontainer.json are both made from them."""
    repository = Path(settings.build_context).resolve()
    pairs = [("-v", f"{repository}:{TARGET}")]
    if user.uid != 0:
        pairs += [("-e", f"DOCKER_UID={user.uid}"), ("-e", f"DOCKER_GID={user.gid}"),
                  ("-e", f"DOCKER_USER={user.name}")]
    if options.colcon_defaults:  # before --env: a COLCON_DEFAULTS_FILE of the user's wins
        pairs += [("-e", f"COLCON_DEFAULTS_FILE={COLCON_DEFAULTS_IN_CONTAINER}"),
                  ("-v", f"{options.colcon_defaults}:{COLCON_DEFAULTS_IN_CONTAINER}:ro")]
    pairs += [("-v", host_path(volume, user.cwd)) for volume in options.volumes]
    pairs += [("-e", variable) for variable in options.env]
    if options.network:
        pairs.append(("--network", options.network))
        if options.network == "host":
            # DDS shared-memory transports see the host's network as local: share IPC too.
            pairs.append(("--ipc", "host"))
    if options.privileged:
        pairs.append(("--privileged", ""))
    pairs += [("--device", device) for device in options.devices]
    if options.x11_display:
        pairs += [("-e", f"DISPLAY={options.x11_display}"), ("-e", "QT_X11_NO_MITSHM=1"),
                  ("-v", f"{X11_SOCKETS}:{X11_SOCKETS}")]
        if options.xauthority:
            pairs += [("-e", f"XAUTHORITY={XAUTH_IN_CONTAINER}"),
                      ("-v", f"{options.xauthority}:{XAUTH_IN_CONTAINER}:ro")]
    if options.gpus:
        pairs += [("--gpus", options.gpus), ("-e", "NVIDIA_DRIVER_CAPABILITIES=all")]
    return pairs


def dev_shell_argv(
    settings: Settings, ref: str, options: ShellOptions, user: HostUser
) -> List[str]:
    """The `docker run` of the dev image: run_options, then bash (or `bash -c` the command)."""
    argv = ["docker", "run", "--rm", "-i"] + (["-t"] if user.tty else [])
    if options.name:
        argv += ["--name", options.name]
    for flag, value in run_options(settings, options, user):
        argv += [flag, value] if value else [flag]
    argv.append(ref)
    return argv + (["bash", "-c", options.command] if options.command else ["bash"])


def shell_platform(settings: Settings, here: str) -> str:
    """The platform of the dev image a shell runs (here: this machine's): this machine's when
    PLATFORM has it (another one may build under QEMU), else PLATFORM's first."""
    return here if here in settings.platform else settings.platform[0]


def blacklisted_names(settings: Settings) -> List[str]:
    """The package names the repository's BLACKLISTED_PACKAGES_FILE lists (its top-level file).
    The dev image's copies of those packages carry a COLCON_IGNORE file, which the repository
    mounted over them in the shell lacks."""
    path = Path(settings.build_context).resolve() / str(settings.blacklisted_packages_file)
    if not path.is_file():
        return []
    try:
        lines = read_list_file(path, "dev-shell")
    except StepError as exc:
        raise DevShellError(exc.message) from None
    return listed_names(lines)


def write_colcon_defaults(names: Sequence[str], destination: Path,
                          user: Optional[Mapping[str, Any]] = None) -> str:
    """A colcon defaults file (JSON is YAML) that leaves names out of every verb selecting
    packages, with the user's defaults (merged_defaults); its path, or '' when there is nothing
    to leave out."""
    if not names:
        return ""
    destination.write_text(json.dumps(merged_defaults(user or {}, names)) + "\n")
    return str(destination)


def merged_defaults(user: Mapping[str, Any], names: Sequence[str]) -> Dict[str, Any]:
    """The user's colcon defaults with names added to the packages-ignore of every verb that
    selects packages (their other settings, and their ignored packages, stay)."""
    out = dict(user)
    for verb in COLCON_SELECTING_VERBS:
        section = dict(out[verb]) if isinstance(out.get(verb), dict) else {}
        given = section.get("packages-ignore")
        given = [n for n in given if isinstance(n, str)] if isinstance(given, list) else []
        section["packages-ignore"] = list(dict.fromkeys(given + list(names)))
        out[verb] = section
    return out


def given_defaults_file(env: Sequence[str], environ: Mapping[str, str]) -> Optional[str]:
    """The COLCON_DEFAULTS_FILE the user's --env gives the shell (the last, as docker takes
    it; `NAME` alone passes this machine's value), or None."""
    found: Optional[str] = None
    for spec in env:
        name, equals, value = spec.partition("=")
        if name == "COLCON_DEFAULTS_FILE":
            found = value if equals else environ.get(name)
    return found or None


def host_file(path: str, binds: Sequence[Tuple[str, str]]) -> Optional[Path]:
    """The host file a container path is mounted from (binds: host path, container path; the
    deepest container path first), None when no bind holds it."""
    for host, inside in sorted(binds, key=lambda b: len(b[1]), reverse=True):
        inside = inside.rstrip("/")
        if path == inside or path.startswith(inside + "/"):
            return Path(host + path[len(inside):])
    return None


def read_defaults(path: Path) -> Optional[Dict[str, Any]]:
    """A colcon defaults file's mapping (YAML; JSON is YAML), None when it is not readable as
    one."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError):  # (not a text file: no defaults file either)
        return None
    try:
        data = json.loads(text)
    except ValueError:
        try:
            import yaml  # colcon's own dependency (the host extra), not docker-ros's
        except ImportError:
            return None
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError:
            return None
    return {} if data is None else data if isinstance(data, dict) else None


def shell_colcon_defaults(names: Sequence[str], options: ShellOptions, repository: Path,
                          cwd: Path, environ: Mapping[str, str], destination: Path
                          ) -> Tuple[ShellOptions, str]:
    """The shell's options with colcon defaults ignoring the blacklisted names, and a line
    for the user ('' if none). A COLCON_DEFAULTS_FILE of the user's (--env) in the repository
    or a --volume is merged into ours (its --env dropped, the line says so); one we cannot
    read stays in force (after ours), and the line warns that colcon then builds the
    blacklisted packages."""
    if not names:
        return options, ""
    ours = replace(options, colcon_defaults=write_colcon_defaults(names, destination))
    given = given_defaults_file(options.env, environ)
    if not given:
        return ours, ""
    source = host_file(given, shell_binds(options, repository, cwd))
    user = read_defaults(source) if source else None
    if user is None:
        return (ours,
                f"docker-ros dev-shell: warning: COLCON_DEFAULTS_FILE={given} (--env) is no "
                "colcon defaults file of the repository or a --volume that docker-ros can read,"
                " so colcon in the shell uses it alone and builds the blacklisted packages "
                f"{', '.join(names)} (add them to its packages-ignore)")
    env = [e for e in options.env if e.partition("=")[0] != "COLCON_DEFAULTS_FILE"]
    return (replace(options, env=env,
                    colcon_defaults=write_colcon_defaults(names, destination, user)),
            f"docker-ros dev-shell: COLCON_DEFAULTS_FILE={given} (--env) is merged into the "
            "shell's colcon defaults, which also ignore the blacklisted packages "
            f"{', '.join(names)}")


def shell_binds(options: ShellOptions, repository: Path, cwd: Path) -> List[Tuple[str, str]]:
    """(host path, container path) of the repository and of each --volume of a host folder
    (not of a named volume) in the shell."""
    binds = [(str(repository), TARGET)]
    for volume in options.volumes:
        host, _, rest = host_path(volume, cwd).partition(":")
        if host.startswith("/"):
            binds.append((host, rest.split(":")[0]))
    return binds


def write_cookie(display: str, environ: Mapping[str, str], destination: Path) -> str:
    """Write the wildcard cookies of display to destination; '' when the host has none (an
    X server without access control, e.g. after `xhost +local:`)."""
    source = host_xauthority(environ)
    parsed = parse_display(display)
    if source is None or parsed is None:
        return ""
    destination.write_bytes(wildcard_cookies(source.read_bytes(), parsed[1]))
    os.chmod(destination, 0o600)
    return str(destination)
