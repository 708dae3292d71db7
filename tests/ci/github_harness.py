"""Runs action.yml's steps in order the way the GitHub runner does for a composite action, as
far as this machine allows.

What GitHub does and this harness does too:
- `inputs`: the `with:` values over the inputs' defaults; defaults may hold expressions over
  `github` (evaluated like GitHub does); every input also as `INPUT_<NAME>` in the environment.
- `${{ ... }}` in `if:`, `env:`, `with:`, `working-directory:` evaluated over the contexts
  `inputs`, `github`, `steps`, `runner`, `env`; a `run:` script is taken verbatim (a test checks
  it holds no expression: that would be a script-injection hole).
- `run:` steps with `shell: bash` run as `bash --noprofile --norc -eo pipefail {script}`, in
  `working-directory` (default GITHUB_WORKSPACE), with GITHUB_* / RUNNER_* of the event and the
  step's `env:`; GITHUB_OUTPUT becomes `steps.<id>.outputs`, GITHUB_PATH lines are put in front
  of PATH for the later steps, GITHUB_ENV lines are added to their environment, and what a step
  writes to its GITHUB_STEP_SUMMARY file is the job summary (the steps' in order).

`uses:` steps are replaced by what they do here (nothing else can be run without GitHub):
- actions/checkout: `git clone` of the event's branch from the test's origin into
  GITHUB_WORKSPACE, then `git submodule update --init [--recursive]` as its `submodules:` says;
  `lfs: true` would also `git lfs pull` (no LFS object in the test repository, so only recorded).
  As its default `persist-credentials: true` does, the token stays in the checkout's
  `.git/config` (`http.https://github.com/.extraheader`, `AUTHORIZATION: basic <base64>`).
- docker/setup-qemu-action: nothing (binfmt handlers come from scripts/setup.sh); recorded.
- docker/setup-docker-action: its `daemon-config` must turn on the containerd image store and
  `set-host` must be true; the engine it hands the later steps (DOCKER_HOST) is this machine's
  engine on that store, which the test names (run_action's containerd_engine).
- gacts/github-slug: its output `slug` made as its v1 (v1.3.5) makes it, by npm's slugify 1.6.8
  (the version its lock file bundles; scripts/setup.sh installs it) run by node.
Any other `uses:` or an expression outside the small grammar below makes the harness fail
rather than guess. Grammar: `path`, `'literal'`, `a == b`, `a != b`, `a || b || ...` (the
first operand that is not empty; paths like `inputs.enable-checkout`,
`github.event.repository.default_branch`).
"""

from __future__ import annotations

import base64
import functools
import json
import os
import re
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional

import yaml

EXPRESSION = re.compile(r"\$\{\{\s*(.*?)\s*\}\}")
COMPARISON = re.compile(r"^(.+?)\s*(==|!=)\s*(.+)$")


class HarnessError(Exception):
    """action.yml uses something the harness does not reproduce."""


@dataclass
class Event:
    """A push of `branch` (or `tag`) of `origin` in `repository` (owner/name)."""

    origin: Path
    repository: str
    ref_name: str
    ref_type: str = "branch"
    default_branch: str = "main"
    actor: str = "octocat"
    token: str = "ghs_harnessTokenNeverLogged0123456789"


@dataclass
class Run:
    returncode: int
    log: str
    outputs: Dict[str, Dict[str, str]]
    skipped: List[str] = field(default_factory=list)
    replaced: List[Dict[str, Any]] = field(default_factory=list)
    summary: str = ""  # the job summary (markdown)


def value(expression: str, contexts: Mapping[str, Any]) -> Any:
    """One operand: a quoted literal or a dotted context path (missing -> '')."""
    expression = expression.strip()
    if expression.startswith("'") and expression.endswith("'"):
        return expression[1:-1].replace("''", "'")
    if not re.fullmatch(r"[A-Za-z_][\w-]*(\.[\w-]+)*", expression):
        raise HarnessError(f"expression not reproduced by the harness: {expression!r}")
    current: Any = contexts
    for part in expression.split("."):
        current = current.get(part, "") if isinstance(current, Mapping) else ""
    return current


def evaluate(expression: str, contexts: Mapping[str, Any]) -> Any:
    if "&&" in expression or "(" in expression:
        raise HarnessError(f"expression not reproduced by the harness: {expression!r}")
    if "||" in expression:
        operands = [evaluate(part, contexts) for part in expression.split("||")]
        return next((result for result in operands if result not in ("", False)), operands[-1])
    match = COMPARISON.match(expression)
    if match:
        left, op, right = match.groups()
        # GitHub compares strings case-insensitively.
        equal = str(value(left, contexts)).lower() == str(value(right, contexts)).lower()
        return equal if op == "==" else not equal
    return value(expression, contexts)


