#!/bin/bash
# docker-ros entrypoint (runs under tini): map the host user, source ROS, exec the command.
#
#   DOCKER_UID / DOCKER_GID / DOCKER_USER  create that user (and group) and run as it

_dros_source() {
    # shellcheck disable=SC1090
    if [[ -f "$1" ]]; then source "$1"; fi
}

_dros_source_ros() {
    if [[ -n "${ROS_DISTRO:-}" ]]; then
        _dros_source "/opt/ros/${ROS_DISTRO}/setup.bash"
    else
        local setup
        for setup in /opt/ros/*/setup.bash; do _dros_source "$setup"; break; done
    fi
    _dros_source /opt/ws_base_image/install/setup.bash
    _dros_source "${WORKSPACE:-/docker-ros/ws}/install/setup.bash"
}

_dros_warn() { echo "docker-ros: $*" >&2; }

# Collisions never stop the container: an existing UID or GID is reused under its own name, a
# name taken with another ID gets an _<id> suffix, and a failed useradd/groupadd only warns.
_dros_map_user() {
    local user="${DOCKER_USER:-dockeruser}" uid="$DOCKER_UID" gid="${DOCKER_GID:-$DOCKER_UID}"
    local group="$user" found
    if found="$(getent group "$gid" | cut -d: -f1)" && [[ -n "$found" ]]; then
        # (silent when it is this mapping's group: a restarted container has it from before)
        if [[ "$found" != "$group" && "$found" != "${group}_$gid" ]]; then
            _dros_warn "GID $gid exists already ($found); reusing it"
        fi
    else
        if getent group "$group" >/dev/null; then
            _dros_warn "group '$group' exists with another GID; creating '${group}_$gid'"
            group="${group}_$gid"
        fi
        groupadd --gid "$gid" "$group" >/dev/null 2>&1 \
            || _dros_warn "could not create group $group ($gid); running with GID $gid unnamed"
    fi
    # docker-ros's groups: sudo, and video for cameras and GPUs (/dev/video*, /dev/dri); and
    # dialout for serial devices (`--device /dev/ttyUSB0` keeps the host's group, dialout)
    local extra=() group_name
    for group_name in sudo video dialout; do
        getent group "$group_name" >/dev/null && extra+=("$group_name")
    done
    local groups=()
    if [[ ${#extra[@]} -gt 0 ]]; then groups=(--groups "$(IFS=,; echo "${extra[*]}")"); fi
    if getent passwd "$uid" >/dev/null; then
        found="$(getent passwd "$uid" | cut -d: -f1)"
        if [[ "$found" != "$user" && "$found" != "${user}_$uid" ]]; then
            _dros_warn "UID $uid exists already ($found); running as that user"
        fi
        user="$found"
        if [[ ${#extra[@]} -gt 0 ]]; then
            usermod --append "${groups[@]}" "$user" >/dev/null 2>&1 \
                || _dros_warn "could not add $user to the groups ${extra[*]}"
        fi
    else
        if getent passwd "$user" >/dev/null; then
            _dros_warn "user '$user' exists with another UID; creating '${user}_$uid'"
            user="${user}_$uid"
        fi
        local primary=(--gid "$gid")
        getent group "$gid" >/dev/null || primary=(--no-user-group)
        useradd --uid "$uid" "${primary[@]}" "${groups[@]}" --create-home --shell /bin/bash \
            "$user" >/dev/null 2>&1 \
            || _dros_warn "could not create user $user ($uid:$gid); running unnamed"
        # docker-ros's new user got root's ~/.bashrc: what a hook added there (aliases,
        # exports, `source` lines) reaches the mapped user's interactive shells too
        local home
        home="$(getent passwd "$uid" | cut -d: -f6)"
        # a home docker made for a mount below it (`-v ~/.ssh:/home/me/.ssh`) is root's, and
        # useradd leaves an existing one as it is: the new user's, as useradd would have made it
        if [[ -n "$home" && -d "$home" && "$(stat -c %u "$home")" == 0 && "$uid" != 0 ]]; then
            chown "$uid:$gid" "$home" 2>/dev/null || true
        fi
        if [[ -f /root/.bashrc && -n "$home" && -d "$home" ]]; then
            cp /root/.bashrc "$home/.bashrc" 2>/dev/null \
                && chown "$uid:$gid" "$home/.bashrc" 2>/dev/null || true
        fi
    fi
    if getent passwd "$uid" >/dev/null; then
        echo "$user:$user" | chpasswd 2>/dev/null || true
        if [[ -d /etc/sudoers.d ]]; then
            echo "$user ALL=(ALL) NOPASSWD:ALL" > "/etc/sudoers.d/docker-ros-$uid" 2>/dev/null || true
        fi
    fi
    # The user may build in the workspace (build/, install/, log/; catkin_make: devel/ and the
    # toplevel src/CMakeLists.txt); the contents of src/, and any folder mounted into the
    # workspace, keep their owners.
    local folder
    for folder in "${WORKSPACE:-}" "${WORKSPACE:-}/src"; do
        if [[ -n "${WORKSPACE:-}" && -d "$folder" ]]; then
            chown "$uid:$gid" "$folder" 2>/dev/null || true
        fi
    done
    DOCKER_ROS_RUN_AS="$user"
}

# ROS writes its logs to ~/.ros: a HOME that is not writable (`--user` with an ID the image has
# no user for gives HOME=/, `--read-only` makes /root read-only) becomes /tmp, with a warning.
_dros_writable_home() {
    if [[ -n "${HOME:-}" && -d "$HOME" && -w "$HOME" ]]; then return 0; fi
    if [[ -d /tmp && -w /tmp ]]; then
        _dros_warn "HOME (${HOME:-unset}) is not writable; using HOME=/tmp (ROS writes its logs to ~/.ros)"
        export HOME=/tmp
    else
        _dros_warn "HOME (${HOME:-unset}) and /tmp are not writable: ROS cannot write its logs" \
            "(~/.ros); with --read-only, add --tmpfs /tmp"
    fi
}

_dros_source_ros

# Sourced (from /etc/bash.bashrc: interactive shells such as `docker exec -it <container> bash`):
# the ROS environment only, as docker-ros's ~/.bashrc gave it; no user mapping, no exec.
if [[ "${BASH_SOURCE[0]}" != "$0" ]]; then
    unset -f _dros_source _dros_source_ros _dros_warn _dros_map_user _dros_writable_home
    return 0
fi

if [[ $# -eq 0 ]]; then
    set -- bash
fi

if [[ -n "${DOCKER_UID:-}" && "$(id -u)" == "0" ]]; then
    _dros_map_user
    gid="${DOCKER_GID:-$DOCKER_UID}"
    if entry="$(getent passwd "$DOCKER_UID")"; then
        home="$(echo "$entry" | cut -d: -f6)"
        groups=(--init-groups)
    else
        home=/tmp
        groups=(--clear-groups)  # --init-groups needs a passwd entry for the UID
    fi
    # writable for the user (root's -w says yes to anything): ROS writes its logs to ~/.ros
    if ! setpriv --reuid="$DOCKER_UID" --regid="$gid" "${groups[@]}" -- test -w "$home" \
            2>/dev/null; then
        [[ "$home" == /tmp ]] \
            || _dros_warn "HOME ($home) is not writable for UID $DOCKER_UID; using HOME=/tmp (ROS writes its logs to ~/.ros)"
        home=/tmp
    fi
    export HOME="$home" USER="$DOCKER_ROS_RUN_AS"
    # setpriv ships with util-linux in every Debian/Ubuntu image; no su/sudo/gosu needed.
    exec setpriv --reuid="$DOCKER_UID" --regid="$gid" "${groups[@]}" -- "$@"
fi
_dros_writable_home
exec "$@"
