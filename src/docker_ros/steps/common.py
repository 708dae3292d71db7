"""Shared plumbing of the ten steps. Standard library only, Python 3.8+ (runs inside images)."""

import contextlib
import fnmatch
import glob
import hashlib
import json
import logging
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple

LOG = logging.getLogger("docker_ros")

STATE_DIR_NAME = ".docker-ros"
# Directories never searched for packages or special files.
SKIP_DIRS = {".git", ".hg", ".svn", "build", "install", "log", STATE_DIR_NAME, "__pycache__"}
IGNORE_MARKERS = ("COLCON_IGNORE", "CATKIN_IGNORE", "AMENT_IGNORE")
PHASES = ("collect", "apply", "all")
SECRETS_DIR = Path("/run/secrets")
BASE_IMAGE_WS = Path("/opt/ws_base_image")
ROS1_DISTROS = (
    "boxturtle", "cturtle", "diamondback", "electric", "fuerte", "groovy", "hydro", "indigo",
    "jade", "kinetic", "lunar", "melodic", "noetic",
)  # fmt: skip
# Variables that bash sets for itself and that must not leak into the commands we start.
BASH_OWN_VARS = ("_", "SHLVL", "PWD", "OLDPWD")


class StepError(Exception):
    """An expected failure of a step: printed as one line, exit code 1 (or the command's)."""

    def __init__(self, step: str, message: str, returncode: int = 1) -> None:
        super().__init__(f"{step}: {message}")
        self.step = step
        self.message = message
        self.returncode = returncode


class Workspace:
    """A colcon workspace: <root>/src/target is the repository, <root>/src/upstream the imports."""

    def __init__(self, root: "os.PathLike[str] | str") -> None:
        self.root = Path(root)

    @property
    def src(self) -> Path:
        return self.root / "src"

    @property
    def target(self) -> Path:
        return self.src / "target"

    @property
    def upstream(self) -> Path:
        return self.src / "upstream"

    @property
    def install(self) -> Path:
        return self.root / "install"

    @property
    def state(self) -> Path:
        """Data handed from one step to the next (resolved dependencies, blacklist, hooks)."""
        return self.root / STATE_DIR_NAME

    def relative(self, path: Path) -> str:
        """`path` relative to the workspace root (same text on the host and in the image)."""
        try:
            return Path(path).relative_to(self.root).as_posix()
        except ValueError:
            return str(path)

    def read_state(self, name: str, default: object = None) -> object:
        path = self.state / name
        if not path.exists():
            return default
        return json.loads(path.read_text())

    def require_sources(self, step: str) -> None:
        """Collect phases read the repository: a missing src/target is a setup error."""
        if not self.target.is_dir():
            raise StepError(
                step,
                f"{self.target} does not exist: the repository must be src/target of the "
                f"workspace {self.root}",
            )

    def require_state(self, step: str, name: str) -> object:
        """State a previous collect phase wrote; a clear error when it is missing."""
        path = self.state / name
        if not path.exists():
            raise StepError(
                step, f"{path} not found: run `{step}` with phase collect (or all) first"
            )
        try:
            return json.loads(path.read_text())
        except ValueError as exc:
            raise StepError(
                step, f"{path} is not valid JSON ({exc}): re-run its collect phase"
            ) from None

    def load_plan(self, step: str, name: str) -> Dict[str, Any]:
        """The JSON object a previous collect phase wrote (see require_state)."""
        data = self.require_state(step, name)
        return data if isinstance(data, dict) else {}

    def save_plan(self, step: str, name: str, plan: object, *, dry_run: bool) -> None:
        """Write a collect phase's result (a dry run only says so)."""
        if dry_run:
            dry(step, f"write {self.state / name}")
        else:
            self.write_state(name, plan)

    def write_state(self, name: str, data: object) -> Path:
        """Deterministic JSON (sorted keys) so identical inputs give byte-identical files."""
        self.state.mkdir(parents=True, exist_ok=True)
        path = self.state / name
        path.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
        return path


def phases(step: str, phase: str) -> Tuple[bool, bool]:
    """(collect?, apply?) for a phase name."""
    if phase not in PHASES:
        raise StepError(step, f"unknown phase {phase!r}; use one of {', '.join(PHASES)}")
    return phase in ("collect", "all"), phase in ("apply", "all")


