"""`python3 -m docker_ros.steps <step> ...`: one step, as the Dockerfile (and debugging) runs it."""

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


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python3 -m docker_ros.steps",
        description="Run one docker-ros pipeline step; settings come from the environment "
        "(docker-ros variable names).",
    )
    p.add_argument("step", choices=STEPS + IMAGE_STEPS, help="the step to run")
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
    options: Dict[str, str] = {}
    if args.dependency_types:
        options["dependency_types"] = args.dependency_types
    if args.destination:
        options["destination"] = args.destination
    if args.stamp_changed:
        options["stamp_changed"] = "true"
    if args.mark_ignored:
        options["mark_ignored"] = "true"
    if args.imports_only:
        options["imports_only"] = "true"
    try:
        settings = load_settings(environ=os.environ, project_dir=Path(ws.target))
        run_step(args.step, ws, settings, phase=args.phase, dry_run=args.dry_run, **options)
    except StepError as exc:
        print(f"docker-ros {args.step}: {exc.message}", file=sys.stderr)
        return exc.returncode or 1
    except SettingsError as exc:
        print(f"docker-ros {args.step}: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        logging.getLogger("docker_ros").error("interrupted")
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
