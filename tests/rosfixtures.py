"""Reusable builders of real ROS test material: packages, git repositories, rosdep rules, .repos.

Pure helpers (no pytest): they write real files and run real git; tests import them."""

import base64
import hashlib
import os
import shutil
import socket
import subprocess
import textwrap
import threading
import time
import zipfile
from dataclasses import dataclass
from functools import partial
from http.server import BaseHTTPRequestHandler, SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Dict, Mapping, Optional, Sequence, Union

from tests.processes import stop

GIT_ENV = {
    "GIT_AUTHOR_NAME": "docker-ros tests",
    "GIT_AUTHOR_EMAIL": "tests@docker-ros.invalid",
    "GIT_COMMITTER_NAME": "docker-ros tests",
    "GIT_COMMITTER_EMAIL": "tests@docker-ros.invalid",
    "GIT_CONFIG_NOSYSTEM": "1",
}

DEFAULT_CPP = """\
#include <cstdio>
int main() {{ std::printf("{name}\\n"); return 0; }}
"""


def make_package(
    directory: Union[str, Path],
    name: str,
    *,
    depends: Sequence[str] = (),
    exec_depends: Sequence[str] = (),
    build_depends: Sequence[str] = (),
    test_depends: Sequence[str] = (),
    build_type: str = "cmake",
    cpp_source: Optional[str] = None,
    cmake_extra: str = "",
    package_format: int = 3,
) -> Path:
    """A package in `directory` (created): package.xml, and for build_type cmake a CMakeLists.txt
    with one executable `<name>_node` (from cpp_source) installed to bin/. colcon builds it
    without ROS. Dependencies that are workspace packages get find_package() calls."""
    path = Path(directory)
    path.mkdir(parents=True, exist_ok=True)
    tags = (
        [f"  <depend>{d}</depend>" for d in depends]
        + [f"  <build_depend>{d}</build_depend>" for d in build_depends]
        + [f"  <exec_depend>{d}</exec_depend>" for d in exec_depends]
        + [f"  <test_depend>{d}</test_depend>" for d in test_depends]
    )
    (path / "package.xml").write_text(
        f'<?xml version="1.0"?>\n<package format="{package_format}">\n'
        f"  <name>{name}</name>\n  <version>0.1.0</version>\n"
        f"  <description>{name} (docker-ros test package)</description>\n"
        '  <maintainer email="tests@docker-ros.invalid">tests</maintainer>\n'
        "  <license>MIT</license>\n"
        + "\n".join(tags)
        + f"\n  <export><build_type>{build_type}</build_type></export>\n</package>\n"
    )
    if build_type == "cmake":
        source = cpp_source if cpp_source is not None else DEFAULT_CPP.format(name=name)
        (path / "main.cpp").write_text(source)
        (path / "CMakeLists.txt").write_text(
            textwrap.dedent(
                f"""\
                cmake_minimum_required(VERSION 3.10)
                project({name} CXX)
                add_executable({name}_node main.cpp)
                install(TARGETS {name}_node DESTINATION bin)
                """
            )
            + cmake_extra
        )
    return path


def make_blacklist_repo(repo: Union[str, Path], rules: str) -> Path:
    """A repository with `app` (needing rosdep key my_tool), `unwanted` (blacklisted), `meta`
    (depending on unwanted) and the rosdep rules file docker/rosdep.yaml with `rules`."""
    repo = Path(repo)
    make_package(repo / "app", "app", depends=["my_tool"])
    make_package(repo / "unwanted", "unwanted")
    make_package(repo / "meta", "meta", exec_depends=["unwanted"])
    (repo / "docker").mkdir()
    (repo / "docker" / "blacklisted-packages.txt").write_text("unwanted\n")
    (repo / "docker" / "rosdep.yaml").write_text(rules)
    return repo


def git(args: Sequence[str], cwd: Union[str, Path]) -> str:
    env = {**os.environ, **GIT_ENV}
    return subprocess.run(
        ["git", *args], cwd=str(cwd), env=env, check=True, capture_output=True, text=True
    ).stdout