@contextlib.contextmanager
def step_log(step: str) -> Iterator[None]:
    """colcon-style `Starting >>> step` / `Finished <<< step [1.2s]` lines."""
    LOG.info("Starting >>> %s", step)
    start = time.monotonic()
    try:
        yield
    except StepError:
        LOG.error("Failed   <<< %s [%.1fs]", step, time.monotonic() - start)
        raise
    LOG.info("Finished <<< %s [%.1fs]", step, time.monotonic() - start)


def format_argv(argv: Sequence[str]) -> str:
    return " ".join(shlex.quote(a) for a in argv)


def dry(step: str, text: str) -> None:
    """What a dry run would do, on stdout (the same prefix as dry-run commands)."""
    print(f"[dry-run] {step}: {text}", flush=True)


def run(
    argv: Sequence[str],
    *,
    step: str,
    dry_run: bool = False,
    cwd: Optional[Path] = None,
    env: Optional[Mapping[str, str]] = None,
    capture: bool = False,
    what: str = "",
) -> str:
    """Run one argv (never a shell string). Raises StepError naming the command and exit code.

    `what` names the file or item at fault in the error (e.g. a script path).
    Returns captured stdout when capture=True.
    """
    shown = format_argv(argv)
    if dry_run:
        dry(step, shown + (f"  (in {cwd})" if cwd else ""))
        return ""
    LOG.info("%s: %s", step, shown)
    full_env = None if env is None else dict(env)
    sys.stdout.flush()
    try:
        proc = subprocess.run(
            list(argv),
            cwd=str(cwd) if cwd else None,
            env=full_env,
            stdout=subprocess.PIPE if capture else None,
            stderr=subprocess.PIPE if capture else None,
            text=True,
        )
    except FileNotFoundError:
        raise StepError(step, f"command not found: {argv[0]} (needed for: {shown})", 127) from None
    if proc.returncode != 0:
        detail = ""
        if capture and proc.stderr and proc.stderr.strip():
            detail = ": " + proc.stderr.strip().splitlines()[-1]
        subject = f"{what} " if what else ""
        raise StepError(
            step,
            f"{subject}failed with exit code {proc.returncode}: {shown}{detail}",
            proc.returncode,
        )
    return proc.stdout if capture else ""


def hook_context(environ: Optional[Mapping[str, str]] = None) -> str:
    """Where hooks run: `image` (an image build, whose images set DOCKER_ROS=1) or `host`."""
    env = os.environ if environ is None else environ
    return "image" if env.get("DOCKER_ROS") == "1" else "host"


def script_hint(content: bytes) -> str:
    """What to do about a failed hook script whose content we recognise as the cause."""
    if b"\r\n" in content:
        return ("; the script has Windows (CRLF) line endings, which bash cannot run: convert it"
                " (`dos2unix FILE`, or `git config core.autocrlf input` and check it out again)")
    return ""


def run_script(
    argv: Sequence[str], script: Path, *, step: str, dry_run: bool, cwd: Path, what: str
) -> None:
    """Run a user hook (argv ends with the script) with DOCKER_ROS_CONTEXT=image|host set;
    a failure we recognise says what to do."""
    env = {**os.environ, "DOCKER_ROS_CONTEXT": hook_context()}
    try:
        run(argv, step=step, dry_run=dry_run, cwd=cwd, what=what, env=env)
    except StepError as exc:
        hint = script_hint(script.read_bytes()) if script.is_file() else ""
        if not hint:
            raise
        raise StepError(step, exc.message + hint, exc.returncode) from None


def run_tee(
    argv: Sequence[str],
    *,
    step: str,
    cwd: Optional[Path] = None,
    env: Optional[Mapping[str, str]] = None,
    on_line: Optional[Callable[[str], bool]] = None,
) -> Tuple[int, List[str]]:
    """Run argv with stdout+stderr streamed line by line to our stdout (the user sees the tool's
    output as it comes) and also returned, for parsing. Returns (exit code, lines).
    `on_line` returning True stops the command (a failure already known, no use waiting)."""
    LOG.info("%s: %s", step, format_argv(argv))
    sys.stdout.flush()
    lines: List[str] = []
    try:
        proc = subprocess.Popen(
            list(argv),
            cwd=str(cwd) if cwd else None,
            env=None if env is None else dict(env),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            universal_newlines=True,
            errors="replace",
        )
    except FileNotFoundError:
        raise StepError(
            step, f"command not found: {argv[0]} (needed for: {format_argv(argv)})", 127
        ) from None
    assert proc.stdout is not None
    with proc.stdout:
        for line in proc.stdout:
            sys.stdout.write(line)
            sys.stdout.flush()
            line = line.rstrip("\n")
            lines.append(line)
            if on_line and on_line(line):
                proc.terminate()
                break
    return proc.wait(), lines


