"""docker-ros.lock in a build: the locked arguments of a step, and the lock stages' own work
(`check` a resolution against the lock, `resolve` an image's entry). The format: lockfile."""

import hashlib
import subprocess
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.entry import entry_parser, image_main
from docker_ros.in_image.runtime.lockapt import (
    apt_closure,
    apt_pins,
    check_available,
    install_python_debs,
    installed_over,
    read_dpkg_status,
)
from docker_ros.in_image.runtime.lockfile import (
    LOCK_FILE,
    LockError,
    active_entry,
    check_inputs,
    dump_lock,
    dump_repos,
    file_digest,
    is_locked,
    lock_file,
    pin_repos,
    stale_inputs,
)
from docker_ros.in_image.runtime.lockpip import check_pip_available, pip_constraints, pip_report
from docker_ros.in_image.runtime.workspace import StepError, Workspace


def locked_arguments(
    ws: Workspace, settings: Settings, *, step: str, kind: str, inputs: Sequence[str],
    key: str = "", dry_run: bool = False,
) -> Optional[List[str]]:
    """After checking `inputs` against the lock's: apt, what a locked step installs instead
    (`name=version` of the whole locked closure); pip, the constraint lines it installs its
    requirements under (pip_constraints). None when not locked: the step is unchanged."""
    entry = active_entry(ws, settings, step)
    if entry is None:
        return None
    key = key or step
    recorded = sorted((entry.get("inputs") or {}).get(key) or [])
    try:
        changes = stale_inputs({key: recorded}, {key: sorted(inputs)}, kinds=(key,))
        if changes:
            raise LockError(
                f"LOCKED: the repository no longer matches docker-ros.lock ({'; '.join(changes)})"
                ": run `inv lock`"
            )
        if kind == "apt":
            pins = apt_pins(inputs, entry.get("apt") or {})
            if not dry_run:  # (a dry run neither updates apt's lists nor asks them)
                check_available(pins, step=step)
            return pins
        constraints = pip_constraints(entry.get("pip") or {})
        if constraints and not dry_run:
            check_pip_available(inputs, constraints, step=step)
        return constraints
    except LockError as exc:
        raise StepError(step, str(exc)) from None


def pinned_repos_file(
    ws: Workspace, step: str, repos_file: Path, repos: Mapping[str, Mapping[str, str]],
    locked: Mapping[str, Mapping[str, str]],
) -> Path:
    """A copy of `repos_file` in the workspace's state folder with every version replaced by its
    locked commit (entries land in src/upstream, recorded as `upstream/<name>`)."""
    try:
        text = dump_repos(pin_repos(repos, locked, "upstream"))
    except LockError as exc:
        raise StepError(step, f"{ws.relative(repos_file)}: {exc}") from None
    pinned = ws.state / f"locked-{hashlib.sha256(str(repos_file).encode()).hexdigest()[:12]}.repos"
    pinned.parent.mkdir(parents=True, exist_ok=True)
    pinned.write_text(text)
    return pinned


def locked_rosdep_plan(
    ws: Workspace, settings: Settings, plan: Mapping[str, Any], dependency_types: str, step: str,
    dry_run: bool = False,
) -> Mapping[str, Any]:
    """rosdep's plan with the chosen set's apt and pip packages replaced by the lock's pins
    (inputs `rosdep_apt_<types>` / `rosdep_pip_<types>`); the plan itself unless LOCKED."""
    chosen = plan.get(dependency_types)
    if not isinstance(chosen, dict):
        return plan
    if not is_locked(settings):
        return plan
    pinned = {
        installer: locked_arguments(ws, settings, step=step, kind=installer,
                                    inputs=list(chosen.get(installer) or []),
                                    key=f"rosdep_{installer}_{dependency_types}",
                                    dry_run=dry_run)
        for installer in ("apt", "pip")
    }
    apt, pip = pinned["apt"], pinned["pip"]
    pinned = {"apt": list(chosen.get("apt") or []) if apt is None else apt,
              "pip": constrained(ws, list(chosen.get("pip") or []), pip, dry_run=dry_run)}
    return {**plan, dependency_types: {**chosen, **pinned}}


def constrained(ws: Workspace, packages: List[str], constraints: Optional[List[str]], *,
                dry_run: bool) -> List[str]:
    """pip argv items: the packages under `-c` of a file of the constraint lines (in the state
    folder); the packages alone without constraints or packages."""
    if not constraints or not packages:
        return packages
    path = ws.state / "locked-pip-constraints.txt"
    if not dry_run:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("\n".join(constraints) + "\n")
    return ["-c", str(path), *packages]


def repository_commits(root: Path) -> Dict[str, Dict[str, str]]:
    """path (relative to `root`'s parent, e.g. `upstream/foo`) -> {url, commit} of every git
    checkout under `root`, nested ones (from nested .repos files) included."""
    commits: Dict[str, Dict[str, str]] = {}
    if not root.is_dir():
        return commits
    for marker in sorted(root.rglob(".git")):
        checkout = marker.parent
        commits[f"{root.name}/{checkout.relative_to(root).as_posix()}"] = {
            "url": _git(checkout, "config", "--get", "remote.origin.url"),
            "commit": _git(checkout, "rev-parse", "HEAD"),
        }
    return commits


