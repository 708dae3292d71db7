"""The one typed settings object: every docker-ros variable declared once, loaded purely."""

from __future__ import annotations

import dataclasses
import difflib
import hashlib
import os
import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Iterable, List, Mapping, Optional, Sequence, Tuple, Union

from docker_ros.in_image.ci import NO_POSTFIX, detect_pipeline, push_also_as, tag_postfix

# docker-ros's (the probe runs as a user the entrypoint creates; its files are left out)
SLIM_BUILD_ARGS_DEFAULT = (
    "--sensor-ipc-mode proxy --continue-after=30 --show-clogs --http-probe=false"
    " --env DOCKER_UID=23456 --env DOCKER_GID=23456 --env DOCKER_USER=dockerslimprobe"
    " --include-path /opt/ros --include-path /docker-ros/ws/install"
    " --include-path /etc/ld.so.cache --include-path /etc/ld.so.conf"
    " --include-path /etc/ld.so.conf.d --preserve-path /etc/passwd --preserve-path /etc/group"
    " --preserve-path /etc/shadow --preserve-path /etc/gshadow"
    " --exclude-pattern /home/dockerslimprobe --exclude-pattern /home/dockerslimprobe/**"
    " --exclude-pattern /var/mail/dockerslimprobe"
)
TRUE_WORDS = ("true", "1", "yes")
MASKED = "****"  # how a secret's value is shown
FALSE_WORDS = ("false", "0", "no")
TARGETS = ("dev", "run", "slim")
# Commands that keep docker-ros's ENABLE_SLIM default (true) on a developer machine too: what
# they produce is what CI pushes. A local `build` slims only when asked (slim_default).
SLIMMING_COMMANDS = ("push", "ci", "manifest")
PLATFORMS = ("amd64", "arm64")
# The default of a setting the CI integrations set (as docker-ros's action and template do).
CI_DEFAULT = "GitHub Action: {}; GitLab template: {}; else none"
RECURSIVE_HELP = "Enable recursive discovery of files named as the {}, anywhere in the workspace"

Value = Union[str, bool, Tuple[str, ...], None]


class SettingsError(ValueError):
    """One or more configuration values are invalid or missing (message lists all of them)."""


BUILD_USES = ("arg", "tool", "none")
# Task flag groups: image tasks (build, run, slim...), host step tasks, pushing tasks.
FLAG_GROUPS = ("image", "host", "push")


def setting(
    default: Value,
    help: str,
    *,
    secret: bool = False,
    choices: Tuple[str, ...] = (),
    default_doc: str = "",
    group: str = "docker-ros",
    path: str = "",
    recursive: str = "",
    build: str = "arg",
    flags: Tuple[str, ...] = (),
    words: bool = False,
) -> Any:
    """Declare one configuration variable: its env name is the field name upper-cased.
    `path` ("file" or "dir"): a path relative to the repository, which must stay inside it;
    `recursive`: the setting that switches on recursive discovery of files of that name;
    `build`: how it reaches an image build: "arg" (a Dockerfile ARG of its name), "tool" (the
    tool turns it into tags, build arguments, secret mounts...), "none" (not a build input);
    `flags`: the groups of tasks that take it as a flag (FLAG_GROUPS), besides --set;
    `words`: split into words as a shell would (quotes keep spaces), checked when loaded."""
    assert build in BUILD_USES and set(flags) <= set(FLAG_GROUPS), (build, flags)
    meta = {
        "help": help,
        "secret": secret,
        "choices": choices,
        "default_doc": default_doc,
        "group": group,
        "path": path,
        "recursive": recursive,
        "build": build,
        "flags": flags,
        "words": words,
    }
    return field(default=default, metadata=meta, repr=not secret)  # (a traceback, a diff)