def walk(
    root: Path, *, prune: Optional[Callable[[Path, List[str]], bool]] = None
) -> Iterator[Path]:
    """Every directory below root (root first), skipping VCS/build dirs; follows symlinks once.

    `prune(directory, entries)` returning True stops the descent below that directory
    (the directory itself is still yielded)."""
    seen = set()
    for dirpath, dirnames, filenames in os.walk(str(root), followlinks=True):
        real = os.path.realpath(dirpath)
        if real in seen:
            dirnames[:] = []
            continue
        seen.add(real)
        dirnames[:] = sorted(d for d in dirnames if d not in SKIP_DIRS)
        if prune is not None and prune(Path(dirpath), dirnames + filenames):
            dirnames[:] = []
        yield Path(dirpath)


def path_problem(repository: Path, relative: str) -> Optional[str]:
    """Why `relative` does not name a place inside the repository (absolute, `..` out of it,
    or through a symlink leading out of it), or None when it does."""
    if Path(relative).is_absolute():
        return "is an absolute path"
    if os.path.normpath(relative).split(os.sep)[0] == "..":
        return "leaves the repository through '..'"
    root = os.path.realpath(str(repository))
    real = os.path.realpath(os.path.join(root, relative))
    if real != root and not real.startswith(root + os.sep):
        return f"leads to {real} through a symlink"
    return None


def repository_path(ws: Workspace, settings: object, name: str, *, step: str) -> Path:
    """The repository's file or folder that path setting `name` names; a StepError when the
    setting points outside the repository (the image would get the build machine's files)."""
    relative = str(getattr(settings, name))
    problem = path_problem(ws.target, relative)
    if problem:
        raise StepError(step, f"{name.upper()}={relative!r} {problem}: give a path inside the "
                        "repository")
    return ws.target / relative


def find_special_files(
    ws: Workspace,
    settings: object,
    name: str,
    *,
    pattern: Optional[str] = None,
    step: str = "docker-ros",
    required: bool = True,
) -> List[Path]:
    """docker-ros's file discovery for path setting `name`: the configured file in the
    repository, and when its recursive setting is on, every file of the same name (or matching
    `pattern`) anywhere in the workspace. A file the user set explicitly must exist."""
    from docker_ros.settings import FIELDS, explicitly_set

    ws.require_sources(step)
    relative_path = str(getattr(settings, name))
    switch = FIELDS[name].metadata["recursive"]
    recursive = bool(switch and getattr(settings, switch))
    found: List[Path] = []
    top = repository_path(ws, settings, name, step=step)
    if top.is_file():
        found.append(top)
    if recursive:
        file_name = Path(relative_path).name
        for directory in walk(ws.src):
            for entry in sorted(directory.iterdir()):
                matches = (fnmatch.fnmatch(entry.name, pattern) if pattern
                           else entry.name == file_name)
                if matches and entry.is_file() and entry not in found:
                    found.append(entry)
    if not found and required and explicitly_set(settings, name):  # type: ignore[arg-type]
        where = f" (nor any {pattern or file_name!r} in {ws.src})" if recursive else ""
        raise StepError(step, f"{name.upper()} '{relative_path}' not found in the repository"
                        f"{where}, but set explicitly: fix the path or unset it")
    return found


def read_list_file(path: Path) -> List[str]:
    """Lines of a list file without comments (# ...), blank lines and surrounding spaces."""
    items = []
    for line in path.read_text().splitlines():
        # As pip: a comment starts at a '#' at line start or after white space (not in URLs).
        line = re.sub(r"(^|\s)#.*$", "", line).strip()
        if line:
            items.append(line)
    return items


