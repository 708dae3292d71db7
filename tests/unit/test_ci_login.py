"""CI jobs: registry login (argv, the job-private DOCKER_CONFIG) and the single-job multi-arch
slim (the runner's architecture only, pushed under the slim names as docker-ros does)."""

import contextlib
import json
import os
import socket
import time
from pathlib import Path

import pytest

from docker_ros.cli.settingstask import logs_in_now
from docker_ros.core.loading import load_settings
from docker_ros.host import login
from docker_ros.host.login import (
    LOGGED_IN,
    LoginError,
    job_login,
    mirror_docker_config,
    plan_login,
    private_config,
)
from docker_ros.host.push import plan_push, push_targets
from docker_ros.host.refs import slim_platforms
from tests.rosfixtures import free_port


def test_login_takes_the_password_on_standard_input_only() -> None:
    s = load_settings(environ={"REGISTRY": "reg.example:5000", "REGISTRY_USER": "me",
                               "REGISTRY_PASSWORD": "s3cret-value"})
    argv = plan_login(s)
    assert argv == ["docker", "login", "--username", "me", "--password-stdin",
                    "reg.example:5000"]
    assert "s3cret-value" not in " ".join(argv)
    assert plan_login(load_settings(environ={"REGISTRY_USER": "me"})) is None


def test_private_docker_config_copies_logins_and_links_the_rest(tmp_path: Path) -> None:
    user = tmp_path / "user"
    (user / "cli-plugins").mkdir(parents=True)
    (user / "config.json").write_text('{"auths": {"other.example": {"auth": "eA=="}}}')
    private = tmp_path / "private"
    mirror_docker_config(user, private, "reg.example")
    assert (private / "cli-plugins").resolve() == (user / "cli-plugins").resolve()
    assert not (private / "config.json").is_symlink()
    assert json.loads((private / "config.json").read_text()) == {
        "auths": {"other.example": {"auth": "eA=="}}, "credHelpers": {"reg.example": ""}}
    (private / "config.json").write_text("{}")  # what a login changes
    assert "other.example" in (user / "config.json").read_text()
    mirror_docker_config(tmp_path / "missing", tmp_path / "fresh", "reg.example")
    assert list((tmp_path / "fresh").iterdir()) == []


def test_the_login_never_goes_to_a_credential_store() -> None:
    """The user's other logins (their store, their helpers) stay usable; the registry's goes to
    the job's file (docker: an empty helper is the file)."""
    config = {"credsStore": "desktop", "credHelpers": {"reg.example": "ecr", "gcr.io": "gcr"},
              "currentContext": "ci"}
    assert private_config(config, "reg.example") == {
        "credsStore": "desktop", "credHelpers": {"reg.example": "", "gcr.io": "gcr"},
        "currentContext": "ci"}
    # docker files a login by host name, and Docker Hub's under its index address
    assert private_config({}, "https://reg.example/v2/")["credHelpers"] == {
        "https://reg.example/v2/": "", "reg.example": ""}
    for hub in ("docker.io", "", "index.docker.io"):
        assert private_config({"credsStore": "desktop"}, hub)["credHelpers"][
            "https://index.docker.io/v1/"] == "", hub


def test_several_platforms_slim_the_runners_only() -> None:
    assert slim_platforms(("amd64", "arm64"), "amd64") == ("amd64",)
    assert slim_platforms(("amd64", "arm64"), "arm64") == ("arm64",)
    assert slim_platforms(("amd64",), "amd64") == ("amd64",)
    assert slim_platforms(("arm64",), "amd64") == ("arm64",)  # slim's own error says why


