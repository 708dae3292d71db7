"""GIT_HTTPS_PASSWORD from the environment reaches the build as the one from .env does: the same
BuildKit secret (tests/docker/test_secrets.py builds with it from .env, and with both secrets
from the environment, and proves nothing leaks). Was an image build of its own."""

from pathlib import Path

from docker_ros.host import buildplan
from docker_ros.host.config import read_settings

SERVER = "127.0.0.1:8080"


def project(tmp_path: Path, **dotenv: str) -> Path:
    (tmp_path / "pkg").mkdir(parents=True)
    (tmp_path / "pkg" / "package.xml").write_text("<package/>")
    values = {"BASE_IMAGE": "base:1", "COMMAND": "true", "GIT_HTTPS_SERVER": SERVER,
              "GIT_HTTPS_USER": "robot", **dotenv}
    (tmp_path / ".env").write_text("".join(f"{k}={v}\n" for k, v in values.items()))
    return tmp_path


def settings_of(folder: Path, environ: dict):
    """The settings `docker-ros build` reads in folder (its .env) with environ."""
    return read_settings({}, {}, project_dir=folder, environ=environ)


def test_the_https_password_from_the_environment_is_the_builds_secret(tmp_path: Path) -> None:
    password = "pw-from-the-environment"
    from_env = settings_of(project(tmp_path / "env"), {"GIT_HTTPS_PASSWORD": password})
    from_dotenv = settings_of(project(tmp_path / "dotenv", GIT_HTTPS_PASSWORD=password), {})
    assert from_env.source_of("git_https_password") == "environment"
    assert from_dotenv.source_of("git_https_password") == ".env"
    for settings in (from_env, from_dotenv):
        assert buildplan.secret_env(settings) == {"DOCKER_ROS_SECRET_GIT_HTTPS_PASSWORD": password}
        assert buildplan.plan_secrets(settings, None) == {
            "GIT_HTTPS_PASSWORD": "env=DOCKER_ROS_SECRET_GIT_HTTPS_PASSWORD"}
    # the environment outranks .env (a CI's masked variable over a developer's file)
    both = settings_of(project(tmp_path / "both", GIT_HTTPS_PASSWORD="old"),
                       {"GIT_HTTPS_PASSWORD": password})
    assert buildplan.secret_env(both) == {"DOCKER_ROS_SECRET_GIT_HTTPS_PASSWORD": password}
