"""ENABLE_LEAN_RUN_IMAGE on a real engine: the run image of the example plus a package with a
library of its own, a yaml-cpp dependency (declared as the -dev package rosdep names) and a
Python script importing a module its package only build-depends on. The run image must hold
the run-time packages (libyaml-cpp0.7, python3-psutil), none of the -dev ones, and still run
every node; a source edit must reuse its dependency layer."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Iterator

import pytest

from tests.docker.buildhelp import (
    cached_vertices,
    copy_example,
    docker_ros,
    own_copy,
    remove_image,
    run_unique,
    run_until,
    sh,
    write_env,
    write_files,
)

pytestmark = pytest.mark.docker
IMAGE = "docker-ros-test/lean:latest"
DEV_ONLY = ("libyaml-cpp-dev", "libroscpp-dev", "libboost1.74-dev", "libstdc++-12-dev",
            "libc6-dev")

FILES = {
    "lean_yaml/package.xml": """\
        <?xml version="1.0"?>
        <package format="3">
          <name>lean_yaml</name>
          <version>0.1.0</version>
          <description>lean run image test: own library, yaml-cpp, psutil</description>
          <maintainer email="tests@docker-ros.invalid">tests</maintainer>
          <license>MIT</license>
          <depend>lean_yaml_cpp</depend>
          <build_depend>lean_psutil</build_depend>
          <export><build_type>cmake</build_type></export>
        </package>
        """,
    "lean_yaml/CMakeLists.txt": """\
        cmake_minimum_required(VERSION 3.10)
        project(lean_yaml CXX)
        find_package(yaml-cpp REQUIRED)
        add_library(lean_greet SHARED src/greet.cpp)
        target_link_libraries(lean_greet yaml-cpp)
        add_executable(lean_yaml_node src/main.cpp)
        target_link_libraries(lean_yaml_node lean_greet)
        install(TARGETS lean_greet lean_yaml_node RUNTIME DESTINATION bin LIBRARY DESTINATION lib)
        install(PROGRAMS scripts/lean_cpus DESTINATION bin)
        """,
    "lean_yaml/src/greet.cpp": """\
        #include <iostream>
        #include <yaml-cpp/yaml.h>
        void greet() {
          std::cout << YAML::Load("greeting: lean yaml says hi")["greeting"].as<std::string>()
                    << std::endl;
        }
        """,
    "lean_yaml/src/main.cpp": "void greet();\nint main() { greet(); return 0; }\n",
    "lean_yaml/scripts/lean_cpus": """\
        #!/usr/bin/env python3
        import psutil
        print("lean psutil sees %d cpus" % psutil.cpu_count())
        """,
    "docker/rosdep.yaml": """\
        lean_yaml_cpp:
          debian: [libyaml-cpp-dev]
        lean_psutil:
          debian: [python3-psutil]
        """,
}


def lean_line(log: str, what: str) -> list:
    match = re.search(rf"lean: {what}: (.*)", log)
    assert match, log[-5000:]
    return match.group(1).split()


@pytest.fixture(scope="module")
def lean(ros1_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    project = copy_example(tmp_path_factory.mktemp("lean") / "ws")
    write_files(project, FILES)
    (project / "lean_yaml/scripts/lean_cpus").chmod(0o755)
    run_unique(project / "lean_yaml/src/main.cpp")  # the build below runs, in every run
    write_env(project, BASE_IMAGE=ros1_base_image, IMAGE=IMAGE, TARGET="run",
              COMMAND="roslaunch docker_ros_example talker_listener.launch",
              ENABLE_LEAN_RUN_IMAGE="true")
    built = docker_ros(project, "build")
    assert built.returncode == 0, built.stdout[-5000:]
    yield {"project": project, "log": built.stdout}
    remove_image(IMAGE)


def test_lean_run_image_has_the_run_time_packages_and_no_dev_ones(lean: dict) -> None:
    dropped = lean_line(lean["log"], "dropped")
    assert {"libyaml-cpp-dev", "libroscpp-dev", "libstd-msgs-dev"} <= set(dropped), dropped
    assert {"libyaml-cpp0.7", "libroscpp4d"} <= set(lean_line(lean["log"], "for libraries"))
    assert {"python3-psutil", "python3-rospy"} <= set(
        lean_line(lean["log"], "for Python modules"))
    query = sh(IMAGE, "dpkg-query -W -f '${Package} ${Status}\\n' "
               + " ".join(("libyaml-cpp0.7", "python3-psutil", "python3-rospy") + DEV_ONLY)
               + " 2>/dev/null | grep ' installed$' | cut -d' ' -f1")
    assert query.stdout.split() == ["libyaml-cpp0.7", "python3-psutil", "python3-rospy"], \
        query.stdout + query.stderr


def test_lean_run_image_runs_every_node(lean: dict) -> None:
    nodes = sh(IMAGE, "lean_yaml_node && lean_cpus")
    assert nodes.returncode == 0, nodes.stdout + nodes.stderr
    assert nodes.stdout.splitlines()[0] == "lean yaml says hi"
    assert re.match(r"lean psutil sees \d+ cpus", nodes.stdout.splitlines()[1])
    heard = run_until(IMAGE, "I heard: hello from docker-ros", 60)
    assert "I heard: hello from docker-ros" in heard, heard[-3000:]


def test_a_source_edit_reuses_the_lean_dependency_layer(lean: dict, tmp_path: Path) -> None:
    edited = f"{IMAGE}-edited"
    project = own_copy(lean["project"], tmp_path / "ws", edited)
    greet = project / "lean_yaml/src/greet.cpp"
    greet.write_text(greet.read_text().replace("says hi", "says hello"))
    try:
        rebuilt = docker_ros(project, "build")
        said = sh(edited, "lean_yaml_node").stdout.strip()
    finally:
        remove_image(edited)
    assert rebuilt.returncode == 0, rebuilt.stdout[-5000:]
    vertices = cached_vertices(rebuilt.stdout)
    stages = {name.split()[0][1:]: cached for name, cached in vertices.items()}
    lean_steps = {stage: stages.get(stage)
                  for stage in ("lean-resolve", "lean-resolution", "dependencies-run")}
    # the analysis runs again, finds the same packages: the install layer comes from cache
    assert lean_steps == {"lean-resolve": False, "lean-resolution": True,
                          "dependencies-run": True}, lean_steps
    assert said == "lean yaml says hello"
