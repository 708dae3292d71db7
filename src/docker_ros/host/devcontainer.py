"""`inv devcontainer`: .devcontainer/devcontainer.json for the repository's dev image, made from
dev-shell's own `docker run` options (devshell.run_options), so that VS Code, Codespaces, DevPod
and the `devcontainer` CLI open the dev image as `inv dev-shell` does.

The file names the dev image the build tags and an `initializeCommand` that builds it first
with docker-ros (`docker-ros build --target dev`, from cache: seconds when nothing changed).
Opening the folder (or "Rebuild Container") so gets an image with the repository's current
dependencies, where a bare `image` would silently keep a stale one. The host user is mapped by
the image's entrypoint, as in dev-shell: the container runs the image's entry point
(`overrideCommand: false`, its `bash` kept waiting by `--tty`), the editor's processes run as the
mapped UID (`remoteUser`), and a login-interactive shell's environment (/etc/bash.bashrc
sources the entrypoint: ROS, the base image's and the workspace's setup) is every process's.
The editor opens the workspace (/docker-ros/ws), where colcon builds the repository and the
.repos imports the build cloned into the image.

A second run merges: what docker-ros wrote last is recorded under
customizations.docker-ros.generated; the user's edits since (a changed value, an added or a
removed extension, mount, runArg or variable) are kept, and what docker-ros no longer
generates goes. A file without that record is never overwritten without --force.
"""

from __future__ import annotations

import dataclasses
import getpass
import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

from docker_ros.core.display import missing_required
from docker_ros.core.errors import DockerRosError
from docker_ros.core.loading import host_platform
from docker_ros.core.settings import FIELDS, Settings, env_name, is_secret, text_of
from docker_ros.host import devshell, engine
from docker_ros.host.config import input_problems
from docker_ros.host.refs import target_ref
from docker_ros.in_image.runtime.packages import find_package_dirs

RELATIVE = Path(".devcontainer") / "devcontainer.json"
MARK = "docker-ros"  # customizations.docker-ros.generated: what docker-ros wrote last
HERE = "${localWorkspaceFolder}"  # the repository on the host, as Dev Containers names it
# The editor opens the ROS workspace around the repository, where dev-shell starts too: colcon
# there builds the repository (src/target) with the .repos imports the build cloned into the
# image (src/upstream), into the container's build/ and install/, not into the repository.
WORKSPACE = "/docker-ros/ws"
# The host user's mapping: the values that differ between users (`--check` passes for any).
USER_VARIABLES = ("DOCKER_UID", "DOCKER_GID", "DOCKER_USER")
# ROS (a ROS 1 workspace and ROS 2 alike), C++ with CMake, Python; a user may remove any.
EXTENSIONS = ("ms-iot.vscode-ros", "ms-vscode.cpptools", "ms-vscode.cmake-tools",
              "ms-python.python")
# Terminals and tasks start bash interactively: /etc/bash.bashrc sources ROS and the workspace
# as they are then (a workspace built after the editor connected too).
EDITOR_SETTINGS = {
    "git.scanRepositories": ["src/target"],  # (the repository, below the workspace folder)
    "terminal.integrated.defaultProfile.linux": "bash",
    "terminal.integrated.profiles.linux": {"bash": {"path": "/bin/bash", "args": ["-i"]}},
    "terminal.integrated.automationProfile.linux": {"path": "/bin/bash", "args": ["-i"]},
}
# settings whose value the build gets from where it runs, not from the file
NOT_PASSED = ("build_context", "target")


class DevcontainerError(DockerRosError):
    """Input that devcontainer.json cannot be written from (one line: what, what to do)."""


@dataclass(frozen=True)
class Plan:
    """What `inv devcontainer` would do: the file's path, its new content, and whether that
    differs from what is there."""

    path: Path
    content: Dict[str, Any]
    changed: bool
    notes: Tuple[str, ...] = ()
    user_only: bool = False  # changed only in the host user's mapping (without_user)

    @property
    def text(self) -> str:
        return json.dumps(self.content, indent=4) + "\n"


def strip_jsonc(text: str) -> str:
    """JSONC as JSON: comments and trailing commas become spaces (lines and columns stay)."""
    out = list(text)
    i, n = 0, len(text)
    last_comma = -1  # position of a comma that only blanks and comments have followed since
    while i < n:
        char = text[i]
        if char == '"':
            last_comma = -1
            i += 1
            while i < n and text[i] != '"':
                i += 2 if text[i] == "\\" else 1
            i += 1
            continue
        if text.startswith("//", i):
            end = text.find("\n", i)
            end = n if end < 0 else end
            out[i:end] = " " * (end - i)
            i = end
            continue
        if text.startswith("/*", i):
            end = text.find("*/", i + 2)
            end = n if end < 0 else end + 2
            out[i:end] = [c if c == "\n" else " " for c in text[i:end]]
            i = end
            continue
        if char == ",":
            last_comma = i
        elif char in "}]" and last_comma >= 0:
            out[last_comma] = " "
            last_comma = -1
        elif not char.isspace():
            last_comma = -1
        i += 1
    return "".join(out)


