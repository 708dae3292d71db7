#!/bin/sh
# The step modules need python3 >= 3.8; some base images (e.g. plain ubuntu) have none, and an
# old one (Ubuntu 18.04's 3.6) would fail later with a SyntaxError deep in a step. Runs first in
# the base stage, before any Python of ours. BASE_IMAGE comes from the stage's ARG.
set -e
# LOCKED: the tool put the lock's pins for prepare into the build (runtime/prepare.py,
# held_to_lock): python3 too comes at its locked version; prepare compares what it installed,
# from this copy of dpkg's state on, with the lock and removes the pins again.
if [ -s /docker-ros/lock-pins/base.pref ]; then
    cp /var/lib/dpkg/status /run/docker-ros/dpkg-status.before
    mkdir -p /etc/apt/preferences.d
    cp /docker-ros/lock-pins/base.pref /etc/apt/preferences.d/docker-ros-lock
fi
MINIMUM_MAJOR=3
MINIMUM_MINOR=8
if ! command -v python3 >/dev/null 2>&1; then
    echo "docker-ros prepare: installing python3 (not in the base image)"
    apt-get update
    apt-get install -y --no-install-recommends python3
fi
# `--version` works on every python3, however old (python2-era ones print it to stderr).
version="$(python3 --version 2>&1 | sed -n 's/^Python \([0-9][0-9]*\.[0-9][0-9]*[0-9.]*\).*/\1/p')"
major="${version%%.*}"
minor="${version#*.}"
minor="${minor%%.*}"
if [ -z "$version" ] || [ "$major" -lt "$MINIMUM_MAJOR" ] \
    || { [ "$major" -eq "$MINIMUM_MAJOR" ] && [ "$minor" -lt "$MINIMUM_MINOR" ]; }; then
    echo "docker-ros prepare: BASE_IMAGE '${BASE_IMAGE:-?}' has python3 ${version:-of unknown version} ($(command -v python3)); docker-ros needs Python $MINIMUM_MAJOR.$MINIMUM_MINOR or newer in the image: use a newer base image (Ubuntu 20.04+, Debian 11+) or install a newer python3 in it" >&2
    exit 1
fi
