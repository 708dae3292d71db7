"""`python3 -m docker_ros.in_image.steps <step> [<step> ...]`: steps as the Dockerfile (and
debugging) runs them; several in one process, one after the other (each Python start costs a
RUN ~70 ms)."""

import argparse
import logging
import os
import sys
from pathlib import Path
from typing import List, Optional

from docker_ros.core.loading import load_settings
from docker_ros.core.settings import SettingsError
from docker_ros.in_image.runtime.entry import entry_parser
from docker_ros.in_image.runtime.workspace import PHASES, StepError, Workspace, setup_logging
from docker_ros.in_image.steps import IMAGE_STEPS, OPTIONS, STEPS, run_step, step_options


def parser() -> argparse.ArgumentParser:
    p = entry_parser("steps", "Run docker-ros pipeline steps, one after the other (the first "
                     "failure stops the rest); settings come from the environment (docker-ros "
                     "variable names).")
    p.add_argument("steps", nargs="+", metavar="step", choices=STEPS + IMAGE_STEPS,
                   help="the step(s) to run: " + ", ".join(STEPS + IMAGE_STEPS))
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
    for option in OPTIONS:
        flag = "--" + option.name.replace("_", "-")
        if option.takes_value:
            p.add_argument(flag, choices=option.choices or None, default=None, help=option.help)
        else:
            p.add_argument(flag, action="store_true", help=option.help)
    return p


def main(argv: Optional[List[str]] = None) -> int:
    args = parser().parse_args(argv)
    setup_logging(args.verbose)
    ws = Workspace(args.workspace)
    given = {o.name: getattr(args, o.name) for o in OPTIONS if getattr(args, o.name)}
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