def parse_jsonc(text: str, path: Path) -> Dict[str, Any]:
    """The object a devcontainer.json holds (comments and trailing commas allowed)."""
    try:
        data = json.loads(strip_jsonc(text))
    except ValueError as exc:
        where = (f"line {exc.lineno} column {exc.colno}: {exc.msg}"
                 if isinstance(exc, json.JSONDecodeError) else str(exc))
        raise DevcontainerError(
            f"{path} is not valid JSON (with comments): {where}; fix it, or move it away "
            "and run again for a new one") from None
    if not isinstance(data, dict):
        raise DevcontainerError(f"{path} holds {type(data).__name__}, not an object; fix it, "
                                "or move it away and run again for a new one")
    return data


def ros_problem(repository: Path, repos_file: str) -> str:
    """Why repository is no ROS repository ('' when it is one: a package.xml, or a .repos
    file importing the packages)."""
    if find_package_dirs(repository) or (repository / repos_file).is_file():
        return ""
    return (f"{repository} has no package.xml and no {repos_file}: it is not a ROS repository; "
            "run it in the repository of your ROS packages (or set BUILD_CONTEXT to it)")


def passed_settings(settings: Settings) -> List[str]:
    """`--set NAME=VALUE` for the settings given by the environment or a flag, so that the
    editor's build uses them too (.env and invoke.yaml it reads itself); never a secret."""
    out: List[str] = []
    for name in FIELDS:
        if (settings.source_of(name) in ("environment", "flag") and not is_secret(name)
                and name not in NOT_PASSED):
            out += ["--set", f"{env_name(name)}={text_of(getattr(settings, name))}"]
    return out


def mount_of(spec: str, repository: Path) -> str:
    """A `docker run -v HOST:CONTAINER[:MODE]` as a Dev Containers mount; a host path in the
    repository relative to ${localWorkspaceFolder}."""
    host, container, *mode = spec.split(":")
    if host.startswith("/"):
        if host == str(repository) or host.startswith(f"{repository}/"):
            host = HERE + host[len(str(repository)):]
        kind = "bind"
    else:
        kind = "volume"
    readonly = ",readonly" if mode and "ro" in mode[0].split(",") else ""
    return f"source={host},target={container},type={kind}{readonly}"


def env_entry(spec: str) -> Tuple[str, str]:
    """`-e NAME=VALUE`, or `-e NAME` (this machine's value: the host's when the editor opens)."""
    name, equals, value = spec.partition("=")
    if not equals or name == "DISPLAY":
        return name, f"${{localEnv:{name}}}"
    return name, value


def generate(settings: Settings, ref: str, pairs: Sequence[Tuple[str, str]], *,
             uid: int, gpus_auto: bool, build: Sequence[str] = ()) -> Dict[str, Any]:
    """devcontainer.json from dev-shell's run options (pairs); uid: the mapped user's (0: root,
    not mapped); gpus_auto: GPUs when the host has the nvidia runtime (the editor's check
    when it opens); build: the initializeCommand ([]: none)."""
    repository = Path(settings.build_context).resolve()
    config: Dict[str, Any] = {"name": ref, "image": ref}
    if build:
        config["initializeCommand"] = list(build)
    env: Dict[str, str] = {}
    mounts: List[str] = []
    # The image's `bash` (after its entry point) waits on a terminal and ends on a hangup:
    # docker stop sends one (an interactive bash ignores SIGTERM).
    run_args = ["--tty", "--stop-signal=SIGHUP"]
    for flag, value in pairs:
        if flag == "-v" and value == f"{repository}:{devshell.TARGET}":
            config["workspaceMount"] = f"source={HERE},target={devshell.TARGET},type=bind"
            config["workspaceFolder"] = WORKSPACE
        elif flag == "-v":
            mounts.append(mount_of(value, repository))
        elif flag == "-e":
            env.update([env_entry(value)])
        else:
            run_args.append(f"{flag}={value}" if value else flag)
    config.update({
        "overrideCommand": False,
        "runArgs": run_args,
        "containerEnv": env,
        # (a number: Dev Containers resolves remoteUser before it reads the container's
        # environment, and the entrypoint creates the user only when the container starts)
        "remoteUser": str(uid) if uid else "root",
        "updateRemoteUserUID": False,  # (the entrypoint maps the user: DOCKER_UID)
        "userEnvProbe": "loginInteractiveShell",
    })
    if mounts:
        config["mounts"] = mounts
    if gpus_auto:
        config["hostRequirements"] = {"gpu": "optional"}
        env["NVIDIA_DRIVER_CAPABILITIES"] = "all"
    config["customizations"] = {"vscode": {"extensions": list(EXTENSIONS),
                                           "settings": dict(EDITOR_SETTINGS)}}
    return config


