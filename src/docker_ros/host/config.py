"""Reading the configuration sources of a project (the impure edge of settings.load_settings),
and the checks of the configuration against the repository before anything is built."""

from __future__ import annotations

import difflib
import io
import logging
import os
import re
from pathlib import Path
from typing import Dict, List, Mapping, Optional, Sequence

from docker_ros.core.ci import github_default_branch
from docker_ros.core.display import display_value
from docker_ros.core.loading import load_settings
from docker_ros.core.settings import (
    FIELDS,
    Settings,
    SettingsError,
    env_name,
    explicitly_set,
    path_settings,
)
from docker_ros.in_image.runtime.files import path_problem
from docker_ros.in_image.runtime.packages import (
    duplicates_message,
    find_package_dirs,
    listed,
    manifest_problem,
    repository_duplicates,
)
from docker_ros.in_image.runtime.repos import repos_problem
from docker_ros.in_image.runtime.rosdeprules import rules_problem
from docker_ros.in_image.runtime.workspace import read_user_text

LOG = logging.getLogger("docker_ros")
# docker's reference grammar (distribution/reference): [domain[:port]/]component(/component)*
_LABEL = r"[a-zA-Z0-9](?:[a-zA-Z0-9-]*[a-zA-Z0-9])?"
# (a first component is a domain only with a '.' or a port, or as localhost: docker's rule)
_DOMAIN = rf"(?:(?:{_LABEL}(?:\.{_LABEL})+|localhost)(?::[0-9]+)?/|{_LABEL}:[0-9]+/)"
_COMPONENT = r"[a-z0-9]+(?:(?:[._]|__|-+)[a-z0-9]+)*"
IMAGE_NAME = re.compile(rf"^{_DOMAIN}?{_COMPONENT}(?:/{_COMPONENT})*$")
IMAGE_TAG = re.compile(r"^[\w][\w.-]{0,127}$")
DIGEST = re.compile(r"^[a-z0-9]+(?:[.+_-][a-z0-9]+)*:[0-9a-fA-F]{32,}$")
POSTFIXED = " + IMAGE_POSTFIX"  # the end of the source of a tag IMAGE_POSTFIX was appended to
ENV_NAMES = [env_name(n) for n in FIELDS]
ASSIGNMENT = re.compile(r"\s*(?:export\s+)?([A-Za-z_][A-Za-z0-9_.]*)\s*=")


def read_settings(
    invoke_config: Optional[Mapping[str, object]],
    flags: Mapping[str, object],
    *,
    project_dir: Optional[Path] = None,
    environ: Optional[Mapping[str, str]] = None,
    lenient: bool = False,
    command: str = "",
) -> Settings:
    """Settings of the project in project_dir (default: cwd) from every source, for the task
    `command`."""
    project = project_dir or Path.cwd()
    env_file = project / ".env"
    text = read_user_text(env_file, SettingsError) if env_file.is_file() else ""
    unreadable = dotenv_problems(text)
    if unreadable:
        raise SettingsError(f"{env_file}: " + "; ".join(unreadable) + ": write NAME=VALUE "
                            "(quote a value with spaces or #, and close the quotes)")
    # (start-up: python-dotenv is needed only where a task reads settings, not by --help)
    from dotenv import dotenv_values
    dotenv = dotenv_values(stream=io.StringIO(text)) if env_file.is_file() else {}
    above = None if env_file.is_file() else repository_env_file(project)
    if above is not None:
        LOG.warning("docker-ros: no .env in %s, but %s has one: run docker-ros in %s (it "
                    "reads .env and BUILD_CONTEXT from the folder it runs in)", project,
                    above.parent, above.parent)
    environ = os.environ if environ is None else environ
    if environ.get("GITHUB_ACTIONS") == "true" and not environ.get("GITHUB_DEFAULT_BRANCH"):
        # GitHub has no variable for it; the event payload names it (CI tag postfix rules).
        environ = {**environ, "GITHUB_DEFAULT_BRANCH": github_default_branch(environ)}
    for warning in dotenv_warnings(dotenv) + sourced_ros_overrides(dotenv, environ):
        LOG.warning("docker-ros: %s: %s", env_file, warning)
    return load_settings(
        invoke_config=invoke_config,
        dotenv=dotenv,
        environ=environ,
        flags=flags,
        project_dir=project,
        lenient=lenient,
        command=command,
    )