def make_git_repo(
    path: Union[str, Path],
    files: Mapping[str, Union[str, bytes]],
    bare_copy_to: Optional[Union[str, Path]] = None,
    *,
    branch: str = "main",
) -> str:
    """A real git repository at `path` with `files` committed on `branch`, and a bare clone
    (default: `<path>.git`) whose file:// URL is returned (what .repos files point to)."""
    work = Path(path)
    work.mkdir(parents=True, exist_ok=True)
    for name, content in files.items():
        target = work / name
        target.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            target.write_bytes(content)
        else:
            target.write_text(content)
    git(["init", "-q", "-b", branch], work)
    git(["add", "-A"], work)
    git(["commit", "-q", "--allow-empty", "-m", "initial"], work)
    bare = Path(bare_copy_to) if bare_copy_to else work.with_name(work.name + ".git")
    if bare.exists():
        shutil.rmtree(str(bare))
    git(["clone", "-q", "--bare", str(work), str(bare)], work.parent)
    return bare.resolve().as_uri()


def write_repos(path: Union[str, Path], repos: Mapping[str, Mapping[str, str]]) -> Path:
    """A vcstool .repos file: {name: {"url": ..., "version": ..., "type": "git"}}."""
    lines = ["repositories:"]
    for name, spec in repos.items():
        lines.append(f"  {name}:")
        lines.append(f"    type: {spec.get('type', 'git')}")
        lines.append(f"    url: {spec['url']}")
        if spec.get("version"):
            lines.append(f"    version: {spec['version']}")
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text("\n".join(lines) + "\n")
    return target


def _yaml_rule(value: object, indent: int) -> str:
    pad = " " * indent
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(str(v) for v in value) + "]"
    if isinstance(value, dict):
        return "".join(f"\n{pad}{k}: {_yaml_rule(v, indent + 2)}" for k, v in value.items())
    return str(value)


def write_rosdep_rules(directory: Union[str, Path], rules: Mapping[str, object]) -> Dict[str, str]:
    """An offline rosdep database in `directory`: rules.yaml, a sources list, an empty rosdistro
    index and a ROS_HOME. Returns the environment (merge into os.environ) with which
    `rosdep update` and then `rosdep resolve` work without network.

    rules: {"key": {"debian": ["pkg"]}} or pip rules {"key": {"debian": {"pip": {"packages":
    ["six"]}}}}; an OS map without versions applies to every version."""
    base = Path(directory).resolve()
    sources = base / "sources.list.d"
    sources.mkdir(parents=True, exist_ok=True)
    rules_file = base / "rules.yaml"
    rules_file.write_text("".join(f"{key}: {_yaml_rule(rule, 2)}\n" for key, rule in rules.items()))
    (sources / "10-docker-ros-tests.list").write_text(f"yaml {rules_file.as_uri()}\n")
    index = base / "index-v4.yaml"
    index.write_text("%YAML 1.1\n---\ntype: index\nversion: 4\ndistributions: {}\n")
    home = base / "ros_home"
    home.mkdir(exist_ok=True)
    return {
        "ROSDEP_SOURCE_PATH": str(sources),
        "ROS_HOME": str(home),
        "ROSDISTRO_INDEX_URL": index.as_uri(),
        "ROS_PYTHON_VERSION": "3",
    }


def rosdep_update(env: Mapping[str, str]) -> None:
    """`rosdep update` against the offline database of write_rosdep_rules."""
    subprocess.run(["rosdep", "update"], env={**os.environ, **env}, check=True, capture_output=True)


def tree_snapshot(root: Union[str, Path]) -> Dict[str, str]:
    """Every file, dir and symlink below root with its content hash / target (before/after)."""
    import hashlib

    out: Dict[str, str] = {}
    base = Path(root)
    for dirpath, dirnames, filenames in os.walk(str(base)):
        for name in sorted(dirnames + filenames):
            full = Path(dirpath) / name
            rel = str(full.relative_to(base))
            if full.is_symlink():
                out[rel] = "link:" + os.readlink(str(full))
            elif full.is_file():
                stat = full.stat()
                digest = hashlib.sha256(full.read_bytes()).hexdigest()
                out[rel] = f"file:{oct(stat.st_mode)}:{digest}"
            else:
                out[rel] = "dir"
    return out


