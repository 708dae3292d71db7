"""A base image laid out as the official ones are (`ros:noetic`, `rwthika/ros2:*`): ROS in
/opt/ros/$ROS_DISTRO with catkin's setup files, ROS_DISTRO set, and in there a package of the
base that no rosdep rule knows (a company's own, built into its base image). The example's
talker includes its header. So the build must source /opt/ros/noetic/setup.bash (CMake finds the
package), rosdep must take the package as installed, as docker-ros's `rosdep install
--ignore-src` with that setup sourced does (before: "no rosdep rule for 'opt_hello'"), and the
run image must start with it sourced. (The other image tests' bases have Debian's ROS in /usr:
no setup file, no ROS_DISTRO.)"""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Iterator

import pytest

from tests.docker.buildhelp import (
    copy_example,
    docker_ros,
    remove_image,
    run_until,
    sh,
    write_env,
    write_files,
)

pytestmark = pytest.mark.docker

BASE = "docker-ros-test/opt-ros:noetic"
IMAGE = "docker-ros-test/opt-ros-example:1"
UNDERLAY = {
    "opt_hello/package.xml": """\
        <?xml version="1.0"?>
        <package format="3">
          <name>opt_hello</name>
          <version>0.1.0</version>
          <description>a package of the base image, in /opt/ros/noetic as ROS's own</description>
          <maintainer email="tests@docker-ros.invalid">tests</maintainer>
          <license>MIT</license>
          <buildtool_depend>catkin</buildtool_depend>
        </package>
        """,
    "opt_hello/CMakeLists.txt": """\
        cmake_minimum_required(VERSION 3.10)
        project(opt_hello)
        find_package(catkin REQUIRED)
        catkin_package(INCLUDE_DIRS include)
        install(DIRECTORY include/${PROJECT_NAME}/
                DESTINATION ${CATKIN_PACKAGE_INCLUDE_DESTINATION})
        """,
    "opt_hello/include/opt_hello/hello.h": """\
        #pragma once
        #define OPT_HELLO_GREETING "hello from /opt/ros"
        """,
    # catkin's setup files in the install prefix, as in ROS's own packages of /opt/ros/noetic
    "Dockerfile": """\
        ARG BASE
        FROM ${BASE} AS build
        RUN apt-get update && apt-get install -y --no-install-recommends build-essential
        COPY opt_hello /tmp/src/opt_hello
        RUN cmake -S /tmp/src/opt_hello -B /tmp/build -DCMAKE_INSTALL_PREFIX=/opt/ros/noetic && \\
            cmake --build /tmp/build --target install
        FROM ${BASE}
        COPY --from=build /opt/ros /opt/ros
        ENV ROS_DISTRO=noetic
        """,
}


def uses_opt_hello(package: Path) -> None:
    """The example's talker sends the underlay's greeting (its header, found through catkin)."""
    cmake = package / "CMakeLists.txt"
    cmake.write_text(cmake.read_text().replace("COMPONENTS roscpp std_msgs)",
                                               "COMPONENTS roscpp std_msgs opt_hello)"))
    manifest = package / "package.xml"
    depend = "  <depend>std_msgs</depend>\n"
    manifest.write_text(manifest.read_text().replace(
        depend, depend + "  <depend>opt_hello</depend>\n"))
    talker = package / "src" / "talker.cpp"
    talker.write_text("#include <opt_hello/hello.h>\n" + talker.read_text().replace(
        'msg.data = "hello from docker-ros "', 'msg.data = std::string(OPT_HELLO_GREETING) + " "'))


@pytest.fixture(scope="module")
def built(ros1_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    root = tmp_path_factory.mktemp("opt-ros")
    write_files(root / "base", UNDERLAY)
    made = subprocess.run(["docker", "buildx", "build", "--load", "--build-arg",
                           f"BASE={ros1_base_image}", "--tag", BASE, str(root / "base")],
                          capture_output=True, text=True, timeout=900)
    assert made.returncode == 0, made.stderr[-3000:]
    project = copy_example(root / "example")
    uses_opt_hello(project / "docker_ros_example")
    write_env(project, BASE_IMAGE=BASE, IMAGE=IMAGE, TARGET="dev,run",
              COMMAND="roslaunch docker_ros_example talker_listener.launch")
    result = docker_ros(project, "build")
    assert result.returncode == 0, result.stdout[-5000:]
    yield
    for ref in (IMAGE, f"{IMAGE}-dev", BASE):
        remove_image(ref)


def test_a_package_of_the_base_images_ros_is_installed_not_a_rosdep_key(built: None) -> None:
    """The rosdep step's record in the dev image (its log line is not shown when BuildKit takes
    the step from its cache): the example's other keys, opt_hello not."""
    origins = sh(f"{IMAGE}-dev", "cat /docker-ros/ws/.docker-ros/rosdep-origins.json").stdout
    assert "rosdep key std_msgs of docker_ros_example" in origins, origins
    assert "opt_hello" not in origins, origins


def test_the_run_image_runs_with_the_opt_ros_setup_sourced(built: None) -> None:
    out = run_until(IMAGE, "I heard: hello from /opt/ros", 60)
    assert "I heard: hello from /opt/ros" in out, out[-3000:]
