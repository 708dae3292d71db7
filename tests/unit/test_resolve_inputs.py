"""The source stage's copies (runtime/inputs.py): the files resolving reads, and the ignore
markers alone, which the dev image's sources get (without ADDITIONAL_FILES_DIR's files)."""

from __future__ import annotations

from docker_ros.core.loading import load_settings
from docker_ros.in_image.runtime.inputs import copy_inputs_and_markers
from docker_ros.in_image.runtime.workspace import Workspace


def test_markers_are_copied_alone_and_the_inputs_with_the_additional_files(tmp_path):
    ws = Workspace(str(tmp_path / "ws"))
    for name in ("kept", "blacklisted"):
        (ws.target / name / "src").mkdir(parents=True)
        (ws.target / name / "package.xml").write_text(f"<package><name>{name}</name></package>")
        (ws.target / name / "src" / "main.cpp").write_text("int main() {}\n")
    (ws.target / "blacklisted" / "COLCON_IGNORE").write_text("")
    (ws.src / "upstream" / "lib").mkdir(parents=True)
    (ws.src / "upstream" / "lib" / "package.xml").write_text("<package><name>lib</name></package>")
    (ws.src / "upstream" / "lib" / "CATKIN_IGNORE").write_text("")
    (ws.target / "docker" / "additional-files").mkdir(parents=True)
    (ws.target / "docker" / "additional-files" / "map.yaml").write_text("image: map.pgm\n")
    settings = load_settings(environ={"BASE_IMAGE": "b:1", "COMMAND": "c"},
                             project_dir=ws.target)
    copy_inputs_and_markers(ws, settings, tmp_path / "inputs", tmp_path / "markers")

    def below(folder):
        return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())

    assert below(tmp_path / "markers") == ["src/target/blacklisted/COLCON_IGNORE",
                                           "src/upstream/lib/CATKIN_IGNORE"]
    assert below(tmp_path / "inputs") == [
        "src/target/blacklisted/COLCON_IGNORE", "src/target/blacklisted/package.xml",
        "src/target/docker/additional-files/map.yaml", "src/target/kept/package.xml",
        "src/upstream/lib/CATKIN_IGNORE", "src/upstream/lib/package.xml"]


def test_markers_folder_exists_without_markers(tmp_path):
    ws = Workspace(str(tmp_path / "ws"))
    ws.target.mkdir(parents=True)
    settings = load_settings(environ={"BASE_IMAGE": "b:1", "COMMAND": "c"},
                             project_dir=ws.target)
    copy_inputs_and_markers(ws, settings, tmp_path / "inputs", tmp_path / "markers")
    assert (tmp_path / "markers" / "src" / "target").is_dir()  # (the marked stage COPYs src/)
