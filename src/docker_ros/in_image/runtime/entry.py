"""What every in-image entry point (`python3 -m docker_ros.in_image.<module>`) starts with: its
arguments, the settings from the environment, errors as one line. Standard library only,
Python 3.8+ (runs inside images). Apart from workspace.py, which the command line's task
declarations import: these need the settings' loading, which `--help` does not."""

import argparse
import os
import sys
from pathlib import Path
from typing import Any, Callable, List, Sequence

from docker_ros.core.loading import load_settings
from docker_ros.core.settings import SettingsError
from docker_ros.in_image.runtime.workspace import (
    DEFAULT_WORKSPACE,
    StepError,
    Workspace,
    setup_logging,
)


def entry_parser(module: str, description: str) -> argparse.ArgumentParser:
    """The argument parser every in-image entry point (`python3 -m docker_ros.in_image.<module>`)
    starts from: its --workspace (default $WORKSPACE, which the images set, else
    /docker-ros/ws) and -v; the entry point adds its own arguments."""
    parser = argparse.ArgumentParser(prog=f"python3 -m docker_ros.in_image.{module}",
                                     description=description)
    default = os.environ.get("WORKSPACE", DEFAULT_WORKSPACE)
    parser.add_argument("--workspace", default=default,
                        help=f"colcon workspace (repository in src/target; default {default})")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return parser


def image_main(argv: Sequence[str], *, module: str, step: str, description: str,
               arguments: Sequence[str], action: "Callable[[Workspace, Any, List[str]], object]",
               settings: bool = True) -> int:
    """An in-image entry point taking the positional arguments named in arguments: parses
    argv (entry_parser), loads the settings from the environment (unless settings is False:
    action then gets None), runs action(workspace, settings, values); errors as one
    `docker-ros <step>:` line and exit code 1."""
    parser = entry_parser(module, description)
    for name in arguments:
        parser.add_argument(name.lower(), metavar=name)
    args = parser.parse_args(list(argv))
    setup_logging(args.verbose)
    ws = Workspace(args.workspace)
    try:
        loaded = (load_settings(environ=os.environ, project_dir=Path(ws.target))
                  if settings else None)
        action(ws, loaded, [getattr(args, name.lower()) for name in arguments])
    except (StepError, SettingsError, OSError) as exc:
        print(f"docker-ros {step}: {getattr(exc, 'message', exc)}", file=sys.stderr)
        return getattr(exc, "returncode", 1) or 1
    return 0