def repository_env_file(folder: Path) -> Optional[Path]:
    """The .env of a folder above folder, up to its git repository's top (a folder with
    `.git`): where a user who runs docker-ros in a package folder meant to run it."""
    here = folder.resolve()
    found = None
    for each in (here, *here.parents):
        if found is None and each != here and (each / ".env").is_file():
            found = each / ".env"
        if (each / ".git").exists():
            return found
    return None  # (no repository: a .env above is nobody's to guess)


def dotenv_problems(text: str) -> List[str]:
    """The lines of a .env file python-dotenv cannot read (it would skip them with a warning,
    and the variable would silently keep another value), by line and variable name: never
    their text, which may be a secret's value (a key with an unclosed quote)."""
    # (start-up: python-dotenv is needed only where a task reads settings, not by --help)
    from dotenv.parser import parse_stream
    out = []
    for binding in parse_stream(io.StringIO(text)):
        if binding.error:
            name = ASSIGNMENT.match(binding.original.string)
            what = f"the value of {name.group(1)}" if name else "it (no NAME=VALUE)"
            out.append(f"line {binding.original.line}: cannot read {what}")
    return out


# docker-ros's earlier names (custom.sh: up to v1.6; REGISTRY_USERNAME: v1.0) -> today's
OLD_NAMES = {
    "CUSTOM_SCRIPT_FILE": "AFTER_DEPENDENCY_INSTALLATION_SCRIPT",
    "ENABLE_RECURSIVE_CUSTOM_SCRIPT": "ENABLE_RECURSIVE_AFTER_DEPENDENCY_INSTALLATION_SCRIPT",
    "REGISTRY_USERNAME": "REGISTRY_USER",
}
# `$(...)` or backticks: a shell runs them; a .env value keeps them as text
COMMAND_SUBSTITUTION = re.compile(r"\$\(|`")


def dotenv_warnings(dotenv: Mapping[str, object]) -> List[str]:
    """Variables of a .env file that look like a misspelt docker-ros variable (other variables
    are the user's business and stay silent), docker-ros variables whose value holds a
    command substitution, which docker-ros's build.sh ran (it sourced .env with bash) and which
    stays text here (COMMAND's is run by the container's shell, as a command line's), and
    those only the CI integrations read."""
    out = []
    for key, value in dotenv.items():
        if key in ENV_NAMES:
            if (key != "COMMAND" and isinstance(value, str)
                    and COMMAND_SUBSTITUTION.search(value)):
                out.append(f"{key}: its command substitution ($(...) or `...`) is not run: .env "
                           "is read as NAME=VALUE lines (${VAR} expands), not by bash as "
                           f"docker-ros's build.sh did; set {key} in the environment instead "
                           f'({key}="$(...)" inv build)')
            if FIELDS[key.lower()].metadata["group"] == "ci":
                out.append(f"{key} has no effect in .env: it is read by the CI integrations "
                           "only, as the GitHub Action's input or the GitLab template's variable")
            continue
        if key.upper() in OLD_NAMES:
            out.append(f"{key} ignored: docker-ros's earlier name, now "
                       f"{OLD_NAMES[key.upper()]}")
            continue
        meant = look_alike(key)
        if meant:
            out.append(f"unknown variable {key} ignored (did you mean {meant}?)")
    return out


# What a shell where ROS is sourced exports: beating .env (environment > .env), unseen
SOURCED_ROS = ("ROS_DISTRO", "RMW_IMPLEMENTATION")


def sourced_ros_overrides(dotenv: Mapping[str, object], environ: Mapping[str, str]
                          ) -> List[str]:
    """The .env values of SOURCED_ROS that another value in the environment overrides (not
    in CI, whose inputs and variables are meant to)."""
    if environ.get("CI"):
        return []
    return [f"{key}={dotenv[key]} is overridden by the environment's {key}={environ[key]} (a "
            f"shell where ROS is sourced exports it): `unset {key}` to build with .env's"
            for key in SOURCED_ROS
            if dotenv.get(key) and environ.get(key) and environ[key] != dotenv[key]]