def git_daemon(remotes: Path, port: int) -> subprocess.Popen:
    """`git daemon` serving the bare repositories in remotes at git://127.0.0.1:port/ (no
    login), once it answers for the first of them; the caller terminates it."""
    daemon = subprocess.Popen(["git", "daemon", "--reuseaddr", "--export-all",
                               f"--base-path={remotes}", "--listen=127.0.0.1", f"--port={port}",
                               str(remotes)])
    probe = f"git://127.0.0.1:{port}/{sorted(remotes.glob('*.git'))[0].name}"
    deadline = time.monotonic() + 10
    while subprocess.run(["git", "ls-remote", probe], capture_output=True).returncode != 0:
        assert time.monotonic() < deadline and daemon.poll() is None, "git daemon did not start"
        time.sleep(0.2)
    return daemon


def git_http_server(root: Union[str, Path], user: str, password: str) -> ThreadingHTTPServer:
    """A smart-HTTP git server (`git http-backend`) for the bare repositories in `root` on
    127.0.0.1:<free port>, Basic auth `user`/`password` required. Serves in a daemon thread;
    the caller ends it with `server.shutdown(); server.server_close()`."""
    expected = "Basic " + base64.b64encode(f"{user}:{password}".encode()).decode()

    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args: object) -> None:
            pass

        def do_GET(self) -> None:
            self.serve()

        def do_POST(self) -> None:
            self.serve()

        def serve(self) -> None:
            if self.headers.get("Authorization") != expected:
                self.send_response(401)
                self.send_header("WWW-Authenticate", 'Basic realm="git"')
                self.send_header("Content-Length", "0")
                self.end_headers()
                return
            path, _, query = self.path.partition("?")
            length = int(self.headers.get("Content-Length") or 0)
            body = self.rfile.read(length) if length else b""
            env = {
                "PATH": os.environ["PATH"],
                "GIT_PROJECT_ROOT": str(root),
                "GIT_HTTP_EXPORT_ALL": "1",
                "PATH_INFO": path,
                "QUERY_STRING": query,
                "REQUEST_METHOD": self.command,
                "CONTENT_TYPE": self.headers.get("Content-Type", ""),
                "CONTENT_LENGTH": str(len(body)),
                "HTTP_CONTENT_ENCODING": self.headers.get("Content-Encoding", ""),
                "GIT_PROTOCOL": self.headers.get("Git-Protocol", ""),
                "REMOTE_USER": user,
            }
            out = subprocess.run(
                ["git", "http-backend"], input=body, env=env, capture_output=True, check=True
            ).stdout
            sep = b"\r\n\r\n" if b"\r\n\r\n" in out else b"\n\n"
            head, _, payload = out.partition(sep)
            status, headers = 200, []
            for line in head.decode().splitlines():
                name, _, value = line.partition(":")
                if name.lower() == "status":
                    status = int(value.split()[0])
                elif name:
                    headers.append((name, value.strip()))
            self.send_response(status)
            for name, value in headers:
                self.send_header(name, value)
            self.send_header("Content-Length", str(len(payload)))
            self.end_headers()
            self.wfile.write(payload)

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def free_port(preferred: int = 0) -> int:
    """A free port of 127.0.0.1: preferred when it is free, else one the system picks."""
    with socket.socket() as probe:
        # (as a server binds: a port whose last connections are in TIME_WAIT is free)
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("127.0.0.1", preferred))
        except OSError:
            probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def ssh_keygen(path: Union[str, Path], comment: str = "docker-ros tests") -> str:
    """A new ed25519 key pair at `path` (private) and `path`.pub; returns the private key text."""
    key = Path(path)
    subprocess.run(
        ["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", comment, "-f", str(key)],
        check=True, capture_output=True,
    )
    return key.read_text()


@dataclass
class SshServer:
    """A running sshd (see sshd_server)."""

    proc: "subprocess.Popen[bytes]"
    port: int
    log: Path

    def stop(self) -> None:
        stop(self.proc, timeout=10)


