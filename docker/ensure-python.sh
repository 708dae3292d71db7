#!/bin/sh
# The step modules need python3; some base images (e.g. plain ubuntu) have none.
set -e
if ! command -v python3 >/dev/null 2>&1; then
    echo "docker-ros prepare: installing python3 (not in the base image)"
    apt-get update
    apt-get install -y --no-install-recommends python3
fi
