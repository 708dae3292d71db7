# A ROS base image made from a Debian or Ubuntu mirror, for machines that reach no container
# registry. ROOTFS_IMAGE is a debootstrap'ed minbase rootfs imported by docker_ros.baseimage; DEBS
# are the ROS tools the distribution packages (ROS 1 in bookworm and Ubuntu's jammy, ROS 2 build
# tooling in trixie), all in /usr.
ARG ROOTFS_IMAGE
FROM ${ROOTFS_IMAGE} AS debs
ARG DEBS
# EXTRA_CA_CERTS (a BuildKit secret, never in a layer) lets apt use an https mirror behind a
# TLS-intercepting proxy.
RUN --mount=type=secret,id=EXTRA_CA_CERTS \
    set -eu; \
    ca=/run/secrets/EXTRA_CA_CERTS; \
    if [ -s "$ca" ]; then set -- -o "Acquire::https::CaInfo=$ca"; fi; \
    apt-get "$@" update; \
    DEBIAN_FRONTEND=noninteractive apt-get "$@" install -y --no-install-recommends $DEBS; \
    apt-get clean; \
    rm -rf /var/lib/apt/lists/*
ENV LANG=C.UTF-8
CMD ["bash"]

# rosdep works offline: Debian's python3-rosdep2 ships its own rules (10-debian.list, for
# Debian's ROS packages and system libraries); a local, empty rosdistro index spares
# `rosdep update` the trip to GitHub; GitHub's rule files (20-default.list) are dropped. Where
# GitHub is reachable, `rosdep init` adds them back.
RUN rm -f /etc/ros/rosdep/sources.list.d/20-default.list && \
    mkdir -p /etc/ros/rosdistro && \
    printf 'type: index\nversion: 4\ndistributions: {}\n' > /etc/ros/rosdistro/index-v4.yaml
ENV ROSDISTRO_INDEX_URL=file:///etc/ros/rosdistro/index-v4.yaml

# Debian's ROS 1 needs no environment: no /opt/ros, no setup.bash, no ROS_DISTRO.
FROM debs AS ros1

FROM debs AS ros2
ENV ROS_VERSION=2

# ROS 1 on Ubuntu 22.04 (universe has Debian's ROS 1). PIP_PACKAGES: colcon and vcstool, which
# Ubuntu does not package, from PyPI. The rules of python3-rosdep2 are listed for Debian only
# (the list's tag `debian`); untagged they apply on Ubuntu too (they have its names).
FROM debs AS ros1-ubuntu
ARG PIP_PACKAGES
RUN --mount=type=secret,id=EXTRA_CA_CERTS \
    set -eu; \
    ca=/run/secrets/EXTRA_CA_CERTS; \
    if [ -s "$ca" ]; then set -- --cert "$ca"; fi; \
    pip3 install "$@" --no-cache-dir $PIP_PACKAGES; \
    sed -i 's/ debian$//' /etc/ros/rosdep/sources.list.d/10-debian.list