@dataclass(frozen=True)
class Settings:
    """Every configuration variable of docker-ros (same names, same defaults) plus ours."""

    additional_debs_file: str = setting(
        "docker/additional-debs.txt",
        "Relative filepath to file containing additional apt deb packages to install",
        path="file", recursive="enable_recursive_additional_debs",
    )
    additional_files_dir: str = setting(
        "docker/additional-files",
        "Relative path to directory containing additional files to copy into image",
        path="dir",
    )
    additional_pip_file: str = setting(
        "docker/additional-pip-requirements.txt",
        "Relative filepath to file containing additional pip packages to install",
        path="file", recursive="enable_recursive_additional_pip",
    )
    after_dependency_installation_script: str = setting(
        "docker/custom.sh",
        "Relative filepath to script containing commands to run after dependency installation",
        path="file", recursive="enable_recursive_after_dependency_installation_script",
    )
    base_image: Optional[str] = setting(
        None, "Base image `name:tag`", default_doc="*required*", flags=("image",)
    )
    before_dependency_identification_script: str = setting(
        "docker/before_dependency_identification.sh",
        "Relative filepath to script containing commands to run before dependency identification",
        path="file",
    )
    before_dependency_installation_script: str = setting(
        "docker/before_dependency_installation.sh",
        "Relative filepath to script containing commands to run before dependency installation",
        path="file", recursive="enable_recursive_before_dependency_installation_script",
    )
    blacklisted_packages_file: str = setting(
        "docker/blacklisted-packages.txt",
        "Relative filepath to file containing blacklisted packages",
        path="file", recursive="enable_recursive_blacklisted_packages",
    )
    build_context: str = setting(
        ".", "Build context of Docker build process (the ROS repository)",
        build="tool", flags=("image", "host")
    )
    buildx_attestations: bool = setting(
        False, "Value passed to `docker buildx build --provenance` and `--sbom`", build="tool"
    )
    command: Optional[str] = setting(
        None, "Launch command of run image", default_doc="*required if `run` is a target*"
    )
    cmake_args: str = setting(
        "-DCMAKE_BUILD_TYPE=Release", "CMake arguments to pass to `colcon build`", flags=("image",),
        words=True,
    )
    dev_image_name: Optional[str] = setting(
        None, "Image name of dev image", default_doc="`<IMAGE_NAME>`", build="tool"
    )
    dev_image_tag: Optional[str] = setting(
        None, "Image tag of dev image", default_doc="`<IMAGE_TAG>-dev`", build="tool"
    )
    disable_ros_installation: bool = setting(
        False, "Disable automatic installation of `ros-$ROS_DISTRO-ros-core` package"
    )
    docker_ros_git_ref: str = setting(
        "main", "Git ref of docker-ros to run in CI (GitLab template variable, Action input)",
        default_doc="GitLab template: `v<version>`, the release it belongs to (a"
        " `docker/docker-ros` copy of docker-ros (Python) in the repository is installed"
        " instead); GitHub Action: the action's own files",
        group="ci", build="none"
    )
    enable_checkout: bool = setting(
        True, "Enable checkout action to (re-)download the repository first (Action input only)",
        group="ci", build="none"
    )
    enable_checkout_submodules: str = setting(
        "recursive",
        "Enable submodules for the checkout action; Action input only",
        choices=("false", "true", "recursive"),
        group="ci", build="none",
    )
    enable_checkout_lfs: bool = setting(
        True, "Enable Git LFS support for the checkout action (Action input only)", group="ci",
        build="none"
    )
    enable_industrial_ci: bool = setting(
        False, "Enable tests (`colcon test` in the dev image; replaces industrial_ci)", build="none"
    )
    enable_lean_run_image: bool = setting(
        False,
        "Install only the Debian packages the install space needs at run time in the run image"
        " (shared libraries, imported Python modules) instead of the `-dev` packages rosdep names",
        build="tool",
    )
    enable_push_as_latest: bool = setting(
        False, "Push images with tag `latest`/`latest-dev` (and `latest-slim`) in addition to the "
        "configured names",
        build="none", flags=("push",)
    )
    enable_singlearch_push: bool = setting(
        False, "Enable push of single arch images with `-amd64`/`-arm64` postfix",
        build="none", flags=("image", "push")
    )
    enable_recursive_additional_debs: bool = setting(
        False, RECURSIVE_HELP.format("additional debs file")
    )
    enable_recursive_additional_pip: bool = setting(
        False, RECURSIVE_HELP.format("additional pip file")
    )
    enable_recursive_after_dependency_installation_script: bool = setting(
        False, RECURSIVE_HELP.format("after-dependency-installation script")
    )
    enable_recursive_before_dependency_installation_script: bool = setting(
        False, RECURSIVE_HELP.format("before-dependency-installation script")
    )
    enable_recursive_blacklisted_packages: bool = setting(
        False, RECURSIVE_HELP.format("blacklisted packages file")
    )
    enable_recursive_vcs_import: bool = setting(
        True, "Enable recursive discovery of files named `*.repos`"
    )
    enable_slim: bool = setting(
        True,
        "Enable an extra slimmed run image (only if `run` stage is targeted): traced, minified,"
        " checked to run alike (see Slim images)", build="none", flags=("push",),
        default_doc="`true` in CI and for `push`, `ci`, `manifest`; `false` for a local"
        " `build` (slim with `true`, a `slim` target or `inv slim`)",
    )
    git_https_password: Optional[str] = setting(
        None, "Password for cloning private Git repositories via HTTPS", secret=True,
        build="tool", default_doc=CI_DEFAULT.format("`${{ github.token }}`", "`$CI_JOB_TOKEN`"),
    )
    git_https_server: Optional[str] = setting(
        None, "Server URL (without protocol) for cloning private Git repositories via HTTPS",
        default_doc=CI_DEFAULT.format("`github.com`", "`$CI_SERVER_HOST`"),
    )
    git_https_user: Optional[str] = setting(
        None, "Username for cloning private Git repositories via HTTPS",
        default_doc=CI_DEFAULT.format("`${{ github.actor }}`", "`gitlab-ci-token`"),
    )
    git_ssh_known_host_keys: Optional[str] = setting(
        None, "Known SSH host keys for cloning private Git repositories via SSH (may be "
        "obtained using `ssh-keyscan`)"
    )
    git_ssh_private_key: Optional[str] = setting(
        None, "SSH private key for cloning private Git repositories via SSH", secret=True,
        build="tool"
    )
    image: Optional[str] = setting(
        None, "Full run image `name:tag`; sets IMAGE_NAME and IMAGE_TAG (as docker-ros build.sh)",
        build="tool", flags=("image",)
    )
    image_name: Optional[str] = setting(
        None,
        "Image name of run image",
        default_doc="GitHub Action: `ghcr.io/<owner>/<repository>`; GitLab template: "
        "`$CI_REGISTRY_IMAGE`; else the current folder's name",
        build="tool",
    )
    image_tag: str = setting("latest", "Image tag of run image", build="tool", flags=("image",))
    platform: Tuple[str, ...] = setting(
        (),
        "Target platform architecture (comma-separated list)",
        choices=PLATFORMS,
        default_doc="this machine's architecture; GitLab template: `amd64`", build="tool",
        flags=("image",),
    )
    registry: Optional[str] = setting(
        None, "Docker registry to push images to",
        default_doc=CI_DEFAULT.format("`ghcr.io`", "`$CI_REGISTRY`"),
        build="none", flags=("push",)
    )
    registry_password: Optional[str] = setting(
        None, "Docker registry password", secret=True, build="none",
        default_doc=CI_DEFAULT.format("`${{ github.token }}`", "`$CI_REGISTRY_PASSWORD`"),
    )
    registry_user: Optional[str] = setting(
        None, "Docker registry username", build="none", flags=("push",),
        default_doc=CI_DEFAULT.format("`${{ github.actor }}`", "`$CI_REGISTRY_USER`"),
    )
    rmw_implementation: str = setting(
        "rmw_fastrtps_cpp", "ROS 2 middleware implementation",
        default_doc="the base image's `RMW_IMPLEMENTATION`, else `rmw_fastrtps_cpp`")
    ros_distro: Optional[str] = setting(
        None, "ROS Distro", default_doc="*required if ROS is not installed in `BASE_IMAGE`*",
        flags=("image",)
    )
    slim_build_args: str = setting(
        SLIM_BUILD_ARGS_DEFAULT,
        "Arguments to the slimming step (except target and tag; docker-slim syntax, options"
        " in Slim images)", build="none", words=True,
    )
    additional_slim_build_args: str = setting(
        "", "Arguments appended to SLIM_BUILD_ARGS (e.g. `--exec 'rosnode list' --expect TEXT`)",
        build="none", words=True,
    )
    slim_image_name: Optional[str] = setting(
        None, "Image name of slim run image", default_doc="`<IMAGE_NAME>`", build="none"
    )
    slim_image_tag: Optional[str] = setting(
        None, "Image tag of slim run image", default_doc="`<IMAGE_TAG>-slim`", build="none"
    )
    target: Tuple[str, ...] = setting(
        ("run",),
        "Target stage of Dockerfile (comma-separated list; `slim`: the run image, slimmed)",
        choices=TARGETS, build="tool",
    )
    vcs_import_file: str = setting(
        ".repos",
        "Relative filepath to file containing additional repos to install via vcstool",
        path="file", recursive="enable_recursive_vcs_import",
    )
    # --- beyond docker-ros ---
    rosdep_rules_file: str = setting(
        "docker/rosdep.yaml",
        "Relative filepath to a rosdep rules file (YAML) whose keys come before the public "
        "rules (on the host in the workspace's own rosdep database, never /etc)",
        group="ours", path="file",
    )
    workspace: Optional[str] = setting(
        None,
        "Host workspace of the step tasks and `--host` composites (repository at src/target)",
        default_doc="`${XDG_CACHE_HOME:-~/.cache}/docker-ros/ws/<current folder's name>` "
        "(`<name>-<hash of its path>` when that one is the workspace of another repository of "
        "the same name)",
        group="ours", build="none", flags=("host",),
    )
    test_results_dir: Optional[str] = setting(
        None,
        "Folder the tests (ENABLE_INDUSTRIAL_CI, `inv test`) write their JUnit XML, logs and exit"
        " codes to; replaced only when empty or made by an earlier run",
        default_doc="`<WORKSPACE>/test-results`; GitHub Action: `<runner.temp>/docker-ros-test-"
        "results` (output `test-results`); GitLab template: the job's folder, copied to "
        "`docker-ros-test-results/` (the job's artifact)",
        group="ours", build="none",
    )
    enable_command_check: bool = setting(
        True,
        "Stop the run image's build when COMMAND names a program, ROS package, executable or"
        " launch file the image lacks (false: build it anyway)",
        group="ours",
    )
    extra_ca_certs: Optional[str] = setting(
        None,
        "PEM file or directory of PEM files trusted during the build (never left in the image)",
        group="ours", build="tool", flags=("image",),
    )
    cache_from: Tuple[str, ...] = setting(
        (),
        "Registry images to reuse as build cache (comma-separated; each a `--cache-from`;"
        " give the dev and the run image so that every stage finds its layers)",
        default_doc="in CI: the dev and run images the pipeline pushes (and the default"
        " branch's); else none; `none` turns it off",
        group="ours", build="tool", flags=("image",),
    )
    cache_to: Optional[str] = setting(
        None,
        "Registry cache the build exports and imports, one per image (`-<target>-<arch>` is"
        " appended, e.g. `<IMAGE>-cache-dev-amd64`): every stage (`--cache-to"
        " type=registry,mode=max`) where the builder can export it (an engine on the containerd"
        " image store, docker-container or remote builders); where it cannot (the classic"
        " store's docker driver, e.g. Engine 20.10) inline cache in the images instead",
        default_doc="in CI: `<IMAGE_NAME>:<IMAGE_TAG>-cache` when the pipeline pushes the dev"
        " image, `<BUILD_STATE_REPOSITORY>:<IMAGE_TAG>-cache` when that is set, else none; else"
        " none; `none` turns it off (every stage's layers, the sources' too, are pushed)",
        group="ours", build="tool",
    )
    no_cache: bool = setting(
        False,
        "Build every stage anew, reusing no layer of the builder's cache (`--no-cache`); the"
        " cache mounts stay (apt's downloads, the colcon build/ cache of this repository)",
        group="ours", build="tool",
    )
    builder: Optional[str] = setting(
        None,
        "buildx builder or docker context the images are built on (`--builder`); a docker"
        " context's engine keeps the images it builds (push sends them from there), other"
        " drivers' `--load` copies them into the local engine",
        default_doc="`BUILDX_BUILDER`, else buildx's current builder",
        group="ours", build="tool",
    )
    build_state_from: Tuple[str, ...] = setting(
        (),
        "Registry images of a build state (`<IMAGE>-build-state`, comma-separated, the first"
        " pullable one wins; `-<arch>` is appended) an empty build cache starts from: only"
        " changed packages compile on an empty CI runner; set, the build also makes the run"
        " image's build state, which `push` pushes",
        default_doc="in CI, when the pipeline pushes the dev image or BUILD_STATE_REPOSITORY is"
        " set: the build state the pipeline pushes (and the default branch's); else none; `none`"
        " turns it off (the colcon build folder is pushed)",
        group="ours", build="tool",
    )
    build_state_repository: Optional[str] = setting(
        None,
        "Registry repository (`registry/name`, no tag) for what holds sources or build products"
        " besides the images: the CI build state (`<tag>-build-state-<arch>`) and the registry"
        " cache (`<tag>-cache-<target>-<arch>`), e.g. a private one next to a public run image",
        default_doc="IMAGE_NAME's repository, and in CI only when the pipeline pushes the dev"
        " image (which holds the sources anyway): a run-only pipeline then pushes no build state"
        " and no registry cache of every stage (the run image carries its inline cache)",
        group="ours", build="tool",
    )
    build_network: Optional[str] = setting(
        None,
        "Network of the build's RUN steps (`host` reaches services on this machine's loopback,"
        " e.g. a local git server, and the outside from an engine without outbound NAT, e.g."
        " the Engine 26 of scripts/setup.sh)",
        choices=("host", "none", "default"), group="ours", build="tool", flags=("image",),
    )
    ros_apt_source_version: str = setting(
        "1.1.0", "Pinned version of the ros-apt-source package used to install ROS", group="ours"
    )
    locked: bool = setting(
        False,
        "Build exactly what docker-ros.lock records (base image digest, imported commits, the"
        " apt versions of prepare and the steps, pip versions); a repository that no longer"
        " matches the lock stops the build",
        group="ours", build="tool", flags=("image", "host"),
    )
    image_postfix: Optional[str] = setting(
        None,
        "Appended to every image tag (docker-ros's CI branch postfix); `none` for no postfix",
        default_doc="`_<branch-slug>_ci` in CI off the default branch, `-<git tag>` in tag"
        " pipelines, else none",
        group="ours", build="tool",
    )
    sources: Mapping[str, str] = field(default_factory=dict, compare=False, repr=False)
    # Derived, not a setting: tags pushed besides the configured ones (`latest`, a git tag).
    push_also_as: Tuple[str, ...] = field(default=(), compare=False)
    # Loaded leniently (`inv config`): setting name -> (value as given, why it is invalid).
    problems: Mapping[str, Tuple[str, str]] = field(
        default_factory=dict, compare=False, repr=False
    )
    # The flags (and --set values) as given, as text: what `ci` passes on to its tasks (the
    # values in force may differ: IMAGE_POSTFIX is added to a tag given as a flag).
    flags: Mapping[str, str] = field(default_factory=dict, compare=False, repr=False)

    def source_of(self, name: str) -> str:
        return self.sources.get(name, "default")


