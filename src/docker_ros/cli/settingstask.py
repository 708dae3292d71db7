"""How a docker-ros task becomes an invoke Task: its flags from the setting declarations, the
settings loaded before its body, its errors and interruptions as one line and an exit code."""

from __future__ import annotations

import copy
import inspect
import os
import signal
import sys
import textwrap
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple, Union

from invoke import Argument, Collection, Context, Exit, Task

from docker_ros.core.display import default_doc
from docker_ros.core.errors import DockerRosError
from docker_ros.core.settings import (
    FIELDS,
    SettingsError,
    env_name,
    flag_name,
    is_secret,
    kind_of,
    settings_where,
)
from docker_ros.in_image.runtime.workspace import StepError, setup_logging

Flag = Tuple[str, object, str]  # name, default, help
DRY_RUN: Flag = ("dry_run", False, "Print exactly what would be done; change nothing")
HOST: Flag = ("host", False, "Run the steps directly on this machine instead of in an image")
IN_CONTAINER: Flag = (
    "in_container", False,
    "Run in a container of the image state just before the step (built up to there), the "
    "repository mounted when the step reads sources; tag the result <IMAGE>-after-<step>",
)
SHELL_ON_FAILURE: Flag = (
    "shell_on_failure", False,
    "When a step fails, open a shell in the state just before the failed command (no "
    "terminal: tag that state <IMAGE>-failed-<step> and print how to enter it)",
)


# Settings every image, host-step or pushing task takes as flags (their declarations' `flags`);
# any other setting: --set NAME=VALUE.
IMAGE_SETTINGS = settings_where("flags", "image")
HOST_SETTINGS = settings_where("flags", "host")
PUSH_SETTINGS = settings_where("flags", "push")
SET: Flag = ("set", None, "Any setting, as NAME=VALUE (repeatable), e.g. --set ENABLE_SLIM=false")
# Secrets are never flags (a command line is visible to every process on the machine): none
# is in --help, and one given is refused saying where it goes instead of invoke's "No idea what".
SECRETS = settings_where("secret", True)


def secret_flag_refusal(task: str, given: Sequence[str]) -> str:
    """The message for secrets given as flags ('' when none was)."""
    if not given:
        return ""
    names = ", ".join(env_name(n) for n in given)
    label = f"docker-ros {task}" if task else "docker-ros"
    return (f"{label}: {' and '.join(flag_name(n) for n in given)}: a secret is never "
            f"a flag (a command line is visible to every process on this machine); set {names}"
            " in the environment or in the project's .env file")


def secret_flags_given(argv: Sequence[str], collection: Collection) -> Tuple[str, List[str]]:
    """The secrets given as flags in a command line (argv after the program), and the task they
    were given to: the last task name before them that is no flag's value."""
    flags = {flag_name(n): n for n in SECRETS}
    names = set(collection.task_names) | {a for v in collection.task_names.values() for a in v}
    task, given, after_value_flag = "", [], False
    for token in argv:
        if token == "--":  # (what follows is a command's, not ours)
            break
        flag = token.split("=", 1)[0]
        if flag in flags:
            given.append(flags[flag])
        elif token in names and not after_value_flag and not given:
            task = token
        after_value_flag = token.startswith("--") and "=" not in token and takes_value(
            collection, task, token)
    return task, list(dict.fromkeys(given))


def takes_value(collection: Collection, task: str, flag: str) -> bool:
    """Whether a flag of the task takes the next word as its value: neither a switch (a bool
    default) nor one whose value is optional. (From the task's signature: invoke's
    get_arguments would use up the task's help texts.)"""
    if task not in collection.task_names:
        return False
    name = flag[2:].replace("-", "_")
    parameter = inspect.signature(collection[task].body).parameters.get(name)
    return (parameter is not None and name not in collection[task].optional
            and not isinstance(parameter.default, bool))


def refuse_secret_flags(argv: Sequence[str], collection: Collection) -> None:
    """Before invoke parses the command line: a secret given as a flag ends the program with
    secret_flag_refusal (exit code 2); the value is never shown."""
    task, given = secret_flags_given(argv, collection)
    if given:
        print(secret_flag_refusal(task, given), file=sys.stderr, flush=True)
        raise SystemExit(2)


