"""vcstool, rosdep and colcon are the `host` extra: only the host-mode steps run them. A missing
one on the host says how to get it; in an image (prepare installs them) the hint would mislead."""

import re
import sys
from importlib.metadata import requires

import pytest

from docker_ros.in_image.runtime.process import HOST_EXTRA, probe, run, run_tee
from docker_ros.in_image.runtime.workspace import StepError

HOST_TOOLS = {"vcstool", "rosdep", "colcon-common-extensions"}


def test_host_tools_are_an_extra_that_the_test_extra_includes() -> None:
    """(the installed metadata: scripts/setup.sh reinstalls when pyproject.toml changes)"""
    by_extra: dict = {}
    for requirement in requires("docker-ros") or []:
        name = re.match(r"[\w.-]+(\[\w+\])?", requirement).group(0)  # type: ignore[union-attr]
        extra = re.search(r'extra == "(\w+)"', requirement)
        by_extra.setdefault(extra.group(1) if extra else "", set()).add(name)
    assert not by_extra[""] & HOST_TOOLS
    # (and the modules of theirs that the host-mode steps import themselves)
    assert by_extra["host"] == HOST_TOOLS | {"catkin_pkg", "PyYAML"}
    assert "docker-ros[host]" in by_extra["test"]


@pytest.mark.parametrize("runner", [run, probe, run_tee])
def test_missing_host_tool_names_the_extra(runner, monkeypatch, tmp_path) -> None:
    monkeypatch.delenv("DOCKER_ROS", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))  # an empty folder: no colcon on this PATH
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python3"))  # nor beside it
    monkeypatch.chdir(tmp_path)
    with pytest.raises(StepError) as err:
        runner(["colcon", "build"], step="colcon")
    assert err.value.returncode == 127
    assert err.value.message.startswith("command not found: colcon")
    assert err.value.message.endswith(HOST_EXTRA)


def test_in_an_image_and_for_other_programs_no_extra_hint(monkeypatch, tmp_path) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python3"))
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("DOCKER_ROS", "1")
    with pytest.raises(StepError) as err:
        run(["colcon", "build"], step="colcon")
    assert "[host]" not in err.value.message
    monkeypatch.delenv("DOCKER_ROS")
    with pytest.raises(StepError) as err:
        run(["apt-get", "update"], step="debs")
    assert "[host]" not in err.value.message
