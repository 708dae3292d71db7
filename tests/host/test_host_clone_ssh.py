"""clone over SSH from Debian's sshd on the loopback: a private key and known host keys from the
settings, a clear error without `ssh`, and no key material left behind."""

import logging
import os
import subprocess
from pathlib import Path

import pytest

from docker_ros.in_image.runtime.workspace import StepError
from docker_ros.in_image.steps import clone
from tests.rosfixtures import make_git_repo, ssh_keygen, sshd_server, write_repos

pytestmark = pytest.mark.host


@pytest.fixture(scope="module")
def ssh_remote(tmp_path_factory):
    """(url, private key, known host keys) of a repository served by sshd for root."""
    work = tmp_path_factory.mktemp("ssh")
    key = ssh_keygen(work / "id_ed25519")
    make_git_repo(work / "repos" / "private_lib", {"README": "private over ssh\n"})
    server = sshd_server(work / "sshd", (work / "id_ed25519.pub").read_text())
    scan = subprocess.run(["ssh-keyscan", "-p", str(server.port), "127.0.0.1"],
                          capture_output=True, text=True, timeout=30)
    assert scan.stdout.strip(), scan.stderr
    url = f"ssh://root@127.0.0.1:{server.port}{work / 'repos' / 'private_lib.git'}"
    yield url, key, scan.stdout
    server.stop()


def test_ssh_key_clones_and_leaves_no_key_behind(project, ssh_remote, caplog, capsys):
    url, key, known_hosts = ssh_remote
    write_repos(project.repo / ".repos", {"private_lib": {"url": url, "version": "main"}})
    caplog.set_level(logging.DEBUG)
    # One line with literal \n, as docker-ros users wrote keys in CI variables.
    settings = project.settings(
        git_ssh_private_key=key.replace("\n", "\\n"), git_ssh_known_host_keys=known_hosts
    )
    clone.main(project.ws, settings)

    assert (project.ws.upstream / "private_lib" / "README").read_text() == "private over ssh\n"
    body = [line for line in key.splitlines() if line and not line.startswith("-----")]
    captured = capsys.readouterr()
    for line in body:
        assert line not in caplog.text + captured.out + captured.err
    for path in project.ws.root.rglob("*"):
        if path.is_file() and not path.is_symlink():
            assert not any(line.encode() in path.read_bytes() for line in body), path


def test_ssh_without_key_fails_naming_the_repository(project, ssh_remote):
    url, _key, known_hosts = ssh_remote
    write_repos(project.repo / ".repos", {"private_lib": {"url": url}})
    with pytest.raises(StepError) as err:
        clone.main(project.ws, project.settings(git_ssh_known_host_keys=known_hosts))
    assert f"repository 'private_lib' ({url}" in err.value.message
    assert err.value.message.endswith(" (the server wants an SSH login: set GIT_SSH_PRIVATE_KEY "
                                      "and GIT_SSH_KNOWN_HOST_KEYS (its lines from `ssh-keyscan "
                                      "127.0.0.1`) in the environment or .env)"), err.value.message
    assert not (project.ws.upstream / "private_lib").exists()


def test_no_ssh_command_is_a_clear_error(project, ssh_remote, tmp_path, monkeypatch):
    """A PATH with every command of ours except ssh (like a base image without openssh-client)."""
    url, key, known_hosts = ssh_remote
    shadow = tmp_path / "bin"
    shadow.mkdir()
    for directory in os.environ["PATH"].split(os.pathsep):
        if not Path(directory).is_dir():
            continue
        for entry in Path(directory).iterdir():
            if entry.name != "ssh" and not (shadow / entry.name).exists():
                (shadow / entry.name).symlink_to(entry)
    monkeypatch.setenv("PATH", str(shadow))
    monkeypatch.delenv("GIT_SSH_COMMAND", raising=False)
    monkeypatch.delenv("GIT_SSH", raising=False)
    write_repos(project.repo / ".repos", {"private_lib": {"url": url}})
    settings = project.settings(git_ssh_private_key=key, git_ssh_known_host_keys=known_hosts)
    with pytest.raises(StepError) as err:
        clone.main(project.ws, settings)
    message = err.value.message
    assert f"repository 'private_lib' ({url}) cloned over SSH" in message, message
    assert "no `ssh` command" in message and "openssh-client" in message, message
