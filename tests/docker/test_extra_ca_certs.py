"""EXTRA_CA_CERTS (issue 5) on any machine: the test makes a CA of its own and an HTTPS server on
127.0.0.1 with a certificate it signed, serving a wheel. The build's pip step downloads it: it
fails naming the fix without the setting, passes with it, and the CA is in no layer of either
image (nor trusted by them afterwards)."""

from __future__ import annotations

import datetime
import functools
import hashlib
import http.server
import io
import ipaddress
import socket
import ssl
import subprocess
import tarfile
import threading
import uuid
import zipfile
from base64 import urlsafe_b64encode
from pathlib import Path
from typing import Iterator, List, NamedTuple

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from tests.docker.buildhelp import docker_ros, failure_message, remove_image, write_env
from tests.rosfixtures import make_package

pytestmark = pytest.mark.docker

IMAGE = "docker-ros-test/ca:1"
MODULE = "docker_ros_ca_probe"


class Pki(NamedTuple):
    ca: Path  # the CA certificate (PEM): what EXTRA_CA_CERTS points at
    cert: Path  # the server's certificate for 127.0.0.1, signed by the CA
    key: Path


def make_pki(directory: Path) -> Pki:
    """A throwaway CA (valid for a day) and a server certificate for 127.0.0.1 it signed."""
    now = datetime.datetime.now(datetime.timezone.utc)
    day = datetime.timedelta(days=1)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME,
                                            f"docker-ros test CA {uuid.uuid4().hex[:8]}")])
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name)
          .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
          .not_valid_before(now - day).not_valid_after(now + day)
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                       content_commitment=False, key_encipherment=False,
                                       data_encipherment=False, key_agreement=False,
                                       encipher_only=False, decipher_only=False), critical=True)
          .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()),
                         critical=False)
          .sign(ca_key, hashes.SHA256()))
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "127.0.0.1")]))
            .issuer_name(ca_name).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - day).not_valid_after(now + day)
            .add_extension(x509.SubjectAlternativeName(
                [x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]),
                           critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(
                ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    pki = Pki(directory / "ca.crt", directory / "server.crt", directory / "server.key")
    pki.ca.write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    pki.cert.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    pki.key.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                          serialization.PrivateFormat.PKCS8,
                                          serialization.NoEncryption()))
    return pki


def make_wheel(directory: Path) -> Path:
    """A minimal pure-Python wheel of one empty module."""
    dist_info = f"{MODULE}-1.0.dist-info"
    files = {
        f"{MODULE}/__init__.py": b"",
        f"{dist_info}/METADATA": b"Metadata-Version: 2.1\nName: docker-ros-ca-probe\n"
                                 b"Version: 1.0\n",
        f"{dist_info}/WHEEL": b"Wheel-Version: 1.0\nGenerator: docker-ros-tests\n"
                              b"Root-Is-Purelib: true\nTag: py3-none-any\n",
    }
    record = [f"{name},sha256={digest(data)},{len(data)}" for name, data in files.items()]
    files[f"{dist_info}/RECORD"] = ("\n".join([*record, f"{dist_info}/RECORD,,"]) + "\n").encode()
    wheel = directory / f"{MODULE}-1.0-py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w") as archive:
        for name, data in files.items():
            archive.writestr(name, data)
    return wheel


def digest(data: bytes) -> str:
    """A wheel RECORD's hash: urlsafe base64 of the SHA-256, no padding."""
    return urlsafe_b64encode(hashlib.sha256(data).digest()).decode().rstrip("=")


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: object) -> None:  # noqa: A002 (the base's name)
        pass


@pytest.fixture
def https_wheel(tmp_path: Path) -> Iterator[tuple]:
    """(PKI, URL of the wheel, port) served over HTTPS on 127.0.0.1 by a certificate of the test CA;
    the URL has a path of this run, so no cached layer of an earlier run hides the download."""
    pki = make_pki(tmp_path)
    served = tmp_path / "served" / uuid.uuid4().hex
    served.mkdir(parents=True)
    wheel = make_wheel(served)
    server = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(QuietHandler, directory=str(tmp_path / "served")))
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.load_cert_chain(str(pki.cert), str(pki.key))
    server.socket = context.wrap_socket(server.socket, server_side=True)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    port = server.server_address[1]
    try:
        yield pki, f"https://127.0.0.1:{port}/{served.name}/{wheel.name}", port
    finally:
        server.shutdown()
        server.server_close()


