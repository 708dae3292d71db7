"""What a project's one-line tasks.py imports (`from docker_ros.tasks import ns`): the invoke
collection, declared in docker_ros.cli.tasks."""

from docker_ros.cli.tasks import ns

__all__ = ["ns"]