def explicitly_set(settings: Settings, name: str) -> bool:
    """Set by the user to something else than the default (CI integrations and image builds
    pass the defaults on, so the source alone does not tell)."""
    return settings.source_of(name) != "default" and getattr(settings, name) != FIELDS[name].default


def path_settings() -> List[str]:
    """Settings holding a path relative to the repository."""
    return [n for n, f in FIELDS.items() if f.metadata["path"]]


def declarations() -> List[dataclasses.Field]:
    return [f for f in dataclasses.fields(Settings) if "help" in f.metadata]


FIELDS = {f.name: f for f in declarations()}


def env_name(name: str) -> str:
    return name.upper()


def flag_name(name: str) -> str:
    return "--" + name.replace("_", "-")


def kind_of(name: str) -> str:
    """'bool', 'list' or 'str', from the field's annotation."""
    annotation = str(FIELDS[name].type)
    if annotation == "bool":
        return "bool"
    if annotation.startswith("Tuple"):
        return "list"
    return "str"


def is_secret(name: str) -> bool:
    return bool(FIELDS[name].metadata["secret"])


def settings_where(key: str, value: object) -> Tuple[str, ...]:
    """The settings, in declaration order, whose declaration has `key` equal to (or, for a
    tuple, holding) value: e.g. ("build", "tool") or ("flags", "push")."""
    def matches(held: object) -> bool:
        return value in held if isinstance(held, tuple) else held == value
    return tuple(n for n, f in FIELDS.items() if matches(f.metadata[key]))


