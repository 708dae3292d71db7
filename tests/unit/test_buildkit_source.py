"""The docker.io source the tests' buildkit image is built from when the pinned one has left
Debian's pool: read from a Sources index (tests/engines.py)."""

from tests.engines import current_docker_io

SOURCES = """Package: docker.io
Binary: docker.io, golang-github-docker-docker-dev
Version: 26.1.5+dfsg1-9
Checksums-Sha256:
 3a4a  1406148 docker.io_26.1.5+dfsg1.orig-buildkit.tar.xz
 e06b  4443500 docker.io_26.1.5+dfsg1.orig.tar.xz
 1111  100 docker.io_26.1.5+dfsg1-9.debian.tar.xz
 2222  10 docker.io_26.1.5+dfsg1-9.dsc
Directory: pool/main/d/docker.io

Package: docker-compose
Version: 2.26.1-4

Package: docker.io
Version: 26.1.5+dfsg1-9+deb13u2
Checksums-Sha256:
 3a4a  1406148 docker.io_26.1.5+dfsg1.orig-buildkit.tar.xz
 e06b  4443500 docker.io_26.1.5+dfsg1.orig.tar.xz
 3333  101 docker.io_26.1.5+dfsg1-9+deb13u2.debian.tar.xz
 4444  11 docker.io_26.1.5+dfsg1-9+deb13u2.dsc
Directory: pool/main/d/docker.io
"""


def test_the_last_docker_io_stanza_gives_version_revision_and_the_three_tarballs() -> None:
    assert current_docker_io(SOURCES) == {
        "version": "26.1.5+dfsg1", "revision": "9+deb13u2",
        "sha256": {"docker.io_26.1.5+dfsg1.orig-buildkit.tar.xz": "3a4a",
                   "docker.io_26.1.5+dfsg1.orig.tar.xz": "e06b",
                   "docker.io_26.1.5+dfsg1-9+deb13u2.debian.tar.xz": "3333"}}
