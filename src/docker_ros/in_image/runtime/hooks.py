"""User hook scripts (the scripts and custom steps): collect copies them into the state
directory, apply runs them from there, so the image's install stage needs no sources."""

import logging
import os
import shutil
from pathlib import Path
from typing import Any, Dict, List

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.apt import apt_env, apt_get, apt_lists_present
from docker_ros.in_image.runtime.files import find_special_files, remove_tree
from docker_ros.in_image.runtime.process import hook_context, is_root, run, run_script
from docker_ros.in_image.runtime.workspace import StepError, Workspace, dry, phases, step_log

LOG = logging.getLogger(__name__)


def hook_name(index: int, source: Path) -> str:
    """`NN-<name>`: run order in the name, stable for identical inputs."""
    return f"{index:02d}-{source.name}"


def plan_hooks(ws: Workspace, step: str, sources: List[Path]) -> Dict[str, Any]:
    """The `<step>.json` content: hook copies (relative to the state dir) and their origins."""
    return {
        "hooks": [
            {"file": f"hooks/{step}/{hook_name(i, src)}", "source": ws.relative(src)}
            for i, src in enumerate(sources, start=1)
        ]
    }


def collect(ws: Workspace, step: str, settings: Settings, name: str, *, dry_run: bool
            ) -> Dict[str, Any]:
    sources = find_special_files(ws, settings, name, step=step)
    if not sources:
        LOG.info("%s: no %s found, nothing to run", step, getattr(settings, name))
    plan = plan_hooks(ws, step, sources)
    hook_dir = ws.state / "hooks" / step
    remove_tree(hook_dir, step=step, dry_run=dry_run)
    for source, hook in zip(sources, plan["hooks"]):
        dest = ws.state / hook["file"]
        if dry_run:
            dry(step, f"copy {source} -> {dest}")
            continue
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(str(source), str(dest))
        os.chmod(str(dest), 0o755)
    ws.save_plan(step, step + ".json", plan, dry_run=dry_run)
    return plan


def apply(ws: Workspace, step: str, plan: Dict[str, Any], *, dry_run: bool) -> None:
    """Run each hook with `bash -e` (docker-ros ran them under `set -e`) in the workspace root,
    docker-ros's WORKDIR, on the host as in images: what a hook writes relative to it stays
    out of the repository (and in the image; the state directory is not part of the run
    image)."""
    hooks = plan.get("hooks") or []
    if not hooks:
        LOG.info("%s: no scripts to run", step)
        return
    # docker-ros ran the hooks right after `apt-get update`; scripts rely on it. In an image
    # build always: its lists are in an apt cache mount, maybe weeks old (a hook's apt-get
    # install would miss a replaced version); on the host when it has none.
    if is_root() and shutil.which("apt-get") and (
            hook_context() == "image" or not apt_lists_present()):
        # (-qq: errors only; its download rates would make two logs of one hook differ)
        run(apt_get(["-qq", "update"]), step=step, dry_run=dry_run, env=apt_env())
    for hook in hooks:
        script = ws.state / hook["file"]
        source = ws.root / hook["source"]
        cwd = ws.root
        if not dry_run and not script.is_file():
            raise StepError(step, f"{script} missing: run `{step}` with phase collect first")
        run_script(["bash", "-e", str(script)], script, step=step, dry_run=dry_run, cwd=cwd,
                   what=str(source))


def main(
    ws: Workspace,
    step: str,
    settings: Settings,
    name: str,
    *,
    phase: str,
    dry_run: bool,
) -> None:
    do_collect, do_apply = phases(step, phase)
    with step_log(step):
        plan: Dict[str, Any] = {}
        if do_collect:
            plan = collect(ws, step, settings, name, dry_run=dry_run)
        if do_apply:
            if not do_collect:
                plan = ws.load_plan(step, step + ".json")
            apply(ws, step, plan, dry_run=dry_run)