def build_secrets() -> Tuple[str, ...]:
    """Secrets an image build receives (as secret mounts, never as build arguments)."""
    return tuple(n for n in settings_where("secret", True) if FIELDS[n].metadata["build"] != "none")


def parse_bool(name: str, raw: str) -> bool:
    word = raw.strip().lower()
    if word in TRUE_WORDS:
        return True
    if word in FALSE_WORDS:
        return False
    raise SettingsError(
        f"{env_name(name)}={raw!r} is not a boolean; use one of "
        f"{', '.join(TRUE_WORDS + FALSE_WORDS)} (any case)"
    )


def parse_list(name: str, raw: str) -> Tuple[str, ...]:
    items = tuple(item.strip() for item in raw.split(",") if item.strip())
    choices = FIELDS[name].metadata["choices"]
    if not items and FIELDS[name].default:  # (TARGET: nothing to build; unset, it is `run`)
        raise SettingsError(
            f"{env_name(name)}={raw!r} is empty: give one or more of {', '.join(choices)} "
            "(comma-separated), or leave it unset"
        )
    bad = [item for item in items if choices and item not in choices]
    twice = sorted({i for i in items if items.count(i) > 1}) if choices else []
    if twice and not bad:  # (PLATFORM=amd64,amd64 built amd64 twice, with -amd64 tags)
        raise SettingsError(f"{env_name(name)}={raw!r}: {', '.join(twice)} given twice; "
                            "name each once")
    if bad:
        raise SettingsError(
            f"{env_name(name)}={raw!r}: {', '.join(bad)} not allowed; "
            f"allowed values: {', '.join(choices)}"
        )
    return items


