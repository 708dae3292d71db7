"""The configuration reference: a table of every setting, made from the settings' declarations
and the tasks' flags. The docs build renders it (docs/_ext/docker_ros_docs.py); nobody keeps it
by hand. `python -m docker_ros.cli.reference` prints it."""

from __future__ import annotations

import inspect
import re
from typing import Dict, List, Sequence

from docker_ros.cli.tasks import ns
from docker_ros.core.display import markdown_table
from docker_ros.core.settings import FIELDS, env_name, flag_name, is_secret
from docker_ros.in_image.steps import BY_NAME, STEPS


def task_flags(name: str) -> List[str]:
    """The flags of a task, in its signature's order: read from the signature, not from
    `Task.help`, which invoke empties as it builds the command line's parser."""
    return list(inspect.signature(ns[name].body).parameters)[1:]


def flag_tasks() -> Dict[str, List[str]]:
    """Setting name -> the tasks that have it as a flag."""
    out: Dict[str, List[str]] = {}
    for name in sorted(ns.task_names):
        for flag in task_flags(name):
            if flag in FIELDS:
                out.setdefault(flag, []).append(name)
    return out


def tasks_phrase(tasks: Sequence[str], every: Sequence[str], steps: Sequence[str]) -> str:
    """The tasks that have a flag, in the fewest names: listed, "the step tasks" and the
    others, or "every task but" those without it (names listed on a tie)."""
    others = [t for t in tasks if t not in steps]
    missing = [t for t in every if t not in tasks]
    if not missing:
        return "every task"
    phrases = [(len(tasks), ", ".join(tasks)),
               (1 + len(missing), "every task but " + ", ".join(missing))]
    if set(steps) <= set(tasks):
        phrases.append((1 + len(others), ", ".join(["the step tasks", *others])))
    return min(phrases, key=lambda phrase: phrase[0])[1]


def table() -> str:
    """The reference as a Markdown table, one row per declared setting."""
    every = sorted(ns.task_names)
    return markdown_table({name: tasks_phrase(tasks, every, STEPS)
                           for name, tasks in flag_tasks().items()})



def step_settings() -> Dict[str, List[str]]:
    """Step -> the settings its task takes as flags beyond those every step task takes."""
    flags = {step: [f for f in task_flags(step) if f in FIELDS and not is_secret(f)]
             for step in STEPS}
    common = set.intersection(*(set(names) for names in flags.values()))
    return {step: [f for f in names if f not in common] for step, names in flags.items()}


def common_step_flags() -> List[str]:
    """The flags every step task takes (its own options and the settings they share)."""
    sets = [set(task_flags(step)) for step in STEPS]
    return ["--" + f.replace("_", "-") for f in task_flags(STEPS[0])
            if all(f in s for s in sets) and not (f in FIELDS and is_secret(f))]


def steps_table() -> str:
    """The ten steps as a Markdown table: task, what it does, and the settings its task takes
    (as flags, or in .env and the environment), from the step declarations and the tasks."""
    rows = ["| # | step | task | does | its settings (flags) |", "|---|---|---|---|---|"]
    for number, (step, names) in enumerate(step_settings().items(), 1):
        settings = ", ".join(f"`{env_name(n)}` (`{flag_name(n)}`)" for n in names)
        rows.append(f"| {number} | {step} | `inv {step}` | {BY_NAME[step].help} | {settings} |")
    return "\n".join(rows)


_FROM = re.compile(r"^FROM\s+(\S+)\s+AS\s+(\S+)", re.IGNORECASE)
_ARG = re.compile(r"^ARG\s+(\w+)(?:=(\S*))?")
_COPIED = re.compile(r"(?:--from=|\bfrom=)([\w.-]+)")


def stage_graph(dockerfile: str) -> str:
    """The Dockerfile's stages as a text tree: each stage under the stage it is FROM (a
    `FROM ${ARG}` under the ARG's default, named), with the stages it copies or mounts from."""
    defaults: Dict[str, str] = {}
    parent: Dict[str, str] = {}
    via: Dict[str, str] = {}
    uses: Dict[str, List[str]] = {}
    stage = ""
    for line in dockerfile.splitlines():
        line = line.strip()
        arg, match = _ARG.match(line), _FROM.match(line)
        if arg and not stage:
            defaults[arg.group(1)] = arg.group(2) or ""
        elif match:
            source, stage = match.groups()
            parent[stage], uses[stage] = source, []
            if source.startswith("${"):
                name = source[2:-1]
                parent[stage] = defaults.get(name) or f"${{{name}}}"
                if defaults.get(name):
                    via[stage] = f"FROM ${{{name}}}, by default"
        elif stage:
            for used in _COPIED.findall(line):
                if used != parent[stage] and used not in uses[stage]:
                    uses[stage].append(used)
    children: Dict[str, List[str]] = {}
    for name, source in parent.items():
        children.setdefault(source, []).append(name)
    roots = [source for source in children if source not in parent]
    lines: List[str] = []

    def show(name: str, prefix: str, last: bool, top: bool) -> None:
        notes = []
        if name in via:
            notes.append(via[name])
        if uses.get(name):
            notes.append("uses " + ", ".join(uses[name]))
        if top:
            lines.append(name + ("" if name in parent else " (build argument)" if "$" in name
                                 else " (empty)" if name == "scratch"
                                 else " (not a stage of this Dockerfile)"))
        else:
            lines.append(prefix + ("└── " if last else "├── ") + name
                         + (f"   [{'; '.join(notes)}]" if notes else ""))
        kids = children.get(name, [])
        deeper = "" if top else prefix + ("    " if last else "│   ")
        for index, kid in enumerate(kids):
            show(kid, deeper, index == len(kids) - 1, False)

    for root in roots:
        show(root, "", True, True)
    return "\n".join(lines)


if __name__ == "__main__":
    print(table())