def _git(checkout: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(checkout), *args], capture_output=True,
                          text=True).stdout.strip()


def recorded_inputs(ws: Workspace, rules_file: Optional[Path]) -> Dict[str, Any]:
    """The resolution the collect phases wrote (debs.json, pip.json, rosdep.json) and the rules
    file's digest: what a locked build compares with the lock."""
    inputs: Dict[str, Any] = {
        "debs": sorted(_state(ws, "debs.json").get("packages") or []),
        "pip": sorted(_state(ws, "pip.json").get("requirements") or []),
        "pip_constraints": sorted(_state(ws, "pip.json").get("constraints") or []),
        "rosdep_rules": file_digest(rules_file),
    }
    for types, chosen in sorted(_state(ws, "rosdep.json").items()):
        if isinstance(chosen, dict):
            for installer in ("apt", "pip"):
                inputs[f"rosdep_{installer}_{types}"] = sorted(chosen.get(installer) or [])
    return inputs


def _state(ws: Workspace, name: str) -> Dict[str, Any]:
    data = ws.read_state(name)
    return dict(data) if isinstance(data, dict) else {}


def resolved_entry(ws: Workspace, settings: Settings, dependency_types: str, upstream: Path,
                   bare: Path) -> Dict[str, Any]:
    """One image target's lock entry, where its installs run (the resolved-dev or resolved-run
    state, resolution in .docker-ros): the collect phases' inputs, the imported commits (the
    source stage's src/upstream at `upstream`), what prepare installed over the bare base image
    (its root at `bare`), what apt and pip would install now (fresh apt lists). The base
    image's digest is the host's to add."""
    inputs = recorded_inputs(ws, rules_path(ws, settings))
    chosen = _state(ws, "rosdep.json").get(dependency_types) or {}
    apt = sorted({*inputs["debs"], *(chosen.get("apt") or [])})
    pip = [*inputs["pip"], *(chosen.get("pip") or [])]
    constraints = _state(ws, "pip.json").get("constraints") or []
    prepare = installed_over(read_dpkg_status(bare / "var/lib/dpkg/status"), read_dpkg_status())
    closure = apt_closure(apt, update=True)
    if pip:
        install_python_debs(closure)
    return {"inputs": inputs, "repos": repository_commits(upstream), "prepare": prepare,
            "apt": closure, "pip": pip_report(pip, constraints)}


def rules_path(ws: Workspace, settings: Settings) -> Optional[Path]:
    name = getattr(settings, "rosdep_rules_file", None)
    return ws.target / name if name else None


def check_resolution(ws: Workspace, settings: Settings) -> None:
    """In a locked build's resolve stage, after the collect phases: stop when what they
    resolved differs from the lock's inputs (before anything is installed, naming each
    change); then put the lock next to the resolution, where the install stages read it."""
    entry = active_entry(ws, settings, "lock")
    if entry is None:
        return
    try:
        check_inputs(entry, recorded_inputs(ws, rules_path(ws, settings)))
    except LockError as exc:
        raise StepError("lock", str(exc)) from None
    ws.state.mkdir(parents=True, exist_ok=True)
    (ws.state / LOCK_FILE).write_text(lock_file(ws).read_text())


def main(argv: List[str]) -> int:
    """`python3 -m docker_ros.in_image.runtime.lock check` (resolve stage) or `... resolve OUT
    TYPES UPSTREAM BARE` (the lock stages: OUT/<target>.json)."""
    if argv[:1] not in (["check"], ["resolve"]):  # --help, or no command: say which there are
        parser = entry_parser("runtime.lock", "LOCKED builds: check a resolution against "
                              "docker-ros.lock, or write an image's lock entry.")
        parser.add_argument("command", choices=["check", "resolve"],
                            help="check | resolve OUT DEPENDENCY_TYPES UPSTREAM BARE")
        parser.parse_args(argv)
        parser.error("the command comes first: check ... or resolve ...")
    if argv[:1] == ["check"]:
        return image_main(argv[1:], module="runtime.lock check", step="lock",
                          description="LOCKED: stop when the resolution differs from "
                          "docker-ros.lock.", arguments=[],
                          action=lambda ws, settings, _: check_resolution(ws, settings))

    def write(ws: Workspace, settings: Settings, args: List[str]) -> None:
        out, types, upstream, bare = Path(args[0]), args[1], Path(args[2]), Path(args[3])
        entry = resolved_entry(ws, settings, types, upstream, bare)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(dump_lock(entry))

    return image_main(argv[1:], module="runtime.lock resolve", step="lock",
                      description="Write the lock entry of one image (what prepare installed "
                      "over the base image at BARE, apt and pip closure, imported commits) to "
                      "OUT.", arguments=["OUT", "DEPENDENCY_TYPES", "UPSTREAM", "BARE"],
                      action=write)


if __name__ == "__main__":
    import sys

    sys.exit(main(sys.argv[1:]))