# Paths on the machine that runs the tool: `~/...` is the user's home, as in a shell.
HOST_PATHS = ("build_context", "workspace", "test_results_dir", "extra_ca_certs")


def parse_value(name: str, raw: object) -> Value:
    """Turn a raw value (string from env/.env/flag, or a YAML scalar) into the field's type."""
    kind = kind_of(name)
    if kind == "bool":
        if isinstance(raw, bool):
            return raw
        return parse_bool(name, str(raw))
    if kind == "list":
        if isinstance(raw, (list, tuple)):
            raw = ",".join(str(item) for item in raw)
        return parse_list(name, str(raw))
    text = str(raw)
    if name in HOST_PATHS and text.startswith("~"):
        text = os.path.expanduser(text)  # (.env and invoke.yaml values get no shell's expansion)
    choices = FIELDS[name].metadata["choices"]
    if choices and text and text not in choices:  # (empty: unset)
        raise SettingsError(
            f"{env_name(name)}={text!r} not allowed; allowed values: {', '.join(choices)}"
        )
    if FIELDS[name].metadata["words"]:
        try:
            shlex.split(text)
        except ValueError as exc:
            raise SettingsError(f"{env_name(name)}={text!r}: {exc}: close or escape the quote"
                                ) from None
    return text


def _did_you_mean(key: str, *, upper: bool = True) -> str:
    """The closest setting, named as users write it: ENABLE_SLIM (`upper`), or enable_slim
    for an invoke.yaml key written in lower case."""
    close = difflib.get_close_matches(key.lower().replace("-", "_"), list(FIELDS), n=1)
    if not close:
        return ""
    return f" (did you mean {env_name(close[0]) if upper else close[0]}?)"


def has_bare_set(argv: Sequence[str]) -> bool:
    """Whether a `--set` on the command line has no value (the last word, or a flag follows):
    invoke passes a bare `--set` on as True only when it is the first one, and drops one that
    comes after a `--set NAME=VALUE`."""
    return any(word == "--set" and (i + 1 == len(argv) or argv[i + 1].startswith("-"))
               for i, word in enumerate(argv))


def parse_set(items: Iterable[object]) -> Dict[str, str]:
    """`--set NAME=VALUE` (repeatable) -> {field name: raw value}; NAME as in .env
    (ENABLE_SLIM) or as the flag (enable-slim). Secrets are refused: a command line is
    visible to every process on the machine. A bare `--set` reaches us as True (the flag
    takes an optional value, so that it is not dropped silently)."""
    out: Dict[str, str] = {}
    errors: List[str] = []
    for item in items:
        if not isinstance(item, str):
            errors.append("--set without a value: use --set NAME=VALUE")
            continue
        key, sep, value = item.partition("=")
        name = key.strip().lower().replace("-", "_")
        if not sep or not name:
            errors.append(f"--set {item!r}: use --set NAME=VALUE")
        elif name not in FIELDS:
            errors.append(f"--set {key}: unknown setting{_did_you_mean(name)}")
        elif is_secret(name):
            errors.append(f"--set {env_name(name)}: a secret is never given on a command line; "
                          "set it in the environment or .env")
        elif FIELDS[name].metadata["group"] == "ci":
            errors.append(f"--set {env_name(name)}: read by the CI integrations only (an input "
                          "of the Action, a variable of the GitLab template); no task reads it")
        else:
            out[name] = value
    if errors:
        raise SettingsError("invalid configuration:\n  " + "\n  ".join(errors))
    return out