def test_single_job_multi_arch_pushes_the_runners_slim_image_under_the_slim_names() -> None:
    """docker-ros's "Build multi-arch images" example: both architectures as manifest lists,
    the slim image of the runner's architecture as it is."""
    s = load_settings(environ={"IMAGE": "reg/x:v1", "TARGET": "run", "PLATFORM": "amd64,arm64",
                               "ENABLE_SLIM": "true",
                               "ENABLE_PUSH_AS_LATEST": "true"})
    assert push_targets(s) == ["run", "slim"]
    commands = plan_push(s, push_targets(s), host="arm64")
    slim = [c for c in commands if "slim" in c[-1]]
    assert slim == [["docker", "tag", "reg/x:v1-slim-arm64", "reg/x:v1-slim"],
                    ["docker", "push", "reg/x:v1-slim"],
                    ["docker", "tag", "reg/x:v1-slim-arm64", "reg/x:latest-slim"],
                    ["docker", "push", "reg/x:latest-slim"]]
    assert ["docker", "push", "reg/x:v1-amd64"] in commands
    assert ["docker", "push", "reg/x:v1-arm64"] in commands
    single = load_settings(environ={"IMAGE": "reg/x:v1", "PLATFORM": "amd64,arm64",
                                    "ENABLE_SLIM": "true", "ENABLE_SINGLEARCH_PUSH": "true"})
    assert [c for c in plan_push(single, ["slim"], host="amd64")] == [
        ["docker", "push", "reg/x:v1-slim-amd64"]]


def test_tasks_that_reach_a_registry_log_in_but_not_on_the_host() -> None:
    assert logs_in_now(True, {"dry_run": False})
    assert not logs_in_now(True, {"host": True})
    assert not logs_in_now(False, {})
    assert logs_in_now("in_container", {"in_container": True})
    assert not logs_in_now("in_container", {"in_container": False})


def test_a_task_of_a_logged_in_job_uses_its_login(tmp_path: Path) -> None:
    """`ci` runs `push` as a process: push finds the job's login (registry and user) in its
    environment and runs `docker login` no second time (no docker is needed for that)."""
    s = load_settings(environ={"REGISTRY": "reg:5000", "REGISTRY_USER": "me",
                               "REGISTRY_PASSWORD": "pw"})
    environ = {LOGGED_IN: "reg:5000 me", "DOCKER_CONFIG": str(tmp_path)}
    with job_login(s, environ, label="docker-ros push"):
        assert environ["DOCKER_CONFIG"] == str(tmp_path)
    assert environ == {LOGGED_IN: "reg:5000 me", "DOCKER_CONFIG": str(tmp_path)}


# A `docker` that does what `docker login --password-stdin` does to DOCKER_CONFIG, and keeps
# its command line and standard input where the test reads them.
FAKE_DOCKER = """#!/bin/sh
echo "$*" > {out}/argv
cat > {out}/stdin
printf '{{"auths": {{"%s": {{"auth": "bWU6cHc="}}}}}}' "$5" > "$DOCKER_CONFIG/config.json"
"""


def test_the_login_lives_in_a_folder_of_the_task_removed_at_its_end(tmp_path: Path,
                                                                   monkeypatch) -> None:
    """Self-hosted and shell runners keep ~/.docker: the login goes to a task-private
    DOCKER_CONFIG, removed when the task ends (also when it fails); the user's stays as it
    was. (What the copy keeps of the user's config: the test before, test_private_docker_
    config_copies_logins_and_links_the_rest.)"""
    user = tmp_path / "user-config"
    user.mkdir()
    before = json.dumps({"auths": {"other.example": {"auth": "dXNlcjpwYXNz"}}})
    (user / "config.json").write_text(before)
    shim = tmp_path / "bin"
    shim.mkdir()
    (shim / "docker").write_text(FAKE_DOCKER.format(out=tmp_path))
    (shim / "docker").chmod(0o755)
    monkeypatch.setenv("PATH", f"{shim}:{os.environ['PATH']}")
    monkeypatch.setenv("DOCKER_CONFIG", str(user))
    monkeypatch.delenv(LOGGED_IN, raising=False)
    s = load_settings(environ={"REGISTRY": "reg.example:5000", "REGISTRY_USER": "me",
                               "REGISTRY_PASSWORD": "pw-on-stdin-only"})
    folders = []
    for fails in (False, True):
        with contextlib.suppress(RuntimeError), job_login(s, os.environ, label="docker-ros push"):
            private = Path(os.environ["DOCKER_CONFIG"])
            folders.append(private.parent)
            assert private.parent.name.startswith("docker-ros-login-")
            assert "reg.example:5000" in json.loads((private / "config.json").read_text())[
                "auths"]
            if fails:
                raise RuntimeError("the task failed")
        assert os.environ["DOCKER_CONFIG"] == str(user) and LOGGED_IN not in os.environ
    assert folders[0] != folders[1] and not any(folder.exists() for folder in folders)
    assert (user / "config.json").read_text() == before
    assert (tmp_path / "stdin").read_text().strip() == "pw-on-stdin-only"
    assert (tmp_path / "argv").read_text().split() == [
        "login", "--username", "me", "--password-stdin", "reg.example:5000"]