def collect_list_entries(
    ws: Workspace, step: str, settings: object, name: str
) -> Tuple[List[str], List[Path]]:
    """Entries of every list file of path setting `name` (in discovery order), and the files."""
    files = find_special_files(ws, settings, name, step=step)
    if not files:
        LOG.info("%s: no %s found, nothing to do", step, getattr(settings, name))
    entries: List[str] = []
    for path in files:
        items = read_list_file(path)
        LOG.info("%s: %d entries in %s", step, len(items), path)
        entries.extend(items)
    return entries, files


def unique(items: Sequence[str]) -> List[str]:
    """Items without repetitions, first occurrence kept (order matters for pip options)."""
    out: List[str] = []
    seen = set()
    for item in items:
        if item not in seen:
            seen.add(item)
            out.append(item)
    return out


def file_sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def env_flag(environ: Mapping[str, str], name: str, default: bool) -> bool:
    """Strict boolean from an environment variable (true/false/1/0/yes/no, any case)."""
    raw = environ.get(name)
    if raw is None or raw == "":
        return default
    word = raw.strip().lower()
    if word in ("true", "1", "yes"):
        return True
    if word in ("false", "0", "no"):
        return False
    raise StepError("config", f"{name}={raw!r} is not a boolean; use true/false/1/0/yes/no")


def read_secret(settings: object, name: str, secrets_dir: Path = SECRETS_DIR) -> Optional[str]:
    """A secret from the settings, or when unset there, from the BuildKit secret file
    `<secrets_dir>/<ENV_NAME>`. Never log the result."""
    field = name.lower()
    value = getattr(settings, field, None)
    if value:
        return str(value)
    path = Path(secrets_dir) / field.upper()
    try:
        text = path.read_text()
    except OSError:
        return None
    # A secret file written with `echo` ends in a newline that is not part of the secret.
    text = text[:-1] if text.endswith("\n") else text
    return text or None


def ros_distro(settings: object, environ: Optional[Mapping[str, str]] = None) -> Optional[str]:
    """ROS_DISTRO from the settings, else from the environment; None (Debian's ROS 1) if unset."""
    value = getattr(settings, "ros_distro", None)
    if value:
        return str(value)
    env = os.environ if environ is None else environ
    return env.get("ROS_DISTRO") or None


def ros_version(distro: Optional[str], environ: Optional[Mapping[str, str]] = None) -> str:
    """ROS_VERSION for package.xml conditions: the environment's, else from the distro name.
    Without a distro we assume ROS 1 (ROS 2 always sets ROS_DISTRO; Debian's ROS 1 does not)."""
    env = os.environ if environ is None else environ
    if env.get("ROS_VERSION"):
        return env["ROS_VERSION"]
    if not distro or distro in ROS1_DISTROS:
        return "1"
    return "2"


def ros_setup_files(
    settings: object, *, environ: Optional[Mapping[str, str]] = None, root: Path = Path("/")
) -> List[Path]:
    """The ROS setup and the base image's workspace setup, each only when it exists."""
    files: List[Path] = []
    distro = ros_distro(settings, environ)
    if distro:
        candidates = [root / "opt/ros" / distro / "setup.bash"]
    else:
        # ROS_DISTRO unknown: a single ROS in /opt/ros is unambiguous; none is Debian's ROS in /usr.
        candidates = [Path(p) for p in sorted(glob.glob(str(root / "opt/ros/*/setup.bash")))]
        candidates = candidates if len(candidates) == 1 else []
    candidates.append(root / BASE_IMAGE_WS.relative_to("/") / "install/setup.bash")
    for path in candidates:
        if path.is_file():
            files.append(path)
        else:
            LOG.debug("not sourcing %s: does not exist", path)
    return files


def sourced_env(
    files: Sequence[Path], *, step: str, base_env: Optional[Mapping[str, str]] = None
) -> Dict[str, str]:
    """The environment after sourcing the bash setup files in order (no file: base_env)."""
    env = dict(os.environ if base_env is None else base_env)
    if not files:
        return env
    script = 'for f; do source "$f" >/dev/null || { echo "$f" >&2; exit 3; }; done; env -0'
    argv = ["bash", "-c", script, "bash"] + [str(f) for f in files]
    try:
        proc = subprocess.run(argv, env=env, capture_output=True)
    except FileNotFoundError:
        raise StepError(
            step, "command not found: bash (needed to source the ROS setup files)", 127
        ) from None
    if proc.returncode != 0:
        failed = proc.stderr.decode(errors="replace").strip().splitlines()
        culprit = failed[-1] if failed else ", ".join(str(f) for f in files)
        raise StepError(
            step, f"sourcing {culprit} failed with exit code {proc.returncode}", proc.returncode
        )
    return parse_env0(proc.stdout)