def look_alike(key: str) -> Optional[str]:
    """The docker-ros variable key misspells, if any: a close name (ENABLE_SLIMM), or the one
    name of the same first word and one word more that has the key's words at the start of
    its own, in order (GIT_PASSWORD: GIT_HTTPS_PASSWORD; ENABLE_RECURSIVE_DEBS:
    ..._ADDITIONAL_DEBS; not ROS_VERSION: ROS_APT_SOURCE_VERSION)."""
    close = difflib.get_close_matches(key.upper(), ENV_NAMES, n=1, cutoff=0.85)
    if close:
        return close[0]
    words = key.upper().split("_")
    if len(words) < 2:
        return None
    kin = [name for name in ENV_NAMES
           if len(name.split("_")) - len(words) <= 1 and words_within(words, name.split("_"))]
    return kin[0] if len(kin) == 1 else None


def words_within(words: Sequence[str], name: Sequence[str]) -> bool:
    """Whether name starts with words[0] and each later word begins a later word of name."""
    if not name or name[0] != words[0]:
        return False
    rest = iter(name[1:])
    return all(any(part.startswith(word) for part in rest) for word in words[1:])


def path_problems(settings: Settings) -> Dict[str, str]:
    """Setting name -> what is wrong with it: BUILD_CONTEXT that is no folder, path settings
    leaving the repository, explicitly set files or folders that do not exist (EXTRA_CA_CERTS
    too, which is no path in the repository)."""
    repository = Path(settings.build_context).expanduser()
    if not repository.is_dir():
        return {"build_context": f"BUILD_CONTEXT '{settings.build_context}' is not a folder: "
                                 "set it to the ROS repository to build"}
    problems: Dict[str, str] = {}
    if settings.extra_ca_certs and not Path(settings.extra_ca_certs).exists():
        # (a path on this machine, not in the repository: the build would stop on it later)
        problems["extra_ca_certs"] = (f"EXTRA_CA_CERTS '{settings.extra_ca_certs}' not found: "
                                      "give a PEM file or a folder of them")
    for name in path_settings():
        value = str(getattr(settings, name))
        problem = path_problem(repository, value)
        if problem:
            problems[name] = (f"{env_name(name)}={value!r} {problem}: give a path inside the "
                              "repository")
            continue
        kind = FIELDS[name].metadata["path"]
        switch = FIELDS[name].metadata["recursive"]
        recursive = bool(switch and getattr(settings, switch))
        path = repository / value
        exists = path.is_dir() if kind == "dir" else path.is_file()
        if path.exists() and not exists:
            wanted, found = ("folder", "file") if kind == "dir" else ("file", "folder")
            problems[name] = (f"{env_name(name)} '{value}' is a {found}, not a {wanted}: give "
                              f"the path of a {wanted}")
            continue
        # With recursive discovery the file may come with the imported repositories (a
        # VCS_IMPORT_FILE only if a .repos file is somewhere to import them, or a hook may
        # write one).
        if (recursive and name == "vcs_import_file" and not exists
                and explicitly_set(settings, name)):
            recursive = (repository / settings.before_dependency_identification_script
                         ).is_file() or any(f.is_file() for f in repository.rglob("*.repos"))
        if explicitly_set(settings, name) and not exists and not recursive:
            problems[name] = (f"{env_name(name)} '{value}' not found in the repository, but "
                              "set explicitly: fix the path or unset it")
    return problems


