"""Cache mount ids are written into the staged Dockerfile: Engine 20.10's Dockerfile frontend
(BuildKit v0.8) leaves ARGs in RUN --mount options unexpanded, which made one build/ cache
shared by every repository and platform (found by scripts/bench.py)."""

import re
from pathlib import Path

from docker_ros.core.loading import load_settings
from docker_ros.host import buildcontext, buildplan


def settings(**environ):
    return load_settings(environ={"BASE_IMAGE": "base:1", "COMMAND": "run me", **environ},
                         project_dir=Path("/tmp/My_Robot"))


def staged(tmp_path: Path, s, platform: str) -> str:
    out = tmp_path / platform / s.image_name.replace("/", "_")
    out.mkdir(parents=True)
    dockerfile = buildcontext.stage_dockerfile(tmp_path, out)
    buildplan.expand_mount_ids(dockerfile, buildplan.mount_ids(s, platform))
    return dockerfile.read_text()


def mount_options(text: str) -> list:
    return re.findall(r"--mount=(\S+)", text)


def test_no_variable_is_left_in_any_mount_option(tmp_path):
    text = staged(tmp_path, settings(), "amd64")
    mounts = mount_options(text)
    assert mounts and not [m for m in mounts if "$" in m], mounts
    assert f"id=docker-ros-build-{buildplan.cache_id(settings(), 'amd64')}," in text


def test_repositories_and_platforms_get_their_own_build_cache(tmp_path):
    def ids(text):
        return {m for m in mount_options(text) if "target=/docker-ros/ws/build" in m}

    a = ids(staged(tmp_path, settings(), "amd64"))
    b = ids(staged(tmp_path, settings(), "arm64"))
    c = ids(staged(tmp_path, settings(IMAGE="other/img"), "amd64"))
    assert len(a) == len(b) == len(c) == 1 and len(a | b | c) == 3


def test_the_shipped_dockerfile_is_not_modified(tmp_path):
    before = buildcontext.DOCKERFILE.read_text()
    staged(tmp_path, settings(), "amd64")
    assert buildcontext.DOCKERFILE.read_text() == before