MISSING: Any = object()


def merge_value(base: Any, ours: Any, theirs: Any, *, adopt: bool = False) -> Any:
    """Three-way: base is what docker-ros wrote last, ours what it writes now, theirs what the
    file holds. An object or list merges item by item; a value the user changed stays theirs,
    one they left is ours (adopt: ours also where docker-ros wrote nothing yet)."""
    if isinstance(ours, dict) and isinstance(theirs, dict):
        previous = base if isinstance(base, dict) else {}
        out = {}
        for key, value in theirs.items():
            if key in ours:
                out[key] = merge_value(previous.get(key, MISSING), ours[key], value, adopt=adopt)
            elif key not in previous or value != previous[key]:
                out[key] = value  # the user's (or changed by the user)
        for key, value in ours.items():
            if key not in theirs and key not in previous:  # (in previous: the user removed it)
                out[key] = value
        return out
    if isinstance(ours, list) and isinstance(theirs, list):
        before = base if isinstance(base, list) else []
        kept = [item for item in theirs if item in ours or item not in before]
        return kept + [item for item in ours if item not in theirs and item not in before]
    if theirs == base or (adopt and base is MISSING):
        return ours
    return theirs


def merge(current: Optional[Dict[str, Any]], ours: Dict[str, Any], path: Path, *,
          force: bool = False) -> Dict[str, Any]:
    """The file's new content: ours on a new file; merged with the file (merge_value) when
    docker-ros wrote it; a file without our record only with force."""
    if current is None:
        return mark(ours, ours)
    customizations = current.get("customizations")
    record = customizations.get(MARK) if isinstance(customizations, dict) else None
    if not isinstance(record, dict) or not isinstance(record.get("generated"), dict):
        if not force:
            raise DevcontainerError(
                f"{path} was not written by docker-ros (no customizations.{MARK}); move it "
                "away, or run with --force to merge docker-ros's settings into it")
        return mark(merge_value({}, ours, current, adopt=True), ours)
    theirs = json.loads(json.dumps(current))
    del theirs["customizations"][MARK]
    return mark(merge_value(record["generated"], ours, theirs), ours)


def mark(config: Dict[str, Any], ours: Mapping[str, Any]) -> Dict[str, Any]:
    """config with the record of what docker-ros generated (ours), last in customizations."""
    out = dict(config)
    customizations = dict(out.get("customizations") or {})
    customizations.pop(MARK, None)
    customizations[MARK] = {"generated": json.loads(json.dumps(ours))}
    out["customizations"] = customizations
    return out


def read_current(path: Path) -> Tuple[Optional[Dict[str, Any]], bool]:
    """The file's object (None: no file) and whether it has comments or trailing commas (which
    a rewrite drops)."""
    if not path.exists():
        return None, False
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DevcontainerError(f"{path} cannot be read ({exc}); fix it or move it away") from None
    return parse_jsonc(text, path), strip_jsonc(text) != text


def without_user(config: Any) -> Any:
    """config without the host user's mapping (remoteUser; DOCKER_UID, DOCKER_GID, DOCKER_USER
    in containerEnv), in the file and in docker-ros's record of it: what `--check` compares, so
    that a file generated by another user (CI's, a colleague's) is up to date for this one."""
    if not isinstance(config, dict):
        return config
    out = {key: value for key, value in config.items() if key != "remoteUser"}
    env = out.get("containerEnv")
    if isinstance(env, dict):
        out["containerEnv"] = {k: v for k, v in env.items() if k not in USER_VARIABLES}
    customizations = out.get("customizations")
    record = customizations.get(MARK) if isinstance(customizations, dict) else None
    if (isinstance(customizations, dict) and isinstance(record, dict)
            and isinstance(record.get("generated"), dict)):
        out["customizations"] = {**customizations,
                                 MARK: {**record, "generated": without_user(record["generated"])}}
    return out


