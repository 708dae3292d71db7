"""docker-ros: turn a repository of ROS packages into dev, run and slim container images."""

__version__ = "0.1.0"
