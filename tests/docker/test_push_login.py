"""`docker-ros push` on a developer's machine logs in first, as a CI job does: a private
BASE_IMAGE in a registry that requires a login is pulled with REGISTRY_USER/REGISTRY_PASSWORD,
the images are pushed, and no login stays in the user's docker configuration."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from tests.ci.cihelp import docker_recorder, push_private_base_image, registry_tags
from tests.conftest import AuthRegistry
from tests.docker.buildhelp import docker_ros, remove_image, write_env
from tests.rosfixtures import make_package

pytestmark = pytest.mark.docker
PRIVATE_BASE = "docker-ros-test/push-login-base"  # (in the run's registry with a login)
# A docker credential helper that knows no login and records any attempt to store one.
CREDENTIAL_HELPER = """#!/bin/sh
case "$1" in
  get) cat >/dev/null; echo "credentials not found in native keychain"; exit 1 ;;
  list) echo "{{}}" ;;
  store) cat >> '{stored}' ;;
  erase) cat >/dev/null ;;
esac
"""


def test_push_logs_in_pulls_a_private_base_and_leaves_no_login(
    ros1_base_image: str, auth_registry: AuthRegistry, tmp_path: Path
) -> None:
    base = push_private_base_image(ros1_base_image, auth_registry, PRIVATE_BASE)
    make_package(tmp_path / "project" / "pkg_login", "pkg_login")
    project = tmp_path / "project"
    ref = f"{auth_registry.address}/docker-ros-test/push-login:1"
    write_env(project, BASE_IMAGE=base, IMAGE=ref, TARGET="run", COMMAND="pkg_login_node",
              REGISTRY=auth_registry.address, REGISTRY_USER=auth_registry.user)
    config, argv_log, shim = docker_recorder(tmp_path)
    # The user's logins live in a credential store (as Docker Desktop's do): it stays theirs,
    # and the registry's password never reaches it.
    user_config = {"auths": {"other.invalid": {}}, "credsStore": "drtest"}
    (config / "config.json").write_text(json.dumps(user_config))
    stored = tmp_path / "store-calls"
    helper = shim / "docker-credential-drtest"
    helper.write_text(CREDENTIAL_HELPER.format(stored=stored))
    helper.chmod(0o755)
    env = {"DOCKER_CONFIG": str(config), "PATH": f"{shim}{os.pathsep}{os.environ['PATH']}",
           "REGISTRY_PASSWORD": auth_registry.password}
    try:
        pushed = docker_ros(project, "push", env=env)
    finally:
        remove_image(ref)
        remove_image(base)
    assert pushed.returncode == 0, pushed.stdout[-4000:]
    assert (f"docker-ros push: logged in to {auth_registry.address} as {auth_registry.user}"
            in pushed.stdout)
    assert pushed.stdout.count("logged in to") == 1, pushed.stdout[-4000:]
    assert f"pushed {ref}" in pushed.stdout
    assert "1" in registry_tags(auth_registry.address, "docker-ros-test/push-login",
                                auth=auth_registry.auth)
    assert "login --username docker-ros-ci --password-stdin" in argv_log.read_text()
    assert auth_registry.password not in pushed.stdout + argv_log.read_text()
    # The user's configuration is as it was: their store, none of this registry's login.
    assert json.loads((config / "config.json").read_text()) == user_config
    assert sorted(os.listdir(config)) == ["cli-plugins", "config.json"]
    assert not stored.exists(), stored.read_text()


def test_push_without_credentials_cannot_pull_the_private_base(
    ros1_base_image: str, auth_registry: AuthRegistry, tmp_path: Path
) -> None:
    """The control: the same private base without REGISTRY_PASSWORD is refused before the
    build, naming BASE_IMAGE (so the test above needs its login)."""
    base = push_private_base_image(ros1_base_image, auth_registry, PRIVATE_BASE)
    project = tmp_path / "project"
    make_package(project / "pkg_login", "pkg_login")
    write_env(project, BASE_IMAGE=base, IMAGE="docker-ros-test/push-login:1", TARGET="run",
              COMMAND="pkg_login_node")
    config, _, _ = docker_recorder(tmp_path)
    pushed = docker_ros(project, "push", env={"DOCKER_CONFIG": str(config)})
    assert pushed.returncode != 0
    # the tool's own check, before any BuildKit step
    assert f"BASE_IMAGE '{base}' is neither a local image nor pullable" in pushed.stdout, \
        pushed.stdout[-3000:]
    assert "==> docker-ros build" not in pushed.stdout and "[internal]" not in pushed.stdout
