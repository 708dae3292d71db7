"""Slim images on a real engine: the example's ROS 1 talker/listener and a ROS 2 ament package
slimmed, proven to still work (issue 9). Two run images, three slim runs.

proves (each line: the test here, all on the two module images):
- a build slims the run image, reports sizes and the times of trace and check, the window
  ending when the files settled and the --expect text was printed (not at --continue-after):
  test_build_slims_the_run_image_and_reports_it (was: the window under 10 s; now the reason
  it ended, which the log names; window_words' wording for each reason: unit, test_slim.py)
- the slim image keeps the run image's config and names its source:
  test_slim_keeps_the_config_and_names_its_source
- the slim talker is heard by a listener from the run image (and hears it):
  test_slim_talker_is_heard_by_a_listener_from_the_run_image
- DOCKER_UID/GID/USER map in the slim image: test_slim_maps_the_docker_user
- the ROS tools --exec probed still run: test_probed_ros_tools_still_run_in_the_slim_image
- what the command never used is gone: test_slim_image_lacks_what_the_command_never_used
- a rebuild with no change reuses the slim image: test_no_change_rebuild_reuses_the_slim_image
- a ROS 2 ament executable and its own library run slim, mapped, without the toolchain:
  test_ros2_slim_runs_the_ament_executable
- a slim image that does not behave like the run image (a needed library excluded) fails the
  check naming the loader's error, and is not tagged:
  test_excluding_a_needed_library_fails_the_check_and_tags_nothing
- an unknown slim option is an error naming it: test_unknown_slim_option_is_an_error_naming_it
- what the command opens after a pause longer than --settle is kept:
  test_what_the_command_opens_after_a_pause_is_kept"""

from __future__ import annotations

import json
import os
import re
import subprocess
import time
from typing import Iterator

import pytest

from tests.docker.buildhelp import (
    copy_example,
    docker_ros,
    image_exists,
    remove_image,
    run_until,
    sh,
    write_env,
)

pytestmark = pytest.mark.docker

PREFIX = f"docker-ros-test-slim-{os.getpid()}"
ROS1_IMAGE = "docker-ros-test/slim-ros1:latest"
ROS2_IMAGE = "docker-ros-test/slim-ros2:latest"
HEARD = "I heard: hello from docker-ros"
REPORT = re.compile(r"slim: (\S+) (\d+) MB -> (\S+) (\d+) MB \(ratio ([\d.]+)x.*?(\d+) of (\d+) "
                    r"files kept")


def inspect(ref: str) -> dict:
    out = subprocess.run(["docker", "image", "inspect", ref], capture_output=True, text=True,
                         check=True).stdout
    return json.loads(out)[0]


def report(log: str) -> str:
    found = REPORT.search(log)
    assert found, log[-3000:]
    run, run_mb, slim, slim_mb, ratio, kept, total = found.groups()
    # shown with -s / in the log: the figures the issue asks for
    print(f"\nSLIM FIGURES {run} {run_mb} MB -> {slim} {slim_mb} MB, ratio {ratio}x, "
          f"{kept}/{total} files")
    return found.group(0)


