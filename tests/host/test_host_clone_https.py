"""clone from a password-protected git HTTP server on the loopback (git http-backend)."""

import logging
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from docker_ros.in_image.runtime.workspace import StepError
from docker_ros.in_image.steps import clone
from tests.processes import left_after
from tests.rosfixtures import git_http_server, make_git_repo, make_package, write_repos

pytestmark = pytest.mark.host
USER, PASSWORD = "robot", "pa55-w0rd-never-logged"
SRC = Path(__file__).resolve().parents[2] / "src"


@pytest.fixture
def private_remote(tmp_path):
    remotes = tmp_path / "remotes"
    make_git_repo(remotes / "private_lib", {"README": "private\n"})
    server = git_http_server(remotes, USER, PASSWORD)
    yield f"127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def test_https_credentials_clone_without_leaking(project, private_remote, caplog, capsys,
                                                 tmp_path, monkeypatch):
    # a user whose git stores every password it gets (credential.helper store)
    home = tmp_path / "home"
    home.mkdir()
    (home / ".gitconfig").write_text("[credential]\n\thelper = store\n")
    monkeypatch.setenv("HOME", str(home))
    # and one given by a parent `git -c` (GIT_CONFIG_PARAMETERS, which every git reads; ours
    # comes after it)
    monkeypatch.setenv("GIT_CONFIG_PARAMETERS", "'credential.helper'='store' 'user.name'='x'")
    url = f"http://{private_remote}/private_lib.git"
    write_repos(project.repo / ".repos", {"private_lib": {"url": url, "version": "main"}})
    caplog.set_level(logging.DEBUG)

    with pytest.raises(StepError) as err:
        clone.main(project.ws, project.settings())
    assert "repository 'private_lib'" in err.value.message
    assert err.value.message.endswith("(the server asks for a login: set GIT_HTTPS_SERVER="
                                      "127.0.0.1, GIT_HTTPS_USER and GIT_HTTPS_PASSWORD in the "
                                      "environment or .env)"), err.value.message
    with pytest.raises(StepError) as err:
        clone.main(project.ws, project.settings(git_https_server=private_remote,
                                                git_https_user=USER, git_https_password="x"))
    assert "(the server refused the login: check GIT_HTTPS_USER" in err.value.message, (
        err.value.message)

    settings = project.settings(
        git_https_server=private_remote, git_https_user=USER, git_https_password=PASSWORD
    )
    clone.main(project.ws, settings)

    assert (project.ws.upstream / "private_lib" / "README").read_text() == "private\n"
    captured = capsys.readouterr()
    assert PASSWORD not in caplog.text + captured.out + captured.err
    for path in [*project.ws.root.rglob("*"), *home.rglob("*")]:
        if path.is_file() and not path.is_symlink():
            assert PASSWORD.encode() not in path.read_bytes(), path
    assert not (home / ".git-credentials").exists()


def test_a_password_written_into_a_repos_url_is_not_shown(project, private_remote, capsys,
                                                          caplog):
    """A .repos URL with `user:password@` (a wrong password here): git hides it; vcstool does
    not when it clones (no version: `Could not clone repository '<url>'`), and neither did the
    clone step's message. Both show `***`, and the message says where the refused login came
    from."""
    wrong = "wr0ng-but-still-secret"
    url = f"http://{USER}:{wrong}@{private_remote}/private_lib.git"
    caplog.set_level(logging.DEBUG)
    for version in ("main", None):
        spec = {"url": url, **({"version": version} if version else {})}
        write_repos(project.repo / ".repos", {"private_lib": spec})
        with pytest.raises(StepError) as err:
            clone.main(project.ws, project.settings())
        message = err.value.message
        shown = f"(http://{USER}:***@{private_remote}/private_lib.git"
        assert shown + (f" @ {version})" if version else ")") in message, message
        assert "refused the user and password written into the URL" in message, message
        captured = capsys.readouterr()
        assert wrong not in message + caplog.text + captured.out + captured.err
    assert f"Could not clone repository 'http://{USER}:***@" in captured.out  # vcstool's line


def test_https_password_from_buildkit_secret_file(project, private_remote, tmp_path, monkeypatch):
    secrets = tmp_path / "secrets"
    secrets.mkdir()
    (secrets / "GIT_HTTPS_PASSWORD").write_text(PASSWORD + "\n")
    monkeypatch.setattr(clone, "SECRETS_DIR", secrets)
    url = f"http://{private_remote}/private_lib.git"
    write_repos(project.repo / ".repos", {"private_lib": {"url": url}})
    settings = project.settings(git_https_server=private_remote, git_https_user=USER)
    with clone.git_credentials(settings, secrets_dir=secrets) as env:
        assert env["GIT_ASKPASS"]
    clone.main(project.ws, settings)
    assert (project.ws.upstream / "private_lib" / "README").is_file()


def test_a_terminated_clone_leaves_no_credential_behind(tmp_path):
    """SIGTERM (a cancelled CI job, `timeout`, `kill`) to the task alone while git waits on a
    server that never answers: the task ends as terminated (143), its askpass folder is gone,
    and so are vcs and the git processes it started (none goes on cloning)."""
    repo = tmp_path / "repo"
    make_package(repo / "pkg_a", "pkg_a")
    with socket.socket() as silent:  # accepts, never answers
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        server = f"127.0.0.1:{silent.getsockname()[1]}"
        write_repos(repo / ".repos", {"lib": {"url": f"http://{server}/lib.git"}})
        temp = tmp_path / "tmp"
        temp.mkdir()
        env = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
        env.update(PYTHONPATH=str(SRC), TMPDIR=str(temp), WORKSPACE=str(tmp_path / "ws"),
                   GIT_HTTPS_SERVER=server, GIT_HTTPS_USER=USER, GIT_HTTPS_PASSWORD=PASSWORD)
        proc = subprocess.Popen([sys.executable, "-m", "docker_ros", "clone"], cwd=repo, env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 60
        while not list(temp.glob("docker-ros-git-*")) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert list(temp.glob("docker-ros-git-*")), "the clone never started"
        time.sleep(1)  # vcs and git are waiting on the server
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
        # (while the server still holds the connection open: a git left behind would wait)
        left = left_after(server)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "docker-ros clone: terminated (SIGTERM)"
    assert list(temp.iterdir()) == []
    assert PASSWORD not in out + err
    assert not left, f"still cloning after the task ended: {left}"

