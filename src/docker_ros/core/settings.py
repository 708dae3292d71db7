"""The one typed settings object: every docker-ros variable declared once (loading.py loads it,
display.py shows it)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, List, Mapping, Optional, Tuple, Union

from docker_ros.core.errors import DockerRosError

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


class SettingsError(DockerRosError, ValueError):
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
        "Build every stage anew, reusing no layer of the builder's cache (`--no-cache`), even"
        " when nothing changed since the last build; the cache mounts stay (apt's downloads,"
        " the colcon build/ cache of this repository)",
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
    labels: str = setting(
        "",
        "Labels of your own for the dev, run and slim images: `key=value` entries, comma-"
        "separated or one a line (they win over the `org.opencontainers.image.*` labels"
        " docker-ros sets; `org.docker-ros.*` are docker-ros's own)",
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


def text_of(value: object) -> str:
    """A value as a variable would give it: true/false, a list joined with commas."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple):
        return ",".join(value)
    return str(value)


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
