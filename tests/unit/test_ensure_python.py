"""docker/ensure-python.sh, the base stage's first command: a python3 older than 3.8 is one clear
line naming BASE_IMAGE, its version and the minimum (the real image case: tests/docker)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "docker" / "ensure-python.sh"


def ensure_python(
    tmp_path: Path, version_line: str, *, stream: str = ""
) -> subprocess.CompletedProcess:
    """Run the script with a python3 first on PATH that prints version_line for --version."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    fake = bin_dir / "python3"
    fake.write_text(f"#!/bin/sh\necho '{version_line}' {stream}\n")
    fake.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}",
           "BASE_IMAGE": "ubuntu:18.04"}
    return subprocess.run(["sh", str(SCRIPT)], env=env, capture_output=True, text=True)


@pytest.mark.parametrize(("line", "stream"), [("Python 3.6.9", ""), ("Python 3.7.17", ""),
                                              ("Python 2.7.18", ">&2"), ("Python 3.8", "")])
def test_too_old_python3_is_one_line_naming_base_image_version_and_minimum(
    tmp_path: Path, line: str, stream: str
) -> None:
    result = ensure_python(tmp_path, line, stream=stream)
    version = line.split()[1]
    if version == "3.8":
        assert result.returncode == 0, result.stderr
        return
    assert result.returncode == 1
    assert result.stderr.splitlines() == [
        f"docker-ros prepare: BASE_IMAGE 'ubuntu:18.04' has python3 {version} "
        f"({tmp_path / 'bin' / 'python3'}); docker-ros needs Python 3.8 or newer in the image: "
        "use a newer base image (Ubuntu 20.04+, Debian 11+) or install a newer python3 in it"]


def test_unreadable_version_fails_too(tmp_path: Path) -> None:
    result = ensure_python(tmp_path, "no version here")
    assert result.returncode == 1
    assert "has python3 of unknown version" in result.stderr


def test_this_python_passes() -> None:
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
    result = subprocess.run(["sh", str(SCRIPT)], env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