def load_settings(
    *,
    invoke_config: Optional[Mapping[str, object]] = None,
    dotenv: Optional[Mapping[str, Optional[str]]] = None,
    environ: Optional[Mapping[str, str]] = None,
    flags: Optional[Mapping[str, object]] = None,
    project_dir: Optional[Path] = None,
    lenient: bool = False,
    command: str = "",
) -> Settings:
    """Merge defaults < invoke.yaml < .env < environment < flags; all errors in one message.
    `lenient`: keep going instead, invalid values stay at their defaults and are listed in
    `problems` (so that `inv config` can show a broken configuration). `command`: the task
    the settings are for (some defaults depend on it, see slim_defaults)."""
    layers: List[Tuple[str, Mapping[str, object]]] = []
    errors: List[str] = []
    problems: Dict[str, Tuple[str, str]] = {}
    yaml_values: Dict[str, object] = {}
    keys: Dict[str, str] = {}  # name -> the key that gave it
    for key, value in (invoke_config or {}).items():
        name = str(key).lower().replace("-", "_")
        if name in keys:  # (image-tag and image_tag: one setting, which would be the last)
            errors.append(f"invoke.yaml: docker_ros.{key} and docker_ros.{keys[name]} are one "
                          "setting: keep one")
            problems[f"invoke.yaml:{key}"] = ("", errors[-1])
            continue
        keys[name] = str(key)
        if name not in FIELDS:
            hint = _did_you_mean(str(key), upper=str(key).isupper())
            errors.append(f"invoke.yaml: unknown key docker_ros.{key}{hint}")
            problems[f"invoke.yaml:{key}"] = (str(value), errors[-1])
        elif is_secret(name):
            # a file of the repository, committed and copied along: never a secret's place
            errors.append(f"invoke.yaml: docker_ros.{key}: a secret is never read from invoke's "
                          "configuration (a committed or shared file); set it in the environment "
                          "or .env")
            problems[f"invoke.yaml:{key}"] = (MASKED, errors[-1])
        elif yaml_text_problem(str(key), value):
            errors.append(f"invoke.yaml: docker_ros.{key}: {yaml_text_problem(str(key), value)}")
            problems[f"invoke.yaml:{key}"] = (str(value), errors[-1])
        elif value is not None and value != "":  # (`key:` alone, like an empty variable: unset)
            yaml_values[name] = value
    layers.append(("invoke.yaml", yaml_values))
    env_layers: Tuple[Tuple[str, Mapping[str, Optional[str]]], ...] = (
        (".env", dotenv or {}),
        ("environment", environ or {}),
    )
    for source, env in env_layers:
        # An empty variable counts as unset (docker-ros's add_arg_if_set; CI inputs left blank).
        layers.append((source, {n: env[env_name(n)] for n in FIELDS if env.get(env_name(n))}))
    layers.append(("flag", {k: v for k, v in (flags or {}).items() if v is not None}))

    values: Dict[str, object] = {}
    sources: Dict[str, str] = {}
    for source, layer in layers:
        for name, raw in split_image(layer, source).items():
            value, origin = raw if isinstance(raw, Derived) else (raw, source)
            try:
                values[name] = parse_value(name, value)
            except SettingsError as exc:
                problems[name] = (str(value), f"{exc} (from {source})")
                sources[name] = source
                continue
            problems.pop(name, None)  # a later source's valid value is the one in force
            sources[name] = origin
    errors += [why for name, (_, why) in problems.items() if name in FIELDS]
    conflict = slim_conflict(values, sources)
    if conflict:
        errors.append(conflict)
        problems["enable_slim"] = ("false", conflict)
        del values["enable_slim"]
    if errors and not lenient:
        raise SettingsError("invalid configuration:\n  " + "\n  ".join(errors))
    derived = derived_defaults(values, sources, environ or {}, project_dir or Path.cwd(),
                               command)
    for name, (value, origin) in derived.items():
        values[name] = value
        if origin:
            sources[name] = origin
    given = {n: text_of(v) for n, v in layers[-1][1].items()}
    return Settings(**values, sources=sources, problems=problems,  # type: ignore[arg-type]
                    flags=given)


def yaml_text_problem(key: str, value: object) -> str:
    """What is wrong with an invoke.yaml value (key: a setting's) for a text setting that YAML
    did not read as text ('' when it is text, or a whole number: as written unless it starts
    with 0)."""
    name = key.lower().replace("-", "_")
    if kind_of(name) != "str" or value is None or (
            isinstance(value, (str, int)) and not isinstance(value, bool)):
        return ""  # (None: `key:` without a value, unset)
    if isinstance(value, float):
        # YAML reads `image_tag: 1.10` as the number 1.1: the tag would be 1.1
        return (f"YAML reads it as the number {value!r} (1.10 is 1.1 to YAML): quote the value "
                f"as you wrote it, e.g. {key}: '1.10'")
    what = ({bool: f"the boolean {str(value).lower()} (yes/no/on/off are booleans to YAML)",
             list: "a list", dict: "a mapping"}.get(type(value), type(value).__name__))
    return (f"YAML reads it as {what}, but {env_name(name)} is one text value: write it as "
            f"text, quoted, e.g. {key}: '...'")


class Derived(Tuple[object, str]):
    """A value computed from another setting, with the provenance to show for it."""


def split_image(layer: Mapping[str, object], source: str) -> Dict[str, object]:
    """IMAGE=name:tag stands for IMAGE_NAME and IMAGE_TAG at the precedence of the source that
    sets it (as docker-ros build.sh); an IMAGE_NAME/IMAGE_TAG of the same source wins."""
    out = dict(layer)
    image = out.get("image")
    if isinstance(image, str) and image:
        name, _, tag = image.rpartition(":")
        if not name or "/" in tag:  # "host:5000/img" has no tag
            name, tag = image, "latest"
        origin = f"derived from IMAGE ({source})"
        out.setdefault("image_name", Derived((name, origin)))
        out.setdefault("image_tag", Derived((tag, origin)))
    return out


