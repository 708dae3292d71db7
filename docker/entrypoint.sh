#!/bin/bash
# docker-ros entrypoint (runs under tini): map the host user, source ROS, exec the command.
#
#   DOCKER_UID / DOCKER_GID / DOCKER_USER  create that user (and group) and run as it

source_if_exists() {
    # shellcheck disable=SC1090
    if [[ -f "$1" ]]; then source "$1"; fi
}

source_ros() {
    if [[ -n "${ROS_DISTRO:-}" ]]; then
        source_if_exists "/opt/ros/${ROS_DISTRO}/setup.bash"
    else
        for setup in /opt/ros/*/setup.bash; do source_if_exists "$setup"; break; done
    fi
    source_if_exists /opt/ws_base_image/install/setup.bash
    source_if_exists "${WORKSPACE:-/docker-ros/ws}/install/setup.bash"
}

map_user() {
    local user="${DOCKER_USER:-dockeruser}" uid="$DOCKER_UID" gid="${DOCKER_GID:-$DOCKER_UID}"
    if ! getent group "$gid" >/dev/null; then
        if getent group "$user" >/dev/null; then
            echo "docker-ros: group '$user' exists with another GID; using GID $gid unnamed" >&2
        else
            groupadd --gid "$gid" "$user" || echo "docker-ros: could not create group $gid" >&2
        fi
    else
        echo "docker-ros: GID $gid exists already ($(getent group "$gid" | cut -d: -f1)); reusing it" >&2
    fi
    if getent passwd "$uid" >/dev/null; then
        user="$(getent passwd "$uid" | cut -d: -f1)"
        echo "docker-ros: UID $uid exists already ($user); running as that user" >&2
    elif getent passwd "$user" >/dev/null; then
        echo "docker-ros: user '$user' exists with another UID; creating '${user}_$uid'" >&2
        user="${user}_$uid"
        useradd --uid "$uid" --gid "$gid" --create-home --shell /bin/bash "$user" >/dev/null 2>&1
    else
        useradd --uid "$uid" --gid "$gid" --create-home --shell /bin/bash "$user" >/dev/null 2>&1 \
            || echo "docker-ros: could not create user $user ($uid:$gid)" >&2
    fi
    echo "$user:$user" | chpasswd 2>/dev/null || true
    if [[ -d /etc/sudoers.d ]]; then
        echo "$user ALL=(ALL) NOPASSWD:ALL" > "/etc/sudoers.d/docker-ros-$uid" 2>/dev/null || true
    fi
    DOCKER_ROS_RUN_AS="$user"
}

source_ros

if [[ $# -eq 0 ]]; then
    set -- bash
fi

if [[ -n "${DOCKER_UID:-}" && "$(id -u)" == "0" ]]; then
    map_user
    home="$(getent passwd "$DOCKER_ROS_RUN_AS" | cut -d: -f6)"
    export HOME="${home:-/tmp}" USER="$DOCKER_ROS_RUN_AS"
    # setpriv ships with util-linux in every Debian/Ubuntu image; no su/sudo/gosu needed.
    exec setpriv --reuid="$DOCKER_UID" --regid="${DOCKER_GID:-$DOCKER_UID}" --init-groups -- "$@"
fi
exec "$@"
