"""COMMAND's check in the run image's build (runtime/launch.py): which words it reads, and how
it finds packages, executables and launch files, on real folders laid out as colcon, ament and
catkin install them."""

from pathlib import Path

import pytest

from docker_ros.in_image.runtime.launch import (
    command_problems,
    launcher,
    package_dirs,
    simple_commands,
)


@pytest.mark.parametrize("command, expected", [
    ("talker", [["talker"]]),
    ("FOO=1 exec ros2 run pkg node --ros-args -r a:=b",
     [["ros2", "run", "pkg", "node", "--ros-args", "-r", "a:=b"]]),
    ("a && b || c; d | e &", [["a"], ["b"], ["c"], ["d"], ["e"]]),
    ("a 2>&1 >/tmp/log && b", [["a", "2"], ["b"]]),
    ("a 'x && y'", [["a", "x && y"]]),
    # what runs after something that may change the environment is not checked
    ("a && source /ws/setup.bash && b", [["a"]]),
    ("cd /data; b", []),
    ("PATH=/x:$PATH b", []),
    ("X=1; b", []),
    ("if true; then b; fi", []),
    ("$PROGRAM --flag", []),
    ("(b)", []),
    ("a 'unclosed", []),
    ("a\nb", [["a"], ["b"]]),
])
def test_simple_commands_stop_where_the_shell_decides_at_run_time(command, expected):
    assert simple_commands(command) == expected


@pytest.mark.parametrize("words, expected", [
    ("ros2 run pkg node", ("ros2 run", ["pkg", "node"])),
    ("ros2 run --prefix 'gdb -ex run' pkg node", ("ros2 run", ["pkg", "node"])),
    ("ros2 launch -d pkg a.launch.py x:=1", ("ros2 launch", ["pkg", "a.launch.py"])),
    ("ros2 launch /cfg/a.launch.py x:=1", ("ros2 launch", ["/cfg/a.launch.py"])),
    ("roslaunch --wait -p 11312 pkg a.launch", ("roslaunch", ["pkg", "a.launch"])),
    ("roslaunch --port=11312 pkg a.launch", ("roslaunch", ["pkg", "a.launch"])),
    ("rosrun pkg node _param:=1", ("rosrun", ["pkg", "node"])),
    ("ros2 run --unknown-option pkg node", None),
    ("ros2 run $PKG node", None),
    ("ros2 topic list", None),
    ("python3 -m x", None),
])
def test_launcher_reads_the_package_and_file_words(words, expected):
    assert launcher(simple_commands(words)[0]) == expected


def make(path: Path, *, executable: bool = False) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("x")
    path.chmod(0o755 if executable else 0o644)


@pytest.fixture
def ros2_env(tmp_path):
    """An isolated colcon install space of ROS 2 package talk (an executable, a launch file,
    a data file that is not executable)."""
    prefix = tmp_path / "install/talk"
    make(prefix / "share/ament_index/resource_index/packages/talk")
    make(prefix / "lib/talk/talker", executable=True)
    make(prefix / "lib/talk/notes.txt")
    make(prefix / "share/talk/launch/both.launch.py")
    return {"AMENT_PREFIX_PATH": f"{prefix}:{tmp_path / 'missing'}"}


@pytest.fixture
def ros1_env(tmp_path):
    """A merged catkin install space of ROS 1 package chat (launch file in share, node in lib)."""
    prefix = tmp_path / "install"
    make(prefix / "share/chat/package.xml")
    make(prefix / "share/chat/launch/chat.launch")
    make(prefix / "lib/chat/chatter", executable=True)
    return {"CMAKE_PREFIX_PATH": str(prefix), "ROS_PACKAGE_PATH": str(prefix / "share")}


FOUND = ["ros2", "rosrun", "roslaunch"]


@pytest.mark.parametrize("command", [
    "ros2 run talk talker",
    "ros2 launch talk both.launch.py use_sim_time:=true",
    "ros2 launch talk launch/both.launch.py",
    "ros2 launch /volume/both.launch.py",
    "ros2 run --prefix 'valgrind' talk talker --ros-args -p a:=1",
    "/volume/start.sh --now",
])
def test_what_is_installed_passes_ros2(command, ros2_env):
    assert command_problems(command, ros2_env, FOUND) == []


