"""Invoke tasks of docker-ros. A ROS repository gets them with this same one line."""

from docker_ros.tasks import ns  # noqa: F401
