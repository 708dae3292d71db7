"""invoke's configuration files checked before invoke reads them (cli/program.py): each file it
would fail on with a traceback is one line; a good one is none."""

from pathlib import Path

import pytest

from docker_ros.cli.program import config_file_problem, config_files, tasks_folder


@pytest.mark.parametrize("text, problem", [
    (b"docker_ros:\n  image_tag: v1\n", None),
    (b"", None),
    (b"docker_ros: [1, 2\n", "docker-ros: SHOWN (line 2) is not valid YAML: expected ',' or ']', "
                             "but got '<stream end>': fix or remove it"),
    (b"- just\n", "docker-ros: invoke.yaml: the top level must be a mapping (key docker_ros:)"),
    (b"docker_ros:\n  image_tag: a\n  IMAGE_TAG: b\n",
     "docker-ros: invoke.yaml: image_tag is given twice under docker_ros: (keys that differ in "
     "case only, as image_tag and IMAGE_TAG, are one setting): keep one"),
    ("# café\n".encode("latin-1"), "docker-ros: SHOWN is not UTF-8 text (invalid continuation "
                                   "byte at byte 5): save it as UTF-8"),
])
def test_a_file_invoke_would_fail_on_is_one_line(tmp_path: Path, text: bytes, problem) -> None:
    path = tmp_path / "invoke.yaml"
    path.write_bytes(text)
    assert config_file_problem(path, "SHOWN") == problem


def test_the_project_file_is_the_first_of_its_suffixes_beside_tasks_py(tmp_path: Path) -> None:
    (tmp_path / "tasks.py").write_text("")
    (tmp_path / "sub").mkdir()
    assert tasks_folder(tmp_path / "sub") == tmp_path
    (tmp_path / "invoke.yml").write_text("")
    (tmp_path / "invoke.json").write_text("{}")
    assert config_files(tmp_path, base=False) == [tmp_path / "invoke.yml"]