@pytest.mark.parametrize("command, problem", [
    ("ros2 run no_such_pkg talker", "package no_such_pkg is not in the run image"),
    ("ros2 run talk listener", "package talk has no executable listener"),
    ("ros2 run talk notes.txt", "package talk has no executable notes.txt"),
    ("ros2 launch talk missing.launch.py", "package talk has no launch file missing.launch.py"),
    ("ros2 launch talk both.launch.py/x", "package talk has no launch file both.launch.py/x"),
    ("ros2run talk talker", "`ros2run` is not a program on PATH"),
    # a name close to an installed one: that one is named
    ("ros2 launch talk bth.launch.py", "bth.launch.py; did you mean both.launch.py? (looked"),
    ("ros2 launch talk launch/both.lauch.py", ".lauch.py; did you mean both.launch.py? (looked"),
    ("ros2 run talk talkr", "talkr; did you mean talker? (looked in"),
    ("ros2 run talk note.txt", "note.txt (looked in"),  # not executable: not a candidate
    ("ros2 launch talk zzz", "zzz (looked in"),
    ("ros2 run tlak talker", "installed; did you mean talk? (check the name"),
    ("ros2 run zzz talker", "installed (check the name"),
])
def test_what_is_missing_is_named_ros2(command, problem, ros2_env):
    problems = command_problems(command, ros2_env, FOUND)
    assert len(problems) == 1 and problem in problems[0], problems


@pytest.mark.parametrize("command, problem", [
    ("roslaunch chat chat.launch", ""),
    ("rosrun chat chatter", ""),
    ("roslaunch no_such_pkg x.launch", "package no_such_pkg is not in the run image"),
    ("roslaunch chat other.launch", "package chat has no launch file other.launch"),
    ("rosrun chat chat.launch", "package chat has no executable chat.launch"),
])
def test_ros1_packages_and_files(command, problem, ros1_env):
    problems = command_problems(command, ros1_env, FOUND)
    assert (problem in problems[0]) if problem else problems == [], problems


def test_a_ros1_package_close_to_an_installed_one_is_suggested(ros1_env, tmp_path):
    make(tmp_path / "src/listener/package.xml")
    env = {**ros1_env, "ROS_PACKAGE_PATH": f"{ros1_env['ROS_PACKAGE_PATH']}:{tmp_path / 'src'}"}
    for command, close in (("roslaunch chta chat.launch", "chat"),
                           ("rosrun listner listener", "listener")):
        problems = command_problems(command, env, FOUND)
        assert len(problems) == 1 and f"installed; did you mean {close}? (" in problems[0]


def test_ros1_package_found_by_its_folder_in_ros_package_path(tmp_path):
    make(tmp_path / "src/chat/package.xml")
    make(tmp_path / "src/chat/launch/chat.launch")
    env = {"ROS_PACKAGE_PATH": str(tmp_path / "src")}
    assert package_dirs("chat", env, ros2=False) == (tmp_path / "src/chat",) * 2
    assert command_problems("roslaunch chat chat.launch", env, FOUND) == []


def test_ros1_isolated_install_found_through_ros_package_path(tmp_path):
    """colcon's isolated install of a catkin package, found as ROS_PACKAGE_PATH's share folder:
    rosrun looks in its lib/<package> and share/<package>, not in the whole prefix."""
    prefix = tmp_path / "install/chat"
    make(prefix / "share/chat/package.xml")
    make(prefix / "lib/chat/chatter", executable=True)
    make(prefix / "bin/elsewhere", executable=True)
    env = {"ROS_PACKAGE_PATH": str(prefix / "share")}
    assert package_dirs("chat", env, ros2=False) == (prefix / "share/chat", prefix / "lib/chat")
    assert command_problems("rosrun chat chatter", env, FOUND) == []
    assert "has no executable elsewhere" in command_problems("rosrun chat elsewhere", env,
                                                             FOUND)[0]


def test_a_package_executable_given_as_a_program_is_named_with_how_to_start_it(ros2_env):
    """COMMAND=talker (an ament_python console script, installed to lib/<package>, not on
    PATH): the check names the package and both ways to start it."""
    talker = Path(ros2_env["AMENT_PREFIX_PATH"].split(":")[0]) / "lib/talk/talker"
    assert command_problems("talker --ros-args -p a:=1", ros2_env, FOUND) == [
        "`talker` is not a program on PATH in the run image: it is an executable of package "
        f"talk; start it with `ros2 run talk talker` or its path {talker}"]
    # without the ros2 command: its path only
    assert command_problems("talker", ros2_env, ["rosrun"])[0].endswith(
        f"start it with its path {talker}")
    # lib/<package>/notes.txt is no executable: the usual message
    assert "(check the name;" in command_problems("notes.txt", ros2_env, FOUND)[0]


def test_a_missing_ros2_command_says_where_it_comes_from(ros2_env):
    problems = command_problems("ros2 launch talk both.launch.py", ros2_env, ["rosrun"])
    assert problems == [
        "`ros2` is not a program on PATH in the run image: the ROS 2 command line (ros2cli) is "
        "not installed; an <exec_depend> on ros2run or ros2launch in a package.xml installs it "
        "where rosdep knows them (Debian's ROS 2 packages have none: start a node by its path, "
        "/docker-ros/ws/install/<package>/lib/<package>/<executable>)"]