class SettingsTask(Task):
    """A Task with chosen short flags (e.g. dev-shell's -c) although auto_shortflags is off:
    automatic ones would differ between tasks, as every setting is a flag of every task."""

    def __init__(self, *args: Any, shortflags: Mapping[str, str], **kwargs: Any) -> None:
        self.shortflags = shortflags
        super().__init__(*args, **kwargs)

    def arg_opts(self, name: str, default: str, taken_names: Any) -> Dict[str, Any]:
        opts = super().arg_opts(name, default, taken_names)
        if name in self.shortflags:
            opts["names"].append(self.shortflags[name])
        return opts

    def get_arguments(self, ignore_unknown_help: Optional[bool] = None) -> List[Argument]:
        """A repeatable flag with an optional value (--set) starts without a raw value, so that
        invoke gives a bare one True (invoke would drop it silently): parse_set refuses it.
        Every flag is a TaskArgument (quick to copy); a whole-number flag refuses another value
        as one line (WholeNumberArgument). The task's
        help texts stay (invoke pops each as it makes the flag: a second parser, the docs'
        reference or a test reading them found none)."""
        kept = dict(self.help)
        try:
            args = super().get_arguments(ignore_unknown_help)
        finally:
            self.help = kept
        for arg in args:
            if arg.kind is list and arg.optional:
                arg.raw_value = None
        return [(WholeNumberArgument if arg.kind is int else TaskArgument).of(arg, self.name)
                for arg in args]

    def __deepcopy__(self, memo: Dict[int, Any]) -> SettingsTask:
        """A copy sharing the signature, which is immutable: `inv` copies every task as it
        loads tasks.py, and copy.deepcopy rebuilt each of the ~15 inspect.Parameter objects."""
        made = type(self).__new__(type(self))
        made.__dict__.update({key: value if key == "__signature__" else copy.deepcopy(value, memo)
                              for key, value in vars(self).items()})
        return made


# What TaskArgument shares with its copies (an Argument's names are a tuple of strings).
IMMUTABLE = (str, int, float, tuple, type, type(None))


class TaskArgument(Argument):
    """invoke's Argument, copied in one step: invoke's parser deep-copies every task's flags
    (~330) each time it parses a command line, and copy.deepcopy's generic walk over them took
    as long as the rest of `--help` after the imports. The lists (a repeatable flag's values
    and default) are copied; the other attributes (names, help, kind...) are immutable and
    shared."""

    task = ""

    @classmethod
    def of(cls, arg: Argument, task: str) -> TaskArgument:
        """arg (as invoke's Task.get_arguments made it) as one of ours, for task."""
        made = cls.__new__(cls)
        made.__dict__.update(vars(arg))
        made.task = task
        return made

    def __deepcopy__(self, memo: Dict[int, Any]) -> TaskArgument:
        made = type(self).__new__(type(self))
        made.__dict__.update({key: value if isinstance(value, IMMUTABLE) else
                              copy.deepcopy(value, memo) for key, value in vars(self).items()})
        return made


class WholeNumberArgument(TaskArgument):
    """An int flag whose value invoke's parser cannot convert (`--seconds abc`) ends the program
    as one line, exit code 2 (invoke's Argument would raise a ValueError: a traceback)."""

    def set_value(self, value: Any, cast: bool = True) -> None:
        try:
            super().set_value(value, cast)
        except ValueError:
            flag = "--" + str(self.name).replace("_", "-")
            raise Exit(f"docker-ros {self.task}: {flag} takes a whole number, not {value!r}",
                       code=2) from None


