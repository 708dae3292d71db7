"""What a project's one-line tasks.py imports (`from docker_ros.tasks import ns`): the invoke
collection, declared in docker_ros.cli.tasks (and, for `inv`, which reads the project's
invoke.yaml after importing tasks.py, one line instead of a traceback for a file it would fail
on; and the refusal of a secret given as a flag, before invoke parses the command line)."""

import sys
from pathlib import Path

from docker_ros.cli.program import stop_on_config_problems, tasks_folder
from docker_ros.cli.settingstask import refuse_secret_flags
from docker_ros.cli.tasks import ns

stop_on_config_problems(tasks_folder(Path.cwd()), base=False, full_paths=True)
refuse_secret_flags(sys.argv[1:], ns)

__all__ = ["ns"]