def content_problems(settings: Settings) -> Dict[str, str]:
    """Setting name -> what is wrong inside the file it names: a rosdep rules file that is not
    valid YAML (rosdep would skip it and the build go on without its rules), the repository's
    .repos file that vcstool cannot read (the clone step would stop on it); and two packages
    of the repository with the same name (the build would stop in its blacklist step)."""
    repository = Path(settings.build_context).expanduser()
    problems: Dict[str, str] = {}
    rules = repository / settings.rosdep_rules_file
    problem = rules_problem(rules, settings.rosdep_rules_file) if rules.is_file() else None
    if problem:
        problems["rosdep_rules_file"] = problem
    repos = repository / settings.vcs_import_file
    problem = repos_problem(repos, settings.vcs_import_file) if repos.is_file() else None
    if problem:
        problems["vcs_import_file"] = f"VCS_IMPORT_FILE {problem}"
    problems.update(list_file_problems(settings, repository))
    package_dirs = find_package_dirs(repository)  # (one walk of the repository for both checks)
    broken = [f"{d.relative_to(repository).as_posix()}/package.xml {problem}"
              for d in package_dirs for problem in [manifest_problem(d)] if problem]
    duplicates = repository_duplicates(repository, package_dirs)
    if broken:
        problems["packages"] = (f"{listed(broken)}: fix it, or put a CATKIN_IGNORE file in its "
                                "folder (colcon and rosdep would stop on it)")
    elif duplicates:
        problems["packages"] = duplicates_message(duplicates)
    inputs = [name for name in path_settings() if (repository / getattr(settings, name)).exists()]
    if not inputs and not package_dirs and not any(repository.rglob("*.repos")):
        problems["packages"] = (
            f"BUILD_CONTEXT '{repository.resolve()}' holds no ROS package (package.xml), no "
            ".repos file and none of docker-ros's input files: run this in your ROS repository, "
            "or set BUILD_CONTEXT to it")
    return problems


# The list files the steps read as text (a script is bash's to read).
LIST_FILES = ("additional_debs_file", "additional_pip_file", "blacklisted_packages_file")


def list_file_problems(settings: Settings, repository: Path) -> Dict[str, str]:
    """The repository's list files that are not UTF-8 text, named as the settings give them."""
    problems: Dict[str, str] = {}
    for name in LIST_FILES:
        value = str(getattr(settings, name))
        if (repository / value).is_file():
            try:
                read_user_text(repository / value, ValueError, value)
            except ValueError as exc:
                problems[name] = f"{env_name(name)} {exc}"
            except OSError as exc:
                problems[name] = f"{env_name(name)} {value}: cannot be read ({exc.strerror})"
    return problems


def input_problems(settings: Settings, targets: Sequence[str], *, images: bool) -> Dict[str, str]:
    """Everything wrong with the inputs (paths, with `images` image names, then the content of
    the files that exist), all at once, before anything runs."""
    problems = {**path_problems(settings),
                **(image_problems(settings, targets) if images else {})}
    if not problems.keys() & {"build_context", "rosdep_rules_file", "vcs_import_file"}:
        problems.update(content_problems(settings))
    return problems


def image_problems(settings: Settings, targets: Sequence[str]) -> Dict[str, str]:
    """Image names and tags docker would refuse, named by the setting they come from (a
    `slim` target: the slim image's); BASE_IMAGE's reference."""
    refs = {"image_name": ("image_name", "image_tag")}
    for kind in ("dev", "slim"):
        if kind in targets:
            refs[f"{kind}_image_name"] = (f"{kind}_image_name", f"{kind}_image_tag")
    problems: Dict[str, str] = {}
    if settings.base_image and not valid_reference(settings.base_image):
        problems["base_image"] = (
            f"BASE_IMAGE ({settings.source_of('base_image')}): {settings.base_image!r} is not a "
            "valid image reference: give [registry/]name[:tag][@digest], the name in lower case")
    told = set()  # the variables a reported value came from: a value derived from the same
    # one (DEV_IMAGE_TAG from IMAGE) is the same mistake, told once
    for name_field, tag_field in refs.values():
        for field, pattern in ((name_field, IMAGE_NAME), (tag_field, IMAGE_TAG)):
            value = str(getattr(settings, field))
            root = root_variable(settings, field, settings.source_of(field))
            if pattern.match(value) or root in told:
                continue
            told.add(root)
            kind = "name" if field.endswith("name") else "tag"
            problems[field] = (f"{origin_of(settings, field)}: {value!r} is not a valid image "
                               f"{kind}: {IMAGE_RULES[kind]}")
            if root == "IMAGE" and "@" in (settings.image or ""):
                problems[field] += " (IMAGE takes name[:tag], no @digest)"
    return problems


