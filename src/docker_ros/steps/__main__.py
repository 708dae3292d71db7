"""`python3 -m docker_ros.steps <step> [<step> ...]`: steps as the Dockerfile (and debugging) runs
them; several in one process, one after the other (each Python start costs a RUN ~70 ms)."""

import argparse
import logging
import os
import sys
from pathlib import Path
from typing import Dict, List, Optional

from docker_ros.runtime.workspace import PHASES, StepError, Workspace, setup_logging
from docker_ros.settings import SettingsError, load_settings
from docker_ros.steps import IMAGE_STEPS, STEPS, run_step

DEFAULT_WORKSPACE = "/docker-ros/ws"


# The steps each option is for: with several steps in one call, each gets only its own options,
# as if it ran alone. (--phase, --workspace and --dry-run are every step's.)
STEP_OPTIONS = {
    "dependency_types": ("rosdep", "prepare"),
    "destination": ("files",),
    "stamp_changed": ("colcon",),
    "mark_ignored": ("blacklist",),
    "imports_only": ("clone",),
}


def step_options(step: str, given: Dict[str, str]) -> Dict[str, str]:
    """The given options (name -> value) that are step's."""
    return {name: value for name, value in given.items() if step in STEP_OPTIONS[name]}


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python3 -m docker_ros.steps",
        description="Run docker-ros pipeline steps, one after the other (the first failure "
        "stops the rest); settings come from the environment (docker-ros variable names).",
    )
    p.add_argument("steps", nargs="+", metavar="step", choices=STEPS + IMAGE_STEPS,
                   help="the step(s) to run: " + ", ".join(STEPS + IMAGE_STEPS))
    p.add_argument(
        "--workspace",
        default=DEFAULT_WORKSPACE,
        help=f"colcon workspace (repository in src/target; default {DEFAULT_WORKSPACE})",
    )
    p.add_argument(
        "--phase",
        choices=PHASES,
        default="all",
        help="collect: read sources into the state dir; apply: act on the state only; "
        "all: both (default)",
    )
    p.add_argument(
        "--dry-run", action="store_true", help="print the commands and file changes, change nothing"
    )
    p.add_argument(
        "--dependency-types",
        choices=("all", "exec"),
        default=None,
        help="rosdep apply: all dependencies (dev) or exec only (run)",
    )
    p.add_argument(
        "--destination",
        default=None,
        help="files apply: target folder (default /docker-ros/additional-files)",
    )
    p.add_argument(
        "--stamp-changed",
        action="store_true",
        help="colcon: give sources whose content changed since the last build the current time "
        "(image builds, where build/ is a cache mount and COPY keeps old times)",
    )
    p.add_argument(
        "--mark-ignored",
        action="store_true",
        help="blacklist: put a COLCON_IGNORE file into each blacklisted package (the image's "
        "copy of the sources; never the user's repository)",
    )
    p.add_argument(
        "--imports-only",
        action="store_true",
        help="clone: import the .repos files present, no hook (the image's upstream stage)",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return p


def main(argv: Optional[List[str]] = None) -> int:
    args = parser().parse_args(argv)
    setup_logging(args.verbose)
    ws = Workspace(args.workspace)
    given = {name: value for name, value in (
        ("dependency_types", args.dependency_types), ("destination", args.destination),
        ("stamp_changed", "true" if args.stamp_changed else None),
        ("mark_ignored", "true" if args.mark_ignored else None),
        ("imports_only", "true" if args.imports_only else None),
    ) if value}
    step = args.steps[0]
    try:
        settings = load_settings(environ=os.environ, project_dir=Path(ws.target))
        for step in args.steps:
            run_step(step, ws, settings, phase=args.phase, dry_run=args.dry_run,
                     **step_options(step, given))
    except StepError as exc:
        print(f"docker-ros {step}: {exc.message}", file=sys.stderr)
        return exc.returncode or 1
    except SettingsError as exc:
        print(f"docker-ros {step}: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        logging.getLogger("docker_ros").error("interrupted")
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
