"""What a project's one-line tasks.py imports (`from docker_ros.tasks import ns`): the invoke
collection, declared in docker_ros.cli.tasks (and, for `inv`, one line instead of a traceback
for an invoke.yaml that is not YAML)."""

from docker_ros.cli.program import one_line_for_invoke_errors
from docker_ros.cli.tasks import ns

one_line_for_invoke_errors()

__all__ = ["ns"]