def test_extra_ca_certs_work_during_the_build_and_stay_out_of_images(
    ros1_base_image: str, https_wheel: tuple, tmp_path: Path
) -> None:
    pki, url, port = https_wheel
    # Only the test CA makes the server trusted (not the host's nor the images' CAs).
    with socket.create_connection(("127.0.0.1", port)) as raw, \
            pytest.raises(ssl.SSLCertVerificationError):
        ssl.create_default_context().wrap_socket(raw, server_hostname="127.0.0.1")
    with socket.create_connection(("127.0.0.1", port)) as raw:
        ssl.create_default_context(cafile=str(pki.ca)).wrap_socket(
            raw, server_hostname="127.0.0.1").close()
    project = tmp_path / "ws"
    make_package(project / "pkg", "pkg")
    (project / "docker").mkdir()
    (project / "docker" / "additional-pip-requirements.txt").write_text(
        f"docker-ros-ca-probe @ {url}\n")
    write_env(project, BASE_IMAGE=ros1_base_image, IMAGE=IMAGE, TARGET="dev,run",
              COMMAND=f"python3 -c 'import {MODULE}'", BUILD_NETWORK="host")
    try:
        without = docker_ros(project, "build")
        assert without.returncode != 0
        last = failure_message(without.stdout)
        assert "failed in step pip" in last, without.stdout[-3000:]
        # The cause and the fix in the last line, after pip's first try (no minutes of retries).
        assert "CERTIFICATE_VERIFY_FAILED" in last and "set EXTRA_CA_CERTS" in last, last
        assert "Retry(total=3" not in without.stdout
        # docker-ros stopped pip: no exit code of our signal (-15) as if pip had failed so
        assert "stopped at pip's first TLS failure" in last and "-15" not in last, last

        certs = tmp_path / "certs"  # outside the repository (the build context)
        certs.mkdir()
        (certs / "test-ca.crt").write_bytes(pki.ca.read_bytes())
        built = docker_ros(project, "build", env={"EXTRA_CA_CERTS": str(certs)})
        assert built.returncode == 0, built.stdout[-4000:]
        assert subprocess.run(["docker", "run", "--rm", IMAGE]).returncode == 0

        # The CA's body is in no layer of either image, and neither image trusts it.
        needles = [line.encode() for line in pki.ca.read_text().splitlines()[1:3]]
        fetch = (f"import urllib.request; urllib.request.urlopen({url!r}, timeout=20)")
        for ref in (IMAGE, f"{IMAGE}-dev"):
            archive = tmp_path / "image.tar"
            subprocess.run(["docker", "save", "-o", str(archive), ref], check=True)
            content = b"".join(layer_files(archive))
            archive.unlink()
            for needle in needles:
                assert needle not in content, f"CA found in {ref}"
            untrusted = subprocess.run(["docker", "run", "--rm", "--network", "host", ref,
                                        "python3", "-c", fetch], capture_output=True, text=True)
            assert untrusted.returncode != 0 and "CERTIFICATE_VERIFY_FAILED" in untrusted.stderr, \
                untrusted.stderr[-2000:]
    finally:
        remove_image(IMAGE)
        remove_image(f"{IMAGE}-dev")


def layer_files(archive: Path) -> List[bytes]:
    """The content of every file of every layer of a `docker save` archive (and its JSON)."""
    chunks = []
    with tarfile.open(archive) as image:
        for member in image.getmembers():
            data = image.extractfile(member) if member.isfile() else None
            if data is None:
                continue
            blob = data.read()
            if not member.name.endswith(".tar"):
                chunks.append(blob)
                continue
            with tarfile.open(fileobj=io.BytesIO(blob)) as layer:
                for entry in layer.getmembers():
                    content = layer.extractfile(entry) if entry.isfile() else None
                    if content is not None:
                        chunks.append(content.read())
    return chunks