def sshd_server(
    work: Union[str, Path], authorized_key: str, sshd: str = "/usr/sbin/sshd"
) -> SshServer:
    """Debian's OpenSSH server on 127.0.0.1:<free port>, in the foreground, with its own host
    key and config in `work`: public-key login only, as the user
    running it (root: `PermitRootLogin prohibit-password`), accepting `authorized_key` (a public
    key line). Git repositories are then served by absolute path:
    `ssh://root@127.0.0.1:<port>/abs/path/repo.git`. The caller terminates the process."""
    base = Path(work)
    base.mkdir(parents=True, exist_ok=True)
    host_key = base / "ssh_host_ed25519_key"
    ssh_keygen(host_key, "docker-ros tests host key")
    authorized = base / "authorized_keys"
    authorized.write_text(authorized_key.strip() + "\n")
    authorized.chmod(0o600)
    port = free_port()
    config = base / "sshd_config"
    config.write_text(
        f"ListenAddress 127.0.0.1:{port}\n"
        f"HostKey {host_key}\n"
        f"PidFile {base / 'sshd.pid'}\n"
        f"AuthorizedKeysFile {authorized}\n"
        "PermitRootLogin prohibit-password\n"
        "PubkeyAuthentication yes\n"
        "PasswordAuthentication no\n"
        "KbdInteractiveAuthentication no\n"
        "UsePAM no\n"
        # the temporary directories below /tmp are not what StrictModes accepts
        "StrictModes no\n"
        "LogLevel VERBOSE\n"
        "Subsystem sftp internal-sftp\n"
    )
    # Privilege separation directory: Debian creates it at boot (systemd), containers may not.
    Path("/run/sshd").mkdir(mode=0o755, exist_ok=True)
    log_path = base / "sshd.log"
    with log_path.open("wb") as log:
        proc = subprocess.Popen(
            [sshd, "-D", "-e", "-f", str(config), "-p", str(port)], stdout=log, stderr=log
        )
    server = SshServer(proc, port, log_path)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"sshd exited with {proc.returncode}: {log_path.read_text()}")
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", port)) == 0:
                return server
        time.sleep(0.05)
    server.stop()
    raise RuntimeError(f"sshd did not listen within 10 s: {log_path.read_text()}")


def make_wheel(directory: Union[str, Path], name: str, version: str) -> Path:
    """A real (pure-Python) wheel of a module `name` whose VERSION is `version`."""
    dist = f"{name}-{version}.dist-info"
    files = {
        f"{name}.py": f"VERSION = {version!r}\n",
        f"{dist}/METADATA": f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n",
        f"{dist}/WHEEL": "Wheel-Version: 1.0\nGenerator: docker-ros-tests\n"
                         "Root-Is-Purelib: true\nTag: py3-none-any\n",
    }
    record = []
    for path, text in files.items():
        digest = base64.urlsafe_b64encode(hashlib.sha256(text.encode()).digest()).rstrip(b"=")
        record.append(f"{path},sha256={digest.decode()},{len(text.encode())}")
    files[f"{dist}/RECORD"] = "\n".join(record + [f"{dist}/RECORD,,"]) + "\n"
    wheel = Path(directory) / f"{name}-{version}-py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w") as archive:
        for path, text in files.items():
            archive.writestr(path, text)
    return wheel


