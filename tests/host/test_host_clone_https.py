"""clone from a password-protected git HTTP server on the loopback (git http-backend)."""

import base64
import logging
import os
import subprocess
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from docker_ros.steps import clone
from docker_ros.steps.common import StepError
from tests.rosfixtures import make_git_repo, write_repos

pytestmark = pytest.mark.host
USER, PASSWORD = "robot", "pa55-w0rd-never-logged"


def git_http_server(root):
    """A smart-HTTP git server for the bare repositories in `root`, Basic auth required."""
    expected = "Basic " + base64.b64encode(f"{USER}:{PASSWORD}".encode()).decode()

    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args):
            pass

        def do_GET(self):
            self.serve()

        def do_POST(self):
            self.serve()

        def serve(self):
            if self.headers.get("Authorization") != expected:
                self.send_response(401)
                self.send_header("WWW-Authenticate", 'Basic realm="git"')
                self.send_header("Content-Length", "0")
                self.end_headers()
                return
            path, _, query = self.path.partition("?")
            length = int(self.headers.get("Content-Length") or 0)
            body = self.rfile.read(length) if length else b""
            env = {
                "PATH": os.environ["PATH"],
                "GIT_PROJECT_ROOT": str(root),
                "GIT_HTTP_EXPORT_ALL": "1",
                "PATH_INFO": path,
                "QUERY_STRING": query,
                "REQUEST_METHOD": self.command,
                "CONTENT_TYPE": self.headers.get("Content-Type", ""),
                "CONTENT_LENGTH": str(len(body)),
                "HTTP_CONTENT_ENCODING": self.headers.get("Content-Encoding", ""),
                "GIT_PROTOCOL": self.headers.get("Git-Protocol", ""),
                "REMOTE_USER": USER,
            }
            out = subprocess.run(
                ["git", "http-backend"], input=body, env=env, capture_output=True, check=True
            ).stdout
            sep = b"\r\n\r\n" if b"\r\n\r\n" in out else b"\n\n"
            head, _, payload = out.partition(sep)
            status, headers = 200, []
            for line in head.decode().splitlines():
                name, _, value = line.partition(":")
                if name.lower() == "status":
                    status = int(value.split()[0])
                elif name:
                    headers.append((name, value.strip()))
            self.send_response(status)
            for name, value in headers:
                self.send_header(name, value)
            self.send_header("Content-Length", str(len(payload)))
            self.end_headers()
            self.wfile.write(payload)

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


@pytest.fixture
def private_remote(tmp_path):
    remotes = tmp_path / "remotes"
    make_git_repo(remotes / "private_lib", {"README": "private\n"})
    server = git_http_server(remotes)
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