def substitute(text: str, contexts: Mapping[str, Any]) -> str:
    return EXPRESSION.sub(lambda m: as_string(evaluate(m.group(1), contexts)), text)


def as_string(result: Any) -> str:
    if isinstance(result, bool):
        return "true" if result else "false"
    return "" if result is None else str(result)


def condition(text: Optional[str], contexts: Mapping[str, Any]) -> bool:
    if text is None:
        return True
    inner = EXPRESSION.fullmatch(text.strip())
    result = evaluate(inner.group(1) if inner else text, contexts)
    return bool(result) and result != "false"


def read_pairs(path: Path) -> Dict[str, str]:
    """GITHUB_OUTPUT / GITHUB_ENV: `key=value` lines and `key<<EOF` blocks."""
    pairs: Dict[str, str] = {}
    lines = path.read_text().splitlines() if path.exists() else []
    index = 0
    while index < len(lines):
        line = lines[index]
        if "<<" in line and ("=" not in line or line.index("<<") < line.index("=")):
            key, marker = line.split("<<", 1)
            end = lines.index(marker, index + 1)
            pairs[key] = "\n".join(lines[index + 1:end])
            index = end + 1
            continue
        if "=" in line:
            key, text = line.split("=", 1)
            pairs[key] = text
        index += 1
    return pairs


def run_action(action_dir: Path, inputs: Mapping[str, str], event: Event, work: Path,
               base_env: Mapping[str, str], containerd_engine: str = "") -> Run:
    """Run action.yml of action_dir with `with:` inputs for event; work holds the workspace.
    containerd_engine: the address of an engine on the containerd image store, what
    docker/setup-docker-action sets up."""
    action = yaml.safe_load((action_dir / "action.yml").read_text())
    if action["runs"]["using"] != "composite":
        raise HarnessError("only composite actions are reproduced")
    workspace, temp = work / "workspace", work / "runner-temp"
    workspace.mkdir(parents=True)
    temp.mkdir()
    event_file = work / "event.json"
    ref = f"refs/{'tags' if event.ref_type == 'tag' else 'heads'}/{event.ref_name}"
    payload = {"ref": ref, "repository": {"default_branch": event.default_branch,
                                          "full_name": event.repository}}
    event_file.write_text(json.dumps(payload))
    github = {
        "workspace": str(workspace), "repository": event.repository, "actor": event.actor,
        "token": event.token, "ref": ref, "ref_name": event.ref_name, "ref_type": event.ref_type,
        "event_name": "push", "event": payload, "action_path": str(action_dir),
        "server_url": "https://github.com",
    }
    contexts: Dict[str, Any] = {"github": github, "runner": {"temp": str(temp)}, "steps": {},
                                "env": {}}
    given = dict(inputs)
    resolved = {}
    for name, spec in (action.get("inputs") or {}).items():
        raw = given.pop(name, None)
        resolved[name] = raw if raw is not None else substitute(str(spec.get("default", "")),
                                                                contexts)
    if given:
        raise HarnessError(f"unknown inputs: {sorted(given)}")
    contexts["inputs"] = resolved
    env = dict(base_env)
    env.update({
        "CI": "true", "GITHUB_ACTIONS": "true", "GITHUB_WORKSPACE": str(workspace),
        "GITHUB_REPOSITORY": event.repository, "GITHUB_REF": ref,
        "GITHUB_REF_NAME": event.ref_name, "GITHUB_REF_TYPE": event.ref_type,
        "GITHUB_EVENT_NAME": "push", "GITHUB_EVENT_PATH": str(event_file),
        "GITHUB_ACTOR": event.actor, "GITHUB_ACTION_PATH": str(action_dir),
        "GITHUB_SERVER_URL": "https://github.com", "RUNNER_TEMP": str(temp),
        "RUNNER_OS": "Linux",
    })
    env.update({f"INPUT_{name.upper()}": text for name, text in resolved.items()})
    run = Run(returncode=0, log="", outputs={})
    for index, step in enumerate(action["runs"]["steps"]):
        name = step.get("name", f"step {index}")
        if not condition(step.get("if"), contexts):
            run.skipped.append(name)
            continue
        if "uses" in step:
            with_ = {k: substitute(as_string(v), contexts)
                     for k, v in (step.get("with") or {}).items()}
            run.replaced.append({"uses": step["uses"], "with": with_})
            result = replaced_step(step["uses"], with_, event, workspace, containerd_engine)
            env.update(result.env)
        else:
            result = run_step(step, contexts, env, workspace, work / f"step{index}")
        if step.get("id"):
            contexts["steps"][step["id"]] = {"outputs": result.outputs}
            run.outputs[step["id"]] = result.outputs
        run.log += f"##[step] {name}\n{result.log}"
        run.summary += result.summary
        if result.returncode != 0:
            run.returncode = result.returncode
            return run
    return run


