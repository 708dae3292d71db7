"""The command line: the invoke tasks (`tasks`, thin: they hand over to docker_ros.host.pipeline),
the `docker-ros` program over them (`program`) and the configuration reference made from them
(`reference`, rendered by the docs build)."""

from docker_ros.cli.program import main

__all__ = ["main"]