def settings_task(
    name: str,
    help: str,
    flags: Sequence[Flag] = (),
    uses: Sequence[str] = (),
    shortflags: Mapping[str, str] = {},
    lenient: bool = False,
    logs_in: Union[bool, str] = False,
    login_required: bool = False,
    helps: Mapping[str, str] = {},
) -> Callable[..., Task]:
    """Make an invoke Task whose flags are the task's own, one per setting it uses, and
    --set NAME=VALUE for any other setting (the full reference: the docs' configuration
    reference and `inv config`);
    a flag whose default is a list may be given several times. `lenient`: invalid values
    reach the task in Settings.problems instead of stopping it. `logs_in`: a task that reaches
    a registry (a private BASE_IMAGE, CACHE_FROM/CACHE_TO, pushes) runs logged in with
    REGISTRY_USER/REGISTRY_PASSWORD when they are set, in a DOCKER_CONFIG of its own, removed
    at its end (see logs_in_now); a failed login stops only a task that `login_required`
    (pushes), others go on with a warning (they may need no registry). `helps`: a setting's
    flag help where this task needs another than the declaration's."""

    def decorate(func: Callable[..., Any]) -> Task:
        own = [f[0] for f in flags]
        settings_flags = [n for n in dict.fromkeys(uses) if n not in own and not is_secret(n)]

        def body(c: Context, **kwargs: Any) -> Any:
            # (start-up: the host modules (build, pipeline and the docker SDK under them) cost
            # ~0.1-0.3 s, reading settings (core.loading, core.ci) ~10 ms; --help and --list
            # need only the task declarations)
            from docker_ros.core.ci import error_annotation  # (start-up, as above)
            from docker_ros.core.loading import has_bare_set, parse_set  # (start-up, as above)
            from docker_ros.host import engine, faults
            from docker_ros.host.config import read_settings  # (start-up, as above)
            from docker_ros.host.pipeline import TaskFailed, logged_in_job  # (start-up, as above)
            setup_logging()
            hear_interrupts()
            if invoke_dry(c):
                # invoke's -R/--dry means "do not act": our dry run, or a refusal, never ignored.
                if "dry_run" not in kwargs:
                    raise Exit(f"docker-ros {name}: has no dry run; invoke's -R/--dry is only "
                               "accepted by tasks with --dry-run", code=2)
                kwargs["dry_run"] = True
            try:
                # A named flag beats a --set of the same setting.
                given = list(kwargs.pop("set") or ())
                # (a flag after a bare --set may have been taken as its value: refused already)
                if has_bare_set(sys.argv[1:]) and not any(
                        item is True or str(item).startswith("-") for item in given):
                    given.append(True)
                overrides: Dict[str, object] = dict(parse_set(given))
                overrides.update({n: kwargs.pop(n) for n in settings_flags
                                  if kwargs[n] is not None})
                for n in settings_flags:
                    kwargs.pop(n, None)
                near = [k for k in c.config if k != "docker_ros" and
                        str(k).lower().replace("-", "_") in ("docker_ros", "dockerros")]
                if near:  # (its settings would be ignored without a word)
                    raise SettingsError(f"invoke configuration: `{near[0]}:` is not read; the "
                                        "settings go under `docker_ros:`")
                cfg = c.config.get("docker_ros", None) or {}
                if not isinstance(cfg, Mapping):
                    raise SettingsError(f"invoke configuration: `docker_ros:` is {cfg!r}: "
                                        "give it the settings as NAME: value lines")
                settings = read_settings(dict(cfg), overrides, lenient=lenient, command=name)
                if not logs_in_now(logs_in, kwargs):
                    return func(c, settings, **kwargs)
                with logged_in_job(settings, f"docker-ros {name}", required=login_required,
                                   dry_run=bool(kwargs.get("dry_run"))):
                    return func(c, settings, **kwargs)
            except KeyboardInterrupt as exc:
                # (a build's names what BuildKit had tagged before the Ctrl-C: build.noted)
                detail = f" ({exc})" if str(exc) else ""
                if isinstance(exc, Terminated):
                    raise Exit(f"docker-ros {name}: terminated (SIGTERM){detail}",
                               code=143) from None
                raise Exit(f"docker-ros {name}: interrupted{detail}", code=130) from None
            except faults.TRANSPORT_ERRORS as exc:  # (the Engine API's transport)
                raise Exit(f"docker-ros {name}: " + faults.engine_lost_line(
                    faults.task_doing(name), faults.request_detail(exc)), code=1) from None
            except DockerRosError as exc:  # (the one place that reports them)
                code = exc.exit_code
                where = exc.step if isinstance(exc, StepError) else name
                text = exc.message if isinstance(exc, StepError) else str(exc)
                lost = faults.lost_during(faults.task_doing(name), text,
                                          answered=engine.answered(),
                                          answers=faults.engine_answers)
                if lost:  # (e.g. a container the engine's shutdown stopped)
                    where, text, code = name, lost, 1
                annotation = error_annotation(os.environ, f"docker-ros {where}", text)
                if annotation and not isinstance(exc, TaskFailed):  # (the task's is there)
                    print(annotation, flush=True)
                raise Exit(f"docker-ros {where}: {text}", code=code) from None

        keyword = inspect.Parameter.KEYWORD_ONLY
        params = [inspect.Parameter("c", inspect.Parameter.POSITIONAL_OR_KEYWORD)]
        params += [inspect.Parameter(n, keyword, default=d) for n, d, _ in [*flags, SET]]
        # Secrets get no flag: a command line is visible to every process on the machine
        # (refuse_secret_flags says so before invoke parses one).
        params += [inspect.Parameter(n, keyword, default=None) for n in settings_flags]
        body.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
        # First paragraph: the one line of `--list` (at most 76 characters, a test checks);
        # the others wrapped for 80 columns.
        first, *rest = help.split("\n\n")
        body.__doc__ = "\n\n".join([first, *(textwrap.fill(part, 76) for part in rest)])
        body.__name__ = name.replace("-", "_")
        help_map: Dict[str, str] = {n: h for n, _, h in [*flags, SET]}
        for n in settings_flags:
            help_map[n] = helps.get(n) or setting_help(n)
        repeatable = ["set"] + [n for n, d, _ in flags if isinstance(d, list)]
        # `--enable-slim` alone means true; `--enable-slim=false` (or a value after it) too.
        # A bare --set gets True that way (invoke drops an empty one): parse_set refuses it.
        optional = [n for n in settings_flags if kind_of(n) == "bool"] + ["set"]
        return SettingsTask(body, name=name, help=help_map, auto_shortflags=False,
                            iterable=repeatable, optional=optional, shortflags=shortflags)

    return decorate