def parse_env0(data: bytes) -> Dict[str, str]:
    """Parse `env -0` output, without the variables bash sets for itself."""
    out: Dict[str, str] = {}
    for entry in data.decode(errors="surrogateescape").split("\0"):
        name, sep, value = entry.partition("=")
        if sep and name and name not in BASH_OWN_VARS:
            out[name] = value
    return out


def copy_tree(src: Path, dst: Path, *, step: str, dry_run: bool) -> None:
    """Copy a directory's contents into dst (merging, symlinks kept as symlinks)."""
    if dry_run:
        dry(step, f"copy {src}/ -> {dst}/")
        return
    LOG.info("%s: copy %s/ -> %s/", step, src, dst)
    _copy_into(Path(src), Path(dst))


def _copy_into(src: Path, dst: Path) -> None:
    # shutil.copytree(dirs_exist_ok=True) fails on existing symlinks: re-runs must not.
    dst.mkdir(parents=True, exist_ok=True)
    for entry in sorted(src.iterdir()):
        target = dst / entry.name
        if entry.is_dir() and not entry.is_symlink():
            if target.is_symlink() or (target.exists() and not target.is_dir()):
                target.unlink()
            _copy_into(entry, target)
            continue
        if target.is_symlink() or target.is_file():
            target.unlink()
        elif target.is_dir():
            shutil.rmtree(str(target))
        if entry.is_symlink():
            os.symlink(os.readlink(str(entry)), str(target))
        else:
            shutil.copy2(str(entry), str(target))
    shutil.copystat(str(src), str(dst))


def remove_tree(path: Path, *, step: str, dry_run: bool) -> None:
    if dry_run:
        dry(step, f"remove {path}")
        return
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.exists():
        shutil.rmtree(str(path))


def is_root() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0


def privileged(argv: Sequence[str]) -> List[str]:
    """Prefix with sudo when not root (host mode for a normal user)."""
    return list(argv) if is_root() else ["sudo", *argv]


def setup_logging(verbose: bool = False) -> None:
    logging.basicConfig(
        stream=sys.stderr,
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(message)s",
    )


def apt_env() -> Dict[str, str]:
    env = dict(os.environ)
    env["DEBIAN_FRONTEND"] = "noninteractive"
    return env


def apt_get(args: Sequence[str]) -> List[str]:
    """apt-get argv, non-interactive also through sudo (which resets the environment)."""
    if is_root():
        return ["apt-get", *args]
    return ["sudo", "DEBIAN_FRONTEND=noninteractive", "apt-get", *args]


def apt_lists_present(lists_dir: Path = Path("/var/lib/apt/lists")) -> bool:
    """Whether apt has package lists (images usually delete them: then `apt-get update` first)."""
    return bool(glob.glob(str(lists_dir / "*_Packages*")))


def apt_install(packages: Sequence[str], *, step: str, dry_run: bool, what: str = "") -> None:
    """apt-get install -y --no-install-recommends, updating the lists when absent or stale."""
    if not packages:
        LOG.info("%s: no apt packages to install", step)
        return
    install = apt_get(["install", "-y", "--no-install-recommends", *packages])
    update = apt_get(["update"])
    if dry_run:
        if not apt_lists_present():
            run(update, step=step, dry_run=True)
        run(install, step=step, dry_run=True)
        return
    if not apt_lists_present():
        run(update, step=step, env=apt_env())
    try:
        run(install, step=step, env=apt_env(), what=what)
    except StepError as exc:
        if exc.returncode == 127:
            raise
        # Stale lists (host, or an apt cache mount) make apt miss packages: update once, retry.
        LOG.info("%s: apt-get install failed, updating package lists and retrying", step)
        run(update, step=step, env=apt_env())
        run(install, step=step, env=apt_env(), what=what)
