"""The ROS environment: distro, setup files, sourced environments, secrets.
Standard library only, Python 3.8+ (runs inside images)."""

import glob
import os
from pathlib import Path
from typing import Dict, List, Mapping, Optional, Sequence

from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.process import probe
from docker_ros.in_image.runtime.workspace import LOG, StepError

SECRETS_DIR = Path("/run/secrets")


BASE_IMAGE_WS = Path("/opt/ws_base_image")


ROS1_DISTROS = (
    "boxturtle", "cturtle", "diamondback", "electric", "fuerte", "groovy", "hydro", "indigo",
    "jade", "kinetic", "lunar", "melodic", "noetic",
)  # fmt: skip


# Variables that bash sets for itself and that must not leak into the commands we start.
BASH_OWN_VARS = ("_", "SHLVL", "PWD", "OLDPWD")


def read_secret(settings: Settings, name: str, secrets_dir: Path = SECRETS_DIR) -> Optional[str]:
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


def ros_distro(settings: Settings, environ: Optional[Mapping[str, str]] = None) -> Optional[str]:
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


def env_paths(env: Mapping[str, str], name: str) -> List[Path]:
    """The folders of a path list variable (ROS_PACKAGE_PATH, AMENT_PREFIX_PATH, ...)."""
    return [Path(p) for p in env.get(name, "").split(os.pathsep) if p]


def ros_setup_files(
    settings: Settings, *, environ: Optional[Mapping[str, str]] = None, root: Path = Path("/")
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


def workspace_setup_files(settings: Settings, install: Path, *, step: str) -> List[Path]:
    """The run-time environment's setup files: ROS, the base image's workspace, then the
    workspace's install space (each only when it exists)."""
    files = ros_setup_files(settings)
    local = install / "setup.bash"
    if local.is_file():
        files.append(local)
    else:
        LOG.info("%s: %s does not exist (workspace not built?), not sourced", step, local)
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
    proc = probe(argv, step=step, env=env, hint="needed to source the ROS setup files",
                 text=False)
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