def test_a_failed_login_only_stops_a_task_that_needs_it(tmp_path: Path, capsys) -> None:
    """`build` (required=False) may need no registry: a refused login is a warning and the
    user's own docker configuration stays in force; `push` (required) stops."""
    registry = f"127.0.0.1:{free_port()}"  # nothing listens: docker login is refused
    s = load_settings(environ={"REGISTRY": registry, "REGISTRY_USER": "me",
                               "REGISTRY_PASSWORD": "pw-never-shown"})
    environ = {"DOCKER_CONFIG": str(tmp_path)}
    with job_login(s, environ, label="docker-ros build", required=False):
        assert environ == {"DOCKER_CONFIG": str(tmp_path)}
    err = capsys.readouterr().err
    assert f"docker-ros build: docker login to {registry} as me failed:" in err
    assert "going on without it" in err and "pw-never-shown" not in err
    pushing = job_login(s, environ, label="docker-ros push")
    with pytest.raises(LoginError, match=f"docker login to {registry} as me failed"), pushing:
        pass
    assert environ == {"DOCKER_CONFIG": str(tmp_path)}


def test_an_optional_login_that_gets_no_answer_gives_up(tmp_path: Path, capsys,
                                                        monkeypatch) -> None:
    """A registry that accepts connections and never answers (out of reach behind a VPN looks
    alike to a client): a build does not wait for docker's own timeouts."""
    monkeypatch.setattr(login, "OPTIONAL_LOGIN_SECONDS", 2.0)
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(8)
        registry = f"127.0.0.1:{silent.getsockname()[1]}"
        s = load_settings(environ={"REGISTRY": registry, "REGISTRY_USER": "me",
                                   "REGISTRY_PASSWORD": "pw"})
        environ = {"DOCKER_CONFIG": str(tmp_path)}
        started = time.monotonic()
        with job_login(s, environ, label="docker-ros build", required=False):
            pass
        assert time.monotonic() - started < 15
    assert f"docker login to {registry} as me got no answer in 2 s" in capsys.readouterr().err


def test_half_of_the_credentials_is_a_warning_naming_the_missing_one(tmp_path: Path,
                                                                     capsys) -> None:
    """REGISTRY_USER without REGISTRY_PASSWORD (a protected CI variable on an unprotected
    branch) logs in nowhere: the task says so at its start instead of failing at the push,
    after the whole build, with the registry's 'unauthorized'."""
    for given, missing in (("REGISTRY_USER", "REGISTRY_PASSWORD"),
                           ("REGISTRY_PASSWORD", "REGISTRY_USER")):
        environ = {"DOCKER_CONFIG": str(tmp_path)}
        s = load_settings(environ={"REGISTRY": "reg:5000", given: "pw-never-shown"})
        with job_login(s, environ, label="docker-ros push"):
            assert environ["DOCKER_CONFIG"] == str(tmp_path)
        err = capsys.readouterr().err
        assert (f"docker-ros push: warning: {given} is set but {missing} is empty: no docker "
                "login to reg:5000") in err
        assert "pw-never-shown" not in err
        # once a job: the tasks `ci` runs as processes (its environment) say it no second time
        with job_login(s, environ, label="docker-ros build"):
            pass
        assert capsys.readouterr().err == ""
    environ = {"DOCKER_CONFIG": str(tmp_path)}
    s = load_settings(environ={"REGISTRY": "reg:5000"})
    with job_login(s, environ, label="docker-ros push"):
        pass
    assert capsys.readouterr().err == ""
