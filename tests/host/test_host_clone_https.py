"""clone from a password-protected git HTTP server on the loopback (git http-backend)."""

import logging

import pytest

from docker_ros.in_image.runtime.workspace import StepError
from docker_ros.in_image.steps import clone
from tests.rosfixtures import git_http_server, make_git_repo, write_repos

pytestmark = pytest.mark.host
USER, PASSWORD = "robot", "pa55-w0rd-never-logged"


@pytest.fixture
def private_remote(tmp_path):
    remotes = tmp_path / "remotes"
    make_git_repo(remotes / "private_lib", {"README": "private\n"})
    server = git_http_server(remotes, USER, PASSWORD)
    yield f"127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def test_https_credentials_clone_without_leaking(project, private_remote, caplog, capsys):
    url = f"http://{private_remote}/private_lib.git"
    write_repos(project.repo / ".repos", {"private_lib": {"url": url, "version": "main"}})
    caplog.set_level(logging.DEBUG)

    with pytest.raises(StepError) as err:
        clone.main(project.ws, project.settings())
    assert "repository 'private_lib'" in err.value.message

    settings = project.settings(
        git_https_server=private_remote, git_https_user=USER, git_https_password=PASSWORD
    )
    clone.main(project.ws, settings)

    assert (project.ws.upstream / "private_lib" / "README").read_text() == "private\n"
    captured = capsys.readouterr()
    assert PASSWORD not in caplog.text + captured.out + captured.err
    for path in project.ws.root.rglob("*"):
        if path.is_file() and not path.is_symlink():
            assert PASSWORD.encode() not in path.read_bytes(), path


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