@pytest.fixture(scope="module")
def ros1(ros1_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    """The example's run image built and slimmed by one `docker-ros build` (ENABLE_SLIM=true),
    with ROS tools probed by --exec and the listener's output expected."""
    project = copy_example(tmp_path_factory.mktemp("slim-ros1") / "example")
    write_env(project, BASE_IMAGE=ros1_base_image, IMAGE=ROS1_IMAGE, TARGET="run",
              COMMAND="roslaunch docker_ros_example talker_listener.launch",
              ADDITIONAL_SLIM_BUILD_ARGS=f"--exec 'rosnode list' --exec 'rostopic list' "
                                         f"--expect '{HEARD}'")
    result = docker_ros(project, "build", env={"ENABLE_SLIM": "true"})
    assert result.returncode == 0, result.stdout[-5000:]
    yield {"project": project, "log": result.stdout, "run": ROS1_IMAGE,
           "slim": ROS1_IMAGE + "-slim"}
    remove_image(ROS1_IMAGE + "-slim")


def test_build_slims_the_run_image_and_reports_it(ros1: dict) -> None:
    line = report(ros1["log"])
    # (docker-ros's default SLIM_BUILD_ARGS has three that do not apply: not told each time)
    assert "ignoring options" not in ros1["log"]
    # the window ends because the traced files settled and the listener was heard (the
    # tracer's own words for why it stopped watching), not at --continue-after's limit, where
    # it would have stopped watching a node still starting; the check watches as long (one
    # line each, with their times)
    trace = re.search(r"slim: trace ([\d.]+) s: COMMAND watched ([\d.]+) s, until no new file "
                      r"was opened for 3 s and every --expect text was printed; \d+ files "
                      r"opened \(keep set [\d.]+ s\)", ros1["log"])
    assert trace, ros1["log"][-2000:]
    traced = [line for line in ros1["log"].splitlines() if "slim: trace " in line]
    assert len(traced) == 1 and "(--continue-after)" not in traced[0], traced
    check = re.search(r"slim: functional check ([\d.]+) s passed \(COMMAND still running after "
                      r"([\d.]+) s in both; 2 exec\(s\), 1 expectation\(s\)\)", ros1["log"])
    assert check and check.group(2) == f"{float(trace.group(2)):g}", ros1["log"][-2000:]
    print(f"\nSLIM TIMES trace {trace.group(1)} s (window {trace.group(2)} s), check "
          f"{check.group(1)} s")
    run_mb, slim_mb = (int(n) for n in re.findall(r"(\d+) MB", line))
    assert slim_mb * 3 < run_mb, line
    assert "latest-slim  amd64" in ros1["log"][ros1["log"].rindex("IMAGE "):]


def test_slim_keeps_the_config_and_names_its_source(ros1: dict) -> None:
    run, slim = inspect(ros1["run"]), inspect(ros1["slim"])
    for key in ("Entrypoint", "Cmd", "Env", "WorkingDir"):
        assert slim["Config"][key] == run["Config"][key], key
    assert slim["Config"]["Labels"]["org.docker-ros.slim.source"] == run["Id"]
    assert len(slim["RootFS"]["Layers"]) == 1


def test_slim_talker_is_heard_by_a_listener_from_the_run_image(ros1: dict) -> None:
    network, talker, listener = f"{PREFIX}-net", f"{PREFIX}-talker", f"{PREFIX}-listener"
    subprocess.run(["docker", "network", "create", network], check=True, capture_output=True)
    try:
        subprocess.run(["docker", "run", "-d", "--name", talker, "--hostname", talker,
                        "--network", network, ros1["slim"]], check=True, capture_output=True)
        heard = subprocess.run(
            ["docker", "run", "--rm", "--name", listener, "--hostname", listener, "--network",
             network, "-e", f"ROS_MASTER_URI=http://{talker}:11311", ros1["run"], "bash", "-c",
             "for i in $(seq 30); do rostopic list >/dev/null 2>&1 && break; sleep 1; done; "
             "timeout 60 rostopic echo -n 1 /chatter"],
            capture_output=True, text=True, timeout=180)
        assert "hello from docker-ros" in heard.stdout, heard.stdout + heard.stderr
        talker_log = subprocess.run(["docker", "logs", talker], capture_output=True, text=True)
        assert HEARD in talker_log.stdout + talker_log.stderr  # the slim listener hears it too
    finally:
        subprocess.run(["docker", "rm", "-f", talker, listener], capture_output=True)
        subprocess.run(["docker", "network", "rm", network], capture_output=True)


def test_slim_maps_the_docker_user(ros1: dict) -> None:
    mapped = sh(ros1["slim"], 'id -u; id -g; echo "$HOME $USER"', "-e", "DOCKER_UID=1234",
                "-e", "DOCKER_GID=1235", "-e", "DOCKER_USER=robot")
    assert mapped.returncode == 0, mapped.stderr
    assert mapped.stdout.split("\n")[:3] == ["1234", "1235", "/home/robot robot"]


def test_probed_ros_tools_still_run_in_the_slim_image(ros1: dict) -> None:
    name = f"{PREFIX}-tools"
    subprocess.run(["docker", "run", "-d", "--name", name, ros1["slim"]], check=True,
                   capture_output=True)
    try:
        deadline = time.monotonic() + 60
        while True:  # the slim image has no sleep/seq/grep: wait from here
            out = subprocess.run(["docker", "exec", name, "/docker-ros/entrypoint.sh", "bash",
                                  "-c", "rosnode list && rostopic list"],
                                 capture_output=True, text=True, timeout=120)
            if "/listener" in out.stdout or time.monotonic() > deadline:
                break
            time.sleep(1)
        assert out.returncode == 0, out.stderr
        assert {"/talker", "/listener", "/chatter", "/rosout"} <= set(out.stdout.split())
    finally:
        subprocess.run(["docker", "rm", "-f", name], capture_output=True)


def test_slim_image_lacks_what_the_command_never_used(ros1: dict) -> None:
    # bash builtins only (the slim image has no ls or test binary); exit 0 unless bash fails
    probe = "for f in /usr/bin/apt /usr/bin/perl /usr/bin/gcc /usr/bin/ls; do " \
            "if [ -e $f ]; then echo $f; fi; done"
    run, slim = sh(ros1["run"], probe), sh(ros1["slim"], probe)
    assert run.returncode == 0 and slim.returncode == 0, run.stderr + slim.stderr
    assert "/usr/bin/apt" in run.stdout.split()
    assert slim.stdout.split() == []


def test_no_change_rebuild_reuses_the_slim_image(ros1: dict) -> None:
    before = inspect(ros1["slim"])["Id"]
    result = docker_ros(ros1["project"], "slim", env={"ENABLE_SLIM": "true"})
    assert result.returncode == 0, result.stdout[-3000:]
    assert f"slim: {ros1['slim']} is up to date" in result.stdout
    assert inspect(ros1["slim"])["Id"] == before  # (how fast: scripts/bench.py)


# ----------------------------------------------------------------------------------- ROS 2
CMAKE = """cmake_minimum_required(VERSION 3.10)
project(slim_hello CXX)
find_package(ament_cmake REQUIRED)
add_library(greeter SHARED src/greeter.cpp)
add_executable(slim_hello src/main.cpp)
target_link_libraries(slim_hello greeter)
install(TARGETS greeter LIBRARY DESTINATION lib)
install(TARGETS slim_hello RUNTIME DESTINATION bin)
ament_package()
"""
PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>slim_hello</name>
  <version>0.0.1</version>
  <description>ament_cmake executable with its own shared library</description>
  <maintainer email="t@example.com">t</maintainer>
  <license>MIT</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""


@pytest.fixture(scope="module")
def ros2(ros2_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    """An ament_cmake package (executable + its own library) whose COMMAND prints and exits:
    run image by `docker-ros build`, then `docker-ros slim`."""
    project = tmp_path_factory.mktemp("slim-ros2") / "ws"
    (project / "slim_hello" / "src").mkdir(parents=True)
    (project / "slim_hello" / "package.xml").write_text(PACKAGE_XML)
    (project / "slim_hello" / "CMakeLists.txt").write_text(CMAKE)
    (project / "slim_hello" / "src" / "greeter.cpp").write_text(
        '#include <iostream>\n#include <string>\nvoid greet(const std::string& who) '
        '{ std::cout << "hello from " << who << std::endl; }\n')
    (project / "slim_hello" / "src" / "main.cpp").write_text(
        '#include <string>\nvoid greet(const std::string& who);\n'
        'int main() { greet("ament"); return 0; }\n')
    write_env(project, BASE_IMAGE=ros2_base_image, IMAGE=ROS2_IMAGE, TARGET="run",
              COMMAND="slim_hello", DISABLE_ROS_INSTALLATION="true",
              ADDITIONAL_SLIM_BUILD_ARGS="--expect 'hello from ament'")
    built = docker_ros(project, "build")
    assert built.returncode == 0, built.stdout[-5000:]
    slimmed = docker_ros(project, "slim", env={"ENABLE_SLIM": "true"})
    assert slimmed.returncode == 0, slimmed.stdout[-5000:]
    yield {"project": project, "log": slimmed.stdout, "run": ROS2_IMAGE,
           "slim": ROS2_IMAGE + "-slim"}
    remove_image(ROS2_IMAGE + "-slim")


def test_ros2_slim_runs_the_ament_executable(ros2: dict) -> None:
    line = report(ros2["log"])
    assert "COMMAND exited with 0 in both; 0 exec(s), 1 expectation(s)" in ros2["log"]
    run_mb, slim_mb = (int(n) for n in re.findall(r"(\d+) MB", line))
    assert slim_mb * 5 < run_mb, line
    assert "hello from ament" in run_until(ros2["slim"], "hello from ament", 30)
    mapped = sh(ros2["slim"], "id -u; slim_hello", "-e", "DOCKER_UID=4321")
    assert mapped.stdout.split("\n")[:2] == ["4321", "hello from ament"], mapped.stderr
    gone = sh(ros2["slim"], "[ -e /usr/bin/cmake ] || [ -e /usr/bin/g++ ] || echo gone")
    assert gone.stdout.strip() == "gone"


def test_excluding_a_needed_library_fails_the_check_and_tags_nothing(ros2: dict) -> None:
    tag = "latest-slim-broken"
    remove_image(f"{ROS2_IMAGE.split(':')[0]}:{tag}")
    result = docker_ros(ros2["project"], "slim", env={
        "ENABLE_SLIM": "true", "SLIM_IMAGE_TAG": tag,
        "ADDITIONAL_SLIM_BUILD_ARGS": "--exclude-pattern '/usr/lib/*/libstdc++.so*'"})
    assert result.returncode != 0
    lines = [line for line in result.stdout.splitlines() if line.startswith("docker-ros slim:")]
    assert lines and "does not behave like it, not tagged" in lines[-1], result.stdout[-3000:]
    assert "COMMAND exited with 0 in the run image but exited with 127 in the slim image" \
        in lines[-1]
    assert "libstdc++" in lines[-1]  # the loader's error names the missing library
    assert not image_exists(f"{ROS2_IMAGE.split(':')[0]}:{tag}")
    dangling = subprocess.run(["docker", "images", "-q", "--filter",
                               f"label=org.docker-ros.slim.source={inspect(ros2['run'])['Id']}"],
                              capture_output=True, text=True).stdout.split()
    assert dangling == [inspect(ros2["slim"])["Id"][7:19]]  # only the good one is left


def test_unknown_slim_option_is_an_error_naming_it(ros2: dict) -> None:
    result = docker_ros(ros2["project"], "slim", "--dry-run", env={
        "ENABLE_SLIM": "true", "ADDITIONAL_SLIM_BUILD_ARGS": "--frobnicate"})
    assert result.returncode == 1
    assert "docker-ros slim: ADDITIONAL_SLIM_BUILD_ARGS: unknown option(s) --frobnicate" in (
        result.stdout)



def test_what_the_command_opens_after_a_pause_is_kept(ros2: dict) -> None:
    """A node that used a program only after a pause longer than --settle (3 s) lost it in its
    slim image, which passed the check (as long as the window) and was tagged: `tar: command
    not found` 6 s after start. The trace goes on while the slim image is made and checked."""
    paused = "docker-ros-test/slim-pause:latest"
    dockerfile = (f"FROM {ros2['run']}\n"
                  'ENV DEFAULT_CMD="slim_hello; sleep 6; tar --version; sleep infinity"\n')
    subprocess.run(["docker", "build", "-q", "-t", paused, "-"], input=dockerfile, text=True,
                   check=True, capture_output=True)
    try:
        result = docker_ros(ros2["project"], "slim", env={"ENABLE_SLIM": "true",
                                                          "IMAGE": paused})
        assert result.returncode == 0, result.stdout[-3000:]
        later = [line for line in result.stdout.splitlines() if "after the window" in line]
        assert later and "/usr/bin/tar" in later[0], result.stdout[-3000:]
        assert "tar (GNU tar)" in run_until(paused + "-slim", "tar (GNU tar)", 30)
    finally:
        remove_image(paused + "-slim")
        remove_image(paused)
