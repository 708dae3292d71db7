"""`python -m docker_ros` = the `docker-ros` console script."""

from docker_ros.cli.program import main

main()