IMAGE_RULES = {
    "name": "lower-case letters, digits and . _ - between /, after an optional registry "
            "host[:port]/",
    "tag": "up to 128 letters, digits, _ . and -, not starting with . or -",
}


def valid_reference(ref: str) -> bool:
    """Whether docker accepts ref as an image reference: name[:tag][@digest]."""
    rest, at, digest = ref.partition("@")
    name, colon, tag = rest.rpartition(":")
    if not colon or "/" in tag:  # "host:5000/img" has no tag
        name, tag = rest, "latest"
    return (bool(IMAGE_NAME.match(name)) and bool(IMAGE_TAG.match(tag))
            and (not at or bool(DIGEST.match(digest))))


def root_variable(settings: Settings, name: str, source: str) -> str:
    """The variable a value derived from IMAGE, IMAGE_NAME or IMAGE_TAG comes from in the end
    (DEV_IMAGE_TAG <- IMAGE_TAG <- IMAGE), else the setting's own."""
    if source.startswith("derived from IMAGE "):
        return "IMAGE"
    upstream = re.match(r"derived from (IMAGE_NAME|IMAGE_TAG) ", source)
    if upstream:
        name = upstream.group(1).lower()
        return root_variable(settings, name, settings.source_of(name))
    return env_name(name)


def origin_of(settings: Settings, name: str, source: str = "") -> str:
    """The variable a (maybe derived) value comes from, for messages; a tag with
    IMAGE_POSTFIX appended names it too, with its source."""
    source = source or settings.source_of(name)
    if source.endswith(POSTFIXED):
        return (f"{origin_of(settings, name, source[:-len(POSTFIXED)])} + IMAGE_POSTFIX "
                f"({settings.source_of('image_postfix')})")
    root = root_variable(settings, name, source)
    if root != env_name(name):
        return f"{env_name(name)} (from {root})"
    if source != "default" and not source.startswith("derived"):
        return env_name(name)
    if name == "image_name":
        return "IMAGE_NAME (from the repository folder name: set IMAGE or IMAGE_NAME)"
    return env_name(name)


def rmw_chosen(settings: Settings) -> bool:
    """Whether somebody chose RMW_IMPLEMENTATION: a value other than the default, or the default
    written in .env, invoke.yaml or a flag (the CI integrations pass the default on in the
    environment). Unchosen, a base image's own stays (see build.arg_values)."""
    return (explicitly_set(settings, "rmw_implementation")
            or settings.source_of("rmw_implementation") not in ("default", "environment"))


def config_table(settings: Settings, problems: Optional[Mapping[str, str]] = None,
                 missing: Sequence[str] = ()) -> str:
    """Every setting with its effective value and where it came from; secrets masked; invalid
    values shown as given and marked, and the `missing` ones a build requires."""
    bad = set(settings.problems) | set(problems or {})
    rows = []
    for n in FIELDS:
        value = display_value(settings, n)
        mark = ("  <- INVALID" if n in bad
                else "  <- MISSING (a build needs it)" if n in missing else "")
        source = settings.source_of(n)
        if n in settings.problems and not FIELDS[n].metadata["secret"]:
            value = settings.problems[n][0]
        elif n == "test_results_dir" and not value and settings.workspace:
            # where `inv test` writes when nothing names a folder (pipeline.results_root)
            value = str(Path(settings.workspace).expanduser() / "test-results")
            source = "derived from WORKSPACE (the tests' results stay out of the repository)"
        elif n == "rmw_implementation" and not rmw_chosen(settings):
            source += " (not chosen: a base image's own RMW_IMPLEMENTATION stays)"
        rows.append((env_name(n), value, source + mark))
    width = max(len(r[0]) for r in rows)
    value_width = min(60, max(len(r[1]) for r in rows))
    lines = [f"{'VARIABLE'.ljust(width)}  {'VALUE'.ljust(value_width)}  SOURCE"]
    for name, value, source in rows:
        lines.append(f"{name.ljust(width)}  {value.ljust(value_width)}  {source}")
    return "\n".join(lines)