def derived_defaults(
    values: Mapping[str, object],
    sources: Mapping[str, str],
    environ: Mapping[str, str],
    project_dir: Path,
    command: str = "",
) -> Dict[str, Tuple[object, str]]:
    """Defaults that depend on other values or on the CI we run in (docker-ros's rules), each
    with its provenance ('' keeps "default")."""
    out: Dict[str, Tuple[object, str]] = {}

    def origin(name: str) -> str:
        return f"derived from {env_name(name)} ({sources.get(name, 'default')})"

    name = values.get("image_name")
    if name:
        out["image_name"] = (str(name).lower(), "")
    elif environ.get("GITHUB_REPOSITORY"):
        out["image_name"] = ("ghcr.io/" + environ["GITHUB_REPOSITORY"].lower(),
                             "derived from GITHUB_REPOSITORY (environment)")
    elif environ.get("CI_REGISTRY_IMAGE"):
        out["image_name"] = (environ["CI_REGISTRY_IMAGE"].lower(),
                             "derived from CI_REGISTRY_IMAGE (environment)")
    else:
        out["image_name"] = (project_dir.resolve().name.lower(), "")
    image_name = str(out["image_name"][0])
    tag = str(values.get("image_tag", "latest"))
    for image in ("dev", "slim"):
        own = values.get(f"{image}_image_name")
        out[f"{image}_image_name"] = ((str(own).lower(), "") if own
                                      else (image_name, origin("image_name")))
        if not values.get(f"{image}_image_tag"):
            out[f"{image}_image_tag"] = (f"{tag}-{image}", origin("image_tag"))
    out.update(with_ci_tags(values, sources, out, environ))
    out.update(slim_defaults(values, sources, environ, command))
    if not values.get("platform"):
        out["platform"] = ((host_platform(),), "")
    if not values.get("workspace"):
        cache = Path(environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
        out["workspace"] = default_workspace(
            cache / "docker-ros" / "ws", project_dir.resolve().name,
            Path(str(values.get("build_context") or ".")).expanduser().resolve())
    if not values.get("registry"):
        if environ.get("GITHUB_ACTIONS"):
            out["registry"] = ("ghcr.io", "derived from GITHUB_ACTIONS (environment)")
        elif environ.get("CI_REGISTRY"):
            out["registry"] = (environ["CI_REGISTRY"], "derived from CI_REGISTRY (environment)")
    if not values.get("cache_from") and detect_pipeline(environ) is not None:
        merged = {**values, **{name: value for name, (value, _) in out.items()}}
        out["cache_from"] = (ci_cache_refs(merged),
                             "derived from the CI pipeline (its pushed dev and run images)")
    merged = {**values, **{name: value for name, (value, _) in out.items()}}
    # What holds the sources or build products (a registry cache of every stage, the build
    # state) goes where docker-ros put nothing of the kind only when asked: to
    # BUILD_STATE_REPOSITORY, or next to a dev image the pipeline pushes (it holds the sources).
    where, why = sources_repository(merged)
    if not values.get("cache_to") and detect_pipeline(environ) is not None and where:
        out["cache_to"] = (f"{where}:{merged.get('image_tag', 'latest')}-cache",
                           f"derived from the CI pipeline ({why})")
    if (not values.get("build_state_from") and detect_pipeline(environ) is not None
            and where):
        out["build_state_from"] = (
            ci_build_state_refs(merged),
            f"derived from the CI pipeline (the build state it pushes, {why})")
    for name in TURNED_OFF:  # `none`: no CI default either
        if values.get(name) in (OFF, (OFF,)):
            out[name] = (None if name == "cache_to" else (), f"{sources[name]}: {OFF}, turned off")
    return out


# Settings whose CI default `none` turns off: the registry cache (mode=max: every stage's
# layers, the sources' too) and the build state (the colcon build folder) are pushed next to the
# images, as public as they are.
TURNED_OFF = ("cache_from", "cache_to", "build_state_from")
OFF = "none"


def default_workspace(folder: Path, name: str, repository: Path) -> Tuple[str, str]:
    """WORKSPACE's default and its provenance: folder/<repository folder name>, unless that
    workspace is another repository's (its src/target link names another folder: ~/a/robot and
    ~/b/robot); then folder/<name>-<8 hex digits of the repository's path>, so that each
    repository keeps its own workspace and test results."""
    plain = folder / name
    link = plain / "src" / "target"
    if not link.is_symlink() or link.resolve() == repository:
        return str(plain), ""
    digest = hashlib.sha256(str(repository).encode()).hexdigest()[:8]
    return (str(folder / f"{name}-{digest}"),
            f"derived: {plain} is the workspace of {os.readlink(link)}")


def unpostfixed_tags(values: Mapping[str, object], tag: str) -> List[str]:
    """A tag and, when it ends with IMAGE_POSTFIX (off the default branch), the default
    branch's tag without it."""
    postfix = str(values.get("image_postfix") or "")
    return [tag] + ([tag[: -len(postfix)]] if postfix and tag.endswith(postfix) else [])


def sources_repository(values: Mapping[str, object]) -> Tuple[str, str]:
    """The repository of CI's default registry cache and build state, and why ('' none):
    BUILD_STATE_REPOSITORY, else IMAGE_NAME's when TARGET pushes the dev image."""
    if values.get("build_state_repository"):
        return str(values["build_state_repository"]), "to BUILD_STATE_REPOSITORY"
    target: Tuple[str, ...] = values.get("target") or FIELDS["target"].default  # type: ignore[assignment]
    if "dev" in target and values.get("image_name"):
        return str(values["image_name"]), "next to the dev image it pushes"
    return "", ""


def ci_build_state_refs(values: Mapping[str, object]) -> Tuple[str, ...]:
    """BUILD_STATE_FROM of a CI job: the build state this pipeline pushes, then the default
    branch's (a new branch's first job starts from it)."""
    tag = str(values.get("image_tag", "latest"))
    where = values.get("build_state_repository") or values["image_name"]
    return tuple(f"{where}:{each}-build-state" for each in unpostfixed_tags(values, tag))


def slim_conflict(values: Mapping[str, object], sources: Mapping[str, str]) -> str:
    """A `slim` target with ENABLE_SLIM=false given: the one contradiction of the two."""
    target: Tuple[str, ...] = values.get("target") or ()  # type: ignore[assignment]
    if "slim" in target and values.get("enable_slim") is False:
        return (f"TARGET ({sources.get('target')}) names slim but ENABLE_SLIM=false "
                f"({sources.get('enable_slim')}): drop one of them")
    return ""


def slim_defaults(
    values: Mapping[str, object],
    sources: Mapping[str, str],
    environ: Mapping[str, str],
    command: str,
) -> Dict[str, Tuple[object, str]]:
    """TARGET `slim` stands for the run image, slimmed (the run image joins TARGET, at the
    source of the slim target, which `ci` passes on as given). ENABLE_SLIM, unless given, keeps
    docker-ros's default (true) in CI and for the commands that make what CI pushes
    (SLIMMING_COMMANDS); a build on a developer machine slims only when asked, as docker-ros's
    local build.sh never slims (a trace and a check on every run image change)."""
    target: Tuple[str, ...] = values.get("target") or FIELDS["target"].default  # type: ignore[assignment]
    given = sources.get("target", "default")
    out: Dict[str, Tuple[object, str]] = {}
    if "slim" in target and "run" not in target:
        at = target.index("slim")
        out["target"] = (target[:at] + ("run",) + target[at:], "")
    if "enable_slim" in sources:  # given (an invalid value stays at the declared default)
        return out
    if "slim" in target:
        out["enable_slim"] = (True, f"derived from TARGET ({given})")
        return out
    pipeline = detect_pipeline(environ)
    if pipeline is not None:
        out["enable_slim"] = (True, f"derived from the CI pipeline ({pipeline.ci}): "
                                    "docker-ros's default")
    elif command in SLIMMING_COMMANDS:
        out["enable_slim"] = (True, f"derived from the command: `{command}` slims as CI does")
    else:
        out["enable_slim"] = (False, "derived: a local build slims only when asked "
                                     "(ENABLE_SLIM=true, TARGET slim or `inv slim`); "
                                     "push, ci and CI pipelines slim")
    return out


def ci_cache_refs(values: Mapping[str, object]) -> Tuple[str, ...]:
    """CACHE_FROM of a CI job on an empty runner: the dev and run images this pipeline pushes
    (also as `-<arch>`, ENABLE_SINGLEARCH_PUSH's names) and, off the default branch, those of
    the default branch (without IMAGE_POSTFIX). A ref not (yet) in the registry only costs
    BuildKit a failed look-up."""
    platforms: Tuple[str, ...] = tuple(values.get("platform") or ())  # type: ignore[arg-type]
    refs: List[str] = []
    for kind in ("dev", "run"):
        name = values["image_name" if kind == "run" else "dev_image_name"]
        tag = str(values.get("image_tag", "latest") if kind == "run" else values["dev_image_tag"])
        for each in unpostfixed_tags(values, tag):
            refs += [f"{name}:{each}"] + [f"{name}:{each}-{p}" for p in platforms]
    # the registry caches CI exports (CACHE_TO), this pipeline's and the default branch's
    run_tag = str(values.get("image_tag", "latest"))
    where = sources_repository(values)[0]  # (none by default in a run-only pipeline)
    for each in unpostfixed_tags(values, run_tag) if where else ():
        refs += [f"{where}:{each}-cache-{kind}-{p}"
                 for kind in ("dev", "run") for p in platforms]
    return tuple(dict.fromkeys(refs))


def ci_tags(values: Mapping[str, object], environ: Mapping[str, str]) -> Dict[str, object]:
    """IMAGE_POSTFIX (given, or from the CI pipeline in environ) appended to the three image
    tags, and the extra tags to push (ENABLE_PUSH_AS_LATEST, tag pipelines)."""
    pipeline = detect_pipeline(environ)
    given = values.get("image_postfix")
    postfix = tag_postfix(pipeline) if given is None else str(given)
    postfix = "" if postfix == NO_POSTFIX else postfix
    tag = str(values.get("image_tag", "latest"))
    latest = bool(values.get("enable_push_as_latest"))
    out: Dict[str, object] = {
        "image_postfix": postfix or None,
        "push_also_as": push_also_as(pipeline, image_tag=tag, enable_push_as_latest=latest,
                                     postfix=postfix),
    }
    if postfix:
        for name in ("image_tag", "dev_image_tag", "slim_image_tag"):
            out[name] = f"{values.get(name) or tag}{postfix}"
    return out


def with_ci_tags(
    values: Mapping[str, object],
    sources: Mapping[str, str],
    derived: Mapping[str, Tuple[object, str]],
    environ: Mapping[str, str],
) -> Dict[str, Tuple[object, str]]:
    """ci_tags with provenance: the tags that got IMAGE_POSTFIX say so."""
    merged = {**values, **{name: value for name, (value, _) in derived.items()}}
    tags = ci_tags(merged, environ)
    out: Dict[str, Tuple[object, str]] = {"push_also_as": (tags["push_also_as"], "")}
    if tags["image_postfix"] is None or "image_postfix" in values:
        out["image_postfix"] = (tags["image_postfix"], "")
    else:
        out["image_postfix"] = (tags["image_postfix"], "derived from the CI pipeline (environment)")
    for name in ("image_tag", "dev_image_tag", "slim_image_tag"):
        if name in tags:
            before = derived[name][1] if name in derived else sources.get(name, "default")
            out[name] = (tags[name], f"{before} + IMAGE_POSTFIX")
    return out


def host_platform() -> str:
    """This machine's architecture as Docker names it (amd64, arm64, ...)."""
    machine = os.uname().machine.lower()
    return {"x86_64": "amd64", "aarch64": "arm64"}.get(machine, machine)


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


def text_of(value: object) -> str:
    """A value as a variable would give it: true/false, a list joined with commas."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple):
        return ",".join(value)
    return str(value)


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
