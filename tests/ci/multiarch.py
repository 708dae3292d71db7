"""The multi-arch modules' workspace (test_multiarch, test_multiarch_builder): one Python catkin
package whose talker says the machine it runs on, as a git repository built FROM the ROS 1 base
and its arm64 sibling. The two modules are apart so that their slow parts, each waiting first
for the emulated arm64 base, run side by side on two of the suite's processes."""

from __future__ import annotations

import platform
import subprocess
from pathlib import Path

import pytest

from tests.ci.cihelp import example_repository
from tests.docker.buildhelp import remove_image, write_files

IMAGE = "docker-ros-test/multiarch"
COMMAND = "roslaunch tiny_chat chat.launch"
HEARD = "tiny_chat heard: hello from"
FILES = {
    "tiny_chat/package.xml": """\
        <?xml version="1.0"?>
        <package format="3">
          <name>tiny_chat</name>
          <version>0.1.0</version>
          <description>multi-arch test: a Python talker and listener (ROS 1)</description>
          <maintainer email="tests@docker-ros.invalid">tests</maintainer>
          <license>MIT</license>
          <buildtool_depend>catkin</buildtool_depend>
          <exec_depend>rospy</exec_depend>
          <exec_depend>std_msgs</exec_depend>
          <exec_depend>roslaunch</exec_depend>
        </package>
        """,
    "tiny_chat/CMakeLists.txt": """\
        cmake_minimum_required(VERSION 3.10)
        project(tiny_chat)
        find_package(catkin REQUIRED)
        catkin_package()
        catkin_install_python(PROGRAMS scripts/talker.py scripts/listener.py
          DESTINATION ${CATKIN_PACKAGE_BIN_DESTINATION})
        install(DIRECTORY launch DESTINATION ${CATKIN_PACKAGE_SHARE_DESTINATION})
        """,
    "tiny_chat/scripts/talker.py": """\
        #!/usr/bin/env python3
        import platform
        import rospy
        from std_msgs.msg import String
        rospy.init_node("talker")
        pub = rospy.Publisher("chat", String, queue_size=10)
        rate = rospy.Rate(5)
        while not rospy.is_shutdown():
            pub.publish("hello from " + platform.machine())
            rate.sleep()
        """,
    "tiny_chat/scripts/listener.py": """\
        #!/usr/bin/env python3
        import rospy
        from std_msgs.msg import String
        rospy.init_node("listener")
        rospy.Subscriber("chat", String, lambda m: print("tiny_chat heard: " + m.data, flush=True))
        rospy.spin()
        """,
    # A Python node needs std_msgs' Python module, which the base has; Debian's rosdep rule
    # also installs its C++ headers and the roscpp -dev chain they pull in: under QEMU, three
    # minutes of every emulated build. The repository's own rule (ROSDEP_RULES_FILE's default
    # place) is what a user of Python nodes writes for a small run image.
    "docker/rosdep.yaml": """\
        std_msgs:
          debian: [python3-std-msgs]
        """,
    "tiny_chat/launch/chat.launch": """\
        <launch>
          <node pkg="tiny_chat" type="talker.py" name="talker" output="screen"/>
          <node pkg="tiny_chat" type="listener.py" name="listener" output="screen"/>
        </launch>
        """,
}



def tiny_workspace(root: Path) -> Path:
    for path in write_files(root, FILES):
        if path.suffix == ".py":
            path.chmod(0o755)
    return root


@pytest.fixture(scope="module")
def repository(ros1_base_image: str, ros1_arm64_base_image: str,
               tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny workspace as a git repository; BASE_IMAGE names the amd64 base, whose arm64
    image bootstrap tagged `<BASE_IMAGE>-arm64`."""
    assert ros1_arm64_base_image == f"{ros1_base_image}-arm64"
    root = tmp_path_factory.mktemp("multiarch")
    source = tiny_workspace(root / "source")
    return example_repository(root, ros1_base_image, source=source, command=COMMAND)


def host_arch() -> str:
    return {"x86_64": "amd64", "aarch64": "arm64"}[platform.machine()]


def pulled_architecture(ref: str, platform: str) -> str:
    """Pull ref's image of platform afresh from the registry; its architecture."""
    remove_image(ref)
    subprocess.run(["docker", "pull", "-q", "--platform", f"linux/{platform}", ref],
                   check=True, capture_output=True)
    return subprocess.run(["docker", "image", "inspect", "-f", "{{.Architecture}}", ref],
                          check=True, capture_output=True, text=True).stdout.strip()