@dataclass
class StepResult:
    returncode: int
    log: str
    outputs: Dict[str, str] = field(default_factory=dict)
    summary: str = ""
    env: Dict[str, str] = field(default_factory=dict)  # (what the action exports to the job)


def run_step(step: Mapping[str, Any], contexts: Dict[str, Any], env: Dict[str, str],
             workspace: Path, files: Path) -> StepResult:
    if step.get("shell") != "bash":
        raise HarnessError(f"step {step.get('name')!r}: only `shell: bash` is reproduced")
    files.mkdir()
    script = files / "script.sh"
    script.write_text(step["run"])
    output, path_file, env_file = files / "output", files / "path", files / "env"
    summary = files / "summary"
    step_env = dict(env)
    step_env.update({k: substitute(str(v), contexts) for k, v in (step.get("env") or {}).items()})
    step_env.update({"GITHUB_OUTPUT": str(output), "GITHUB_PATH": str(path_file),
                     "GITHUB_ENV": str(env_file), "GITHUB_STEP_SUMMARY": str(summary)})
    cwd = substitute(str(step.get("working-directory", "")), contexts) or str(workspace)
    proc = subprocess.run(["bash", "--noprofile", "--norc", "-eo", "pipefail", str(script)],
                          cwd=cwd, env=step_env, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, timeout=3600)
    if path_file.exists():
        for line in reversed(path_file.read_text().splitlines()):
            env["PATH"] = f"{line}{os.pathsep}{env.get('PATH', '')}"
    env.update(read_pairs(env_file))
    return StepResult(proc.returncode, proc.stdout, read_pairs(output),
                      summary.read_text() if summary.exists() else "")


# gacts/github-slug's src/formatters.js (v1.3.5)
GACTS_SLUG = ("const slugify = require('slugify');"
              "const text = require('fs').readFileSync(0, 'utf8');"
              "process.stdout.write(slugify(text.replace(/[._/()#+]/g, '-'),"
              " {replacement: '-', lower: true, strict: true}));")


@functools.lru_cache(maxsize=None)
def npm_modules() -> str:
    """The folder of npm's global packages (where scripts/setup.sh installs slugify)."""
    return subprocess.run(["npm", "root", "-g"], capture_output=True, text=True,
                          check=True).stdout.strip()


def github_slug_action(text: str) -> str:
    """What gacts/github-slug@v1 outputs as `slug` for `to-slug: text`."""
    return subprocess.run(["node", "-e", GACTS_SLUG], input=text, capture_output=True,
                          text=True, check=True,
                          env={**os.environ, "NODE_PATH": npm_modules()}).stdout


def replaced_step(uses: str, with_: Mapping[str, str], event: Event, workspace: Path,
                  containerd_engine: str = "") -> StepResult:
    action = uses.split("@", 1)[0]
    if action == "actions/checkout":
        argv = ["git", "clone", "-q", "--branch", event.ref_name, str(event.origin),
                str(workspace)]
        log = subprocess.run(argv, capture_output=True, text=True, check=True).stderr
        basic = base64.b64encode(f"x-access-token:{event.token}".encode()).decode()
        subprocess.run(["git", "config", "--local", "http.https://github.com/.extraheader",
                        f"AUTHORIZATION: basic {basic}"], cwd=workspace, check=True)
        submodules = with_.get("submodules", "false")
        if submodules in ("true", "recursive"):
            sub = ["git", "submodule", "update", "--init"]
            sub += ["--recursive"] if submodules == "recursive" else []
            log += subprocess.run(sub, cwd=workspace, capture_output=True, text=True,
                                  check=True).stderr
        return StepResult(0, log)
    if action == "docker/setup-qemu-action":
        return StepResult(0, "(binfmt handlers of this machine)\n")
    if action == "docker/setup-docker-action":
        features = json.loads(with_.get("daemon-config") or "{}").get("features", {})
        if features.get("containerd-snapshotter") is not True or with_.get("set-host") != "true":
            raise HarnessError(f"{uses} with {dict(with_)}: not an engine on the containerd "
                               "image store that the later steps reach (set-host)")
        if not containerd_engine:
            raise HarnessError(f"{uses}: the test named no engine on the containerd image store")
        return StepResult(0, f"(this machine's engine at {containerd_engine})\n",
                          {"sock": containerd_engine}, env={"DOCKER_HOST": containerd_engine})
    if action == "gacts/github-slug":  # no `slug` output for an empty `to-slug` (trimmed)
        text = with_.get("to-slug", "").strip()
        slug = github_slug_action(text) if text else ""
        return StepResult(0, f"slug: {slug}\n", {"slug": slug} if text else {})
    raise HarnessError(f"`uses: {uses}` is not reproduced by the harness")
