"""Reading the configuration sources of a project (the impure edge of settings.load_settings)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Optional

from dotenv import dotenv_values

from docker_ros.ci import github_default_branch
from docker_ros.settings import (
    FIELDS,
    Settings,
    display_value,
    env_name,
    load_settings,
)


def read_settings(
    invoke_config: Optional[Mapping[str, object]],
    flags: Mapping[str, object],
    *,
    project_dir: Optional[Path] = None,
    environ: Optional[Mapping[str, str]] = None,
) -> Settings:
    """Settings of the project in project_dir (default: cwd) from every source."""
    project = project_dir or Path.cwd()
    env_file = project / ".env"
    dotenv = dotenv_values(env_file) if env_file.is_file() else {}
    environ = os.environ if environ is None else environ
    if environ.get("GITHUB_ACTIONS") == "true" and not environ.get("GITHUB_DEFAULT_BRANCH"):
        # GitHub has no variable for it; the event payload names it (CI tag postfix rules).
        environ = {**environ, "GITHUB_DEFAULT_BRANCH": github_default_branch(environ)}
    return load_settings(
        invoke_config=invoke_config,
        dotenv=dotenv,
        environ=environ,
        flags=flags,
        project_dir=project,
    )


def config_table(settings: Settings) -> str:
    """Every setting with its effective value and where it came from; secrets masked."""
    rows = [(env_name(n), display_value(settings, n), settings.source_of(n)) for n in FIELDS]
    width = max(len(r[0]) for r in rows)
    value_width = min(60, max(len(r[1]) for r in rows))
    lines = [f"{'VARIABLE'.ljust(width)}  {'VALUE'.ljust(value_width)}  SOURCE"]
    for name, value, source in rows:
        lines.append(f"{name.ljust(width)}  {value.ljust(value_width)}  {source}")
    return "\n".join(lines)

