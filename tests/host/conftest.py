"""Fixtures of the host integration tests: a workspace whose src/target is a symlink to a
user repository (as on a developer's machine), settings from an environ mapping, a venv."""

import subprocess
import sys
from pathlib import Path
from typing import Callable, Dict

import pytest

from docker_ros.core.loading import load_settings
from docker_ros.core.settings import Settings
from docker_ros.in_image.runtime.workspace import Workspace


class Project:
    """A user repository plus the host workspace that links it as src/target."""

    def __init__(self, base: Path) -> None:
        self.repo = base / "user-repo"
        self.repo.mkdir()
        self.ws = Workspace(base / "ws")
        self.ws.src.mkdir(parents=True)
        self.ws.target.symlink_to(self.repo, target_is_directory=True)

    def settings(self, **env: str) -> Settings:
        return load_settings(environ={k.upper(): v for k, v in env.items()}, project_dir=self.repo)


@pytest.fixture
def project(tmp_path: Path) -> Project:
    return Project(tmp_path)


@pytest.fixture(scope="session")
def venv_python(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A virtualenv's python (the target of pip installs in tests)."""
    path = tmp_path_factory.mktemp("venv") / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(path)], check=True)
    return path / "bin" / "python"


@pytest.fixture
def environ(monkeypatch: pytest.MonkeyPatch) -> Callable[..., None]:
    """Set environment variables for the test (os.environ is what the steps' tools see)."""

    def apply(values: Dict[str, str]) -> None:
        for key, value in values.items():
            monkeypatch.setenv(key, value)

    return apply