def plan(settings: Settings, ours: Dict[str, Any], *, force: bool = False) -> Plan:
    """The file's new content and whether it changes (nothing written)."""
    path = Path(settings.build_context).resolve() / RELATIVE
    current, commented = read_current(path)
    content = merge(current, ours, path, force=force)
    changed = content != current
    notes = ((f"{path}: its comments and trailing commas are not kept (JSON is written)",)
             if changed and commented else ())
    user_only = changed and current is not None and without_user(content) == without_user(current)
    return Plan(path, content, changed, notes, user_only)


def up_to_date_message(result: Plan) -> str:
    if not result.changed:
        return f"{result.path} is up to date"
    if result.user_only:
        return (f"{result.path} is up to date (it maps another host user than this one: "
                "`inv devcontainer` maps yours)")
    return (f"{result.path} is not up to date with the settings; run `inv devcontainer` "
            "(your own edits are kept)")


def write(result: Plan) -> None:
    result.path.parent.mkdir(parents=True, exist_ok=True)
    temporary = result.path.with_name(result.path.name + ".docker-ros-tmp")
    temporary.write_text(result.text)
    temporary.replace(result.path)


def build_command(settings: Settings) -> List[str]:
    """The initializeCommand: the dev image built by docker-ros, with the settings that came
    from the environment or flags."""
    return ["docker-ros", "build", "--target", "dev", *passed_settings(settings)]



def build_problem(settings: Settings) -> str:
    """Why docker-ros cannot build the dev image with these settings ('' if it can)."""
    missing = missing_required(settings, ["base_image"])
    problems = list(input_problems(settings, ["dev"], images=True).values())
    return "; ".join(([missing] if missing else []) + problems)


def config_for(settings: Settings, ref: str, options: devshell.ShellOptions, *,
               user: devshell.HostUser, display: str, gpus: str, image_present: bool
               ) -> Tuple[Dict[str, Any], Tuple[str, ...]]:
    """devcontainer.json's generated content for the host user, and notes for the user.
    display: the X11 DISPLAY to forward ('' none), as dev-shell's --x11 selects it; gpus:
    'auto' (the editor checks the host when it opens), '' or none, or a `--gpus` value."""
    repository = Path(settings.build_context).resolve()
    problem = ros_problem(repository, str(settings.vcs_import_file))
    if problem:
        raise DevcontainerError(problem)
    cannot = build_problem(settings)
    if cannot and not image_present:
        raise DevcontainerError(
            f"the dev image {ref} is not built, and docker-ros cannot build it: {cannot}")
    notes: Tuple[str, ...] = ()
    if cannot:
        notes += (f"the dev image {ref} is used as it is (no initializeCommand): docker-ros "
                  f"cannot build it again ({cannot})",)
    blacklisted = devshell.blacklisted_names(settings)
    if blacklisted:  # (dev-shell mounts colcon defaults made for the shell; a file outlives it)
        notes += (f"colcon in the dev container builds the blacklisted packages too: give it "
                  f"--packages-ignore {' '.join(blacklisted)}",)
    explicit = "" if gpus in ("auto", "none") else gpus
    shell = dataclasses.replace(options, x11_display=display, xauthority="", gpus=explicit,
                                colcon_defaults="")
    pairs = devshell.run_options(settings, shell, user)
    config = generate(settings, ref, pairs, uid=user.uid, gpus_auto=gpus == "auto",
                      build=() if cannot else build_command(settings))
    return config, notes


def run(settings: Settings, options: devshell.ShellOptions, *, x11: str,
                     gpus: str, check: bool, force: bool, dry_run: bool) -> int:
    """`inv devcontainer`: write (dry_run: print; check: compare) devcontainer.json for the
    host user, with dev-shell's decisions; the exit code (check: 1 when not up to date)."""
    ref = target_ref(settings, "dev", devshell.shell_platform(settings, host_platform()))
    devshell.check_shell_options(options.volumes, options.env)
    display = os.environ.get("DISPLAY", "")
    display = display if devshell.select_x11(x11, display) else ""
    user = devshell.HostUser(os.getuid(), os.getgid(), getpass.getuser())
    config, notes = config_for(
        settings, ref, options, user=user, display=display, gpus=gpus,
        image_present=engine.inspect_image(ref) is not None)
    result = plan(settings, config, force=force)
    for note in notes + result.notes:
        print(f"docker-ros devcontainer: {note}", file=sys.stderr, flush=True)
    if check:
        print(up_to_date_message(result), flush=True)
        return 1 if result.changed and not result.user_only else 0
    if dry_run:
        print(result.text, end="", flush=True)
        return 0
    if result.changed:
        write(result)
        print(f"wrote {result.path}", flush=True)
    else:
        print(f"{result.path} is up to date", flush=True)
    return 0
