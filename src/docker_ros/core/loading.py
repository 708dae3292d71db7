"""Loading the settings: parsing values, merging the layers, the defaults derived from CI."""

from __future__ import annotations

import difflib
import hashlib
import os
import shlex
from pathlib import Path
from typing import Dict, Iterable, List, Mapping, Optional, Sequence, Tuple

from docker_ros.core.ci import NO_POSTFIX, detect_pipeline, push_also_as, tag_postfix
from docker_ros.core.labels import LabelsError, parse_labels
from docker_ros.core.settings import (
    FALSE_WORDS,
    FIELDS,
    MASKED,
    SLIMMING_COMMANDS,
    TRUE_WORDS,
    Settings,
    SettingsError,
    Value,
    env_name,
    is_secret,
    kind_of,
    text_of,
)


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
    if name == "labels":
        try:
            parse_labels(text)
        except LabelsError as exc:
            raise SettingsError(f"{env_name(name)}: {exc}") from None
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