def file_http_server(root: Union[str, Path]) -> ThreadingHTTPServer:
    """Files of `root` (with directory listings: a pip --find-links page) on 127.0.0.1:<free
    port>, in a daemon thread; the caller ends it with `shutdown(); server_close()`."""

    class Quiet(SimpleHTTPRequestHandler):
        def log_message(self, *args: object) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), partial(Quiet, directory=str(root)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


ROS1_FILES = {
    "demo_msgs/package.xml": """<?xml version="1.0"?>
<package format="3">
  <name>demo_msgs</name>
  <version>0.1.0</version>
  <description>A message and a service (docker-ros test package)</description>
  <maintainer email="tests@docker-ros.invalid">tests</maintainer>
  <license>MIT</license>
  <buildtool_depend>catkin</buildtool_depend>
  <build_depend>message_generation</build_depend>
  <depend>std_msgs</depend>
  <exec_depend>message_runtime</exec_depend>
</package>
""",
    "demo_msgs/CMakeLists.txt": """cmake_minimum_required(VERSION 3.10)
project(demo_msgs)
find_package(catkin REQUIRED COMPONENTS message_generation std_msgs)
add_message_files(FILES Greeting.msg)
add_service_files(FILES AddTwo.srv)
generate_messages(DEPENDENCIES std_msgs)
catkin_package(CATKIN_DEPENDS message_runtime std_msgs)
""",
    "demo_msgs/msg/Greeting.msg": "std_msgs/Header header\nstring text\nint32 count\n",
    "demo_msgs/srv/AddTwo.srv": "int64 a\nint64 b\n---\nint64 sum\n",
    "demo_nodes/package.xml": """<?xml version="1.0"?>
<package format="3">
  <name>demo_nodes</name>
  <version>0.1.0</version>
  <description>Nodes, a rostest and a gtest (docker-ros test package)</description>
  <maintainer email="tests@docker-ros.invalid">tests</maintainer>
  <license>MIT</license>
  <buildtool_depend>catkin</buildtool_depend>
  <depend>roscpp</depend>
  <depend>demo_msgs</depend>
  <exec_depend>rospy</exec_depend>
  <exec_depend>roslaunch</exec_depend>
  <test_depend>rostest</test_depend>
  <test_depend>rosunit</test_depend>
</package>
""",
    "demo_nodes/CMakeLists.txt": """cmake_minimum_required(VERSION 3.10)
project(demo_nodes)
find_package(catkin REQUIRED COMPONENTS roscpp demo_msgs)
catkin_package()
include_directories(${catkin_INCLUDE_DIRS})
add_executable(talker src/talker.cpp)
target_link_libraries(talker ${catkin_LIBRARIES})
add_dependencies(talker ${catkin_EXPORTED_TARGETS})
catkin_install_python(PROGRAMS scripts/listener.py
  DESTINATION ${CATKIN_PACKAGE_BIN_DESTINATION})
install(TARGETS talker RUNTIME DESTINATION ${CATKIN_PACKAGE_BIN_DESTINATION})
install(DIRECTORY launch config DESTINATION ${CATKIN_PACKAGE_SHARE_DESTINATION})
if(CATKIN_ENABLE_TESTING)
  find_package(rostest REQUIRED)
  add_rostest(test/demo.test)
  catkin_add_gtest(utils_test test/utils_test.cpp)
endif()
""",
    "demo_nodes/src/talker.cpp": """#include <ros/ros.h>
#include <demo_msgs/AddTwo.h>
#include <demo_msgs/Greeting.h>

bool add(demo_msgs::AddTwo::Request& req, demo_msgs::AddTwo::Response& res) {
  res.sum = req.a + req.b;
  return true;
}

int main(int argc, char** argv) {
  ros::init(argc, argv, "talker");
  ros::NodeHandle nh;
  ros::NodeHandle pnh("~");
  std::string text;
  pnh.param<std::string>("text", text, "hello");
  ros::Publisher pub = nh.advertise<demo_msgs::Greeting>("greeting", 10);
  ros::ServiceServer srv = nh.advertiseService("add_two", add);
  ros::Rate rate(5);
  for (int count = 0; ros::ok(); ++count) {
    demo_msgs::Greeting msg;
    msg.header.stamp = ros::Time::now();
    msg.text = text;
    msg.count = count;
    pub.publish(msg);
    ros::spinOnce();
    rate.sleep();
  }
  return 0;
}
""",
    "demo_nodes/scripts/listener.py": """#!/usr/bin/env python3
import rospy
from demo_msgs.msg import Greeting
from demo_msgs.srv import AddTwo


def heard(msg):
    rospy.loginfo("heard: %s #%d", msg.text, msg.count)


if __name__ == "__main__":
    rospy.init_node("listener")
    rospy.Subscriber("greeting", Greeting, heard)
    rospy.wait_for_service("add_two")
    rospy.loginfo("sum: %d", rospy.ServiceProxy("add_two", AddTwo)(2, 3).sum)
    rospy.spin()
""",
    "demo_nodes/launch/demo.launch": """<launch>
  <node pkg="demo_nodes" type="talker" name="talker" output="screen">
    <rosparam command="load" file="$(find demo_nodes)/config/params.yaml"/>
  </node>
  <node pkg="demo_nodes" type="listener.py" name="listener" output="screen"/>
</launch>
""",
    "demo_nodes/config/params.yaml": 'text: "hello from yaml"\n',
    "demo_nodes/test/demo.test": """<launch>
  <node pkg="demo_nodes" type="talker" name="talker"/>
  <test test-name="greeting_test" pkg="demo_nodes" type="greeting_test.py" time-limit="60"/>
</launch>
""",
    "demo_nodes/test/greeting_test.py": """#!/usr/bin/env python3
import unittest

import rospy
import rostest
from demo_msgs.msg import Greeting
from demo_msgs.srv import AddTwo


class GreetingTest(unittest.TestCase):
    def test_greeting_arrives(self):
        msg = rospy.wait_for_message("greeting", Greeting, timeout=30)
        self.assertTrue(msg.text.startswith("hello"))

    def test_add_two(self):
        rospy.wait_for_service("add_two", timeout=30)
        self.assertEqual(rospy.ServiceProxy("add_two", AddTwo)(2, 3).sum, 5)


if __name__ == "__main__":
    rospy.init_node("greeting_test")
    rostest.rosrun("demo_nodes", "greeting_test", GreetingTest)
""",
    "demo_nodes/test/utils_test.cpp": """#include <gtest/gtest.h>
TEST(Utils, Adds) { EXPECT_EQ(2 + 3, 5); }
TEST(Utils, Multiplies) { EXPECT_EQ(2 * 3, 6); }
int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
""",
}
ROS1_EXECUTABLES = ("demo_nodes/scripts/listener.py", "demo_nodes/test/greeting_test.py")


def make_ros1_repo(repo: Union[str, Path], *, failing: bool = False) -> Path:
    """A typical ROS 1 (catkin) repository: demo_msgs (a message and a service,
    message_generation) and demo_nodes (a C++ talker publishing /greeting and serving
    /add_two, a Python listener installed with catkin_install_python, demo.launch loading
    config/params.yaml, a rostest of two Python unittest cases and a gtest of two cases).
    failing: one case of each test fails (GreetingTest.test_add_two, Utils.Multiplies)."""
    repo = Path(repo)
    for name, text in ROS1_FILES.items():
        if failing:
            text = text.replace("(2, 3).sum, 5)", "(2, 3).sum, 6)")
            text = text.replace("EXPECT_EQ(2 * 3, 6)", "EXPECT_EQ(2 * 3, 7)")
        target = repo / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(text)
    for name in ROS1_EXECUTABLES:
        (repo / name).chmod(0o755)
    return repo


ROS2_PYTHON_FILES = {
    "demo_interfaces/package.xml": """<?xml version="1.0"?>
<package format="3">
  <name>demo_interfaces</name>
  <version>0.1.0</version>
  <description>A message and a service (docker-ros test package)</description>
  <maintainer email="tests@docker-ros.invalid">tests</maintainer>
  <license>MIT</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_cmake</buildtool_depend>
  <buildtool_depend>rosidl_generator_c</buildtool_depend>
  <buildtool_depend>rosidl_generator_cpp</buildtool_depend>
  <depend>rosidl_runtime_c</depend>
  <depend>rosidl_runtime_cpp</depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
""",
    # Debian has no rosidl_default_generators: its C/C++ generators are named one by one
    "demo_interfaces/CMakeLists.txt": """cmake_minimum_required(VERSION 3.10)
project(demo_interfaces)
find_package(ament_cmake REQUIRED)
find_package(rosidl_cmake REQUIRED)
find_package(rosidl_generator_c REQUIRED)
find_package(rosidl_generator_cpp REQUIRED)
rosidl_generate_interfaces(${PROJECT_NAME} "msg/Greeting.msg" "srv/AddTwo.srv")
ament_package()
""",
    "demo_interfaces/msg/Greeting.msg": "string text\nint32 count\n",
    "demo_interfaces/srv/AddTwo.srv": "int64 a\nint64 b\n---\nint64 sum\n",
    "demo_py/package.xml": """<?xml version="1.0"?>
<package format="3">
  <name>demo_py</name>
  <version>0.1.0</version>
  <description>Python nodes (docker-ros test package)</description>
  <maintainer email="tests@docker-ros.invalid">tests</maintainer>
  <license>MIT</license>
  <exec_depend>ament_index_python</exec_depend>
  <exec_depend>demo_interfaces</exec_depend>
  <exec_depend>python3-yaml</exec_depend>
  <test_depend>ament_flake8</test_depend>
  <test_depend>ament_pep257</test_depend>
  <test_depend>python3-pytest</test_depend>
  <export><build_type>ament_python</build_type></export>
</package>
""",
    "demo_py/resource/demo_py": "",
    "demo_py/setup.cfg": """[develop]
script_dir=$base/lib/demo_py
[install]
install_scripts=$base/lib/demo_py
""",
    "demo_py/setup.py": """from glob import glob

from setuptools import setup

package_name = "demo_py"

setup(
    name=package_name,
    version="0.1.0",
    packages=[package_name],
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/launch", glob("launch/*")),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="tests",
    maintainer_email="tests@docker-ros.invalid",
    description="Python nodes",
    license="MIT",
    extras_require={"test": ["pytest"]},
    entry_points={"console_scripts": ["talker = demo_py.talker:main"]},
)
""",
    "demo_py/demo_py/__init__.py": "",
    "demo_py/demo_py/util.py": '''"""Helpers."""


def add(a, b):
    """Add two numbers."""
    return a + b
''',
    # no rclpy (Debian has none): prints the installed params file's greeting, a message field
    # name, then a sum by a module imported late (as in a timer callback)
    "demo_py/demo_py/talker.py": '''"""A talker."""
import os
import time

import yaml
from ament_index_python.packages import get_package_share_directory


def main():
    """Greet, wait, import late, stay up."""
    with open(os.path.join(get_package_share_directory("demo_py"), "config",
                           "params.yaml")) as f:
        print("greeting:", yaml.safe_load(f)["text"], flush=True)
    msg = os.path.join(get_package_share_directory("demo_interfaces"), "msg", "Greeting.msg")
    with open(msg) as f:
        print("field:", f.read().split()[1], flush=True)
    time.sleep(float(os.environ.get("LATE_AFTER", "5")))
    from demo_py import util
    print("late sum:", util.add(2, 3), flush=True)
    while True:
        time.sleep(1)
''',
    "demo_py/config/params.yaml": 'text: "hello from yaml"\n',
    "demo_py/launch/demo.launch.py": """from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description():
    return LaunchDescription([Node(package="demo_py", executable="talker", output="screen")])
""",
    "demo_py/launch/demo.launch.xml": """<launch>
  <node pkg="demo_py" exec="talker" output="screen"/>
</launch>
""",
    "demo_py/test/test_util.py": """from demo_py.util import add


def test_add():
    assert add(2, 3) == 5
""",
    "demo_py/test/test_flake8.py": """import pytest
from ament_flake8.main import main_with_errors


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8():
    rc, errors = main_with_errors(argv=[])
    assert rc == 0, "Found %d code style errors / warnings:\\n" % len(errors) + "\\n".join(errors)
""",
    "demo_py/test/test_pep257.py": """import pytest
from ament_pep257.main import main


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257():
    assert main(argv=[".", "test"]) == 0, "Found code style errors / warnings"
""",
    # Debian's rosdep rules have no Python keys
    "docker/rosdep.yaml": """python3-yaml:
  debian: [python3-yaml]
python3-pytest:
  debian: [python3-pytest]
""",
}


def make_ros2_python_repo(repo: Union[str, Path]) -> Path:
    """A typical ROS 2 Python repository for the Debian ROS 2 base (no rclpy, launch or ros2
    CLI there): demo_interfaces (ament_cmake, a message and a service, rosidl's C/C++
    generators) and demo_py (ament_python: setup.py/setup.cfg, resource marker, a console
    script `talker` installed to lib/demo_py, a Python and an XML launch file and
    config/params.yaml installed as data_files, pytest tests of its own and the flake8/pep257
    ament linters as pytest cases), with docker/rosdep.yaml for the Python keys."""
    repo = Path(repo)
    for name, text in ROS2_PYTHON_FILES.items():
        target = repo / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(text)
    return repo