def logs_in_now(logs_in: Union[bool, str], flags: Mapping[str, object]) -> bool:
    """Whether a task logs in: `logs_in` True (not with --host, on this machine), or the name
    of the flag that makes it reach a registry (a step's --in-container)."""
    if isinstance(logs_in, str):
        return bool(flags.get(logs_in))
    return logs_in and not flags.get("host")


class Terminated(KeyboardInterrupt):
    """SIGTERM (a cancelled CI job, `timeout`, `kill`), handled as Ctrl-C is: what the task
    made (a login's DOCKER_CONFIG, a key file, temporary folders) is removed on the way out."""


def terminated(signum: int, frame: Any) -> None:
    # Once: a second SIGTERM (the job's runner and `docker-ros ci` may both send one) must not
    # cut short the clean-up the first one started.
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise Terminated


def hear_interrupts() -> None:
    """Ctrl-C raises KeyboardInterrupt (exit 130, "interrupted") even when we started with
    SIGINT ignored, as a background job of a script does: buildx and docker (Go) stop on it
    anyway, and their failure must not be reported as a failed build. SIGTERM raises
    Terminated (exit 143), whose way out runs the same clean-ups."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, terminated)


def setting_help(name: str) -> str:
    """A setting's flag help: its description and default (the flag names the variable).
    A default with a word too long for the help column (which invoke would break) is left to
    `inv config`."""
    default = default_doc(name).replace("`", "").replace("*", "")
    text = str(FIELDS[name].metadata["help"])
    # (the defaults of the CI integrations are not this machine's: the reference lists them)
    if (not default or max(len(word) for word in default.split()) > 26
            or default.startswith("GitHub Action:")):
        return text
    if default.startswith("required"):  # no default: a value must be given
        return f"{text} ({default})"
    return f"{text} (default: {default})"


def invoke_dry(c: Context) -> bool:
    """invoke's core flag -R/--dry (config run.dry)."""
    try:
        return bool(c.config.run.dry)
    except AttributeError:
        return False
