"""The failing tool's own lines, a full disk and an unreachable host, read from the output of
real failures (tests/unit/data/faults: apt, dpkg, pip and git in the ROS 1 base image with a
bad mirror, a closed port or a full tmpfs; gcc and CMake on the host; a docker-ros build on an
engine whose data root was full)."""

from __future__ import annotations

import http.client
from pathlib import Path
from typing import List

import docker
import pytest
import requests
import urllib3

from docker_ros.host import faults as host_faults
from docker_ros.in_image.runtime import faults
from docker_ros.in_image.runtime.process import fault_lines, run, run_script
from docker_ros.in_image.runtime.workspace import StepError

DATA = Path(__file__).parent / "data" / "faults"


def sample(name: str) -> List[str]:
    return (DATA / name).read_text().splitlines()


@pytest.mark.parametrize("name, expected", [
    ("apt-full.txt", ["E: You don't have enough free space in /var/cache/apt/archives/."]),
    ("apt-unresolvable.txt", [
        "W: Failed to fetch http://no-such-mirror.invalid/debian/dists/bookworm/InRelease  "
        "Could not resolve 'no-such-mirror.invalid'",
        "W: Some index files failed to download. They have been ignored, or old ones used "
        "instead.",
        "E: Unable to locate package curl"]),
    ("dpkg-full.txt", [
        "dpkg: error processing archive /var/cache/apt/archives/curl_7.88.1-10+deb12u15_amd64"
        ".deb (--unpack): cannot copy extracted data for './usr/share/doc/curl/changelog.gz' "
        "to '/usr/share/doc/curl/changelog.gz.dpkg-new': failed to write (No space left on "
        "device)",
        "E: Sub-process /usr/bin/dpkg returned an error code (1)"]),
    ("pip-full.txt", ["ERROR: Could not install packages due to an OSError: [Errno 28] No "
                      "space left on device"]),
    ("pip-refused.txt", [
        "ERROR: Could not find a version that satisfies the requirement "
        "catkin-pkg-nonexistent-xyz (from versions: none)",
        "ERROR: No matching distribution found for catkin-pkg-nonexistent-xyz"]),
    ("gcc-error.txt", ["talker.c:2:10: error: ‘undefined_thing’ undeclared (first use in this "
                       "function)"]),
    ("cmake-error.txt", ['CMake Error at CMakeLists.txt:3 (find_package): By not providing '
                         '"Findroscpp_missing.cmake" in CMAKE_MODULE_PATH this']),
    ("git-missing-file.txt", ["fatal: '/srv/missing/repo.git' does not appear to be a git "
                              "repository", "fatal: Could not read from remote repository."]),
])
def test_the_tools_own_error_lines_are_found(name: str, expected: List[str]) -> None:
    assert faults.tool_lines(sample(name)) == expected


def test_a_full_disk_comes_first_when_there_are_more_lines_than_shown() -> None:
    lines = sample("buildkit-engine-disk-full.log")
    shown = faults.tool_lines(host_faults.step_output(lines))
    assert shown[0] == "E: Write error - write (28: No space left on device)"
    assert len(shown) == faults.SHOWN_LINES


@pytest.mark.parametrize("name, full", [
    ("apt-full.txt", True), ("dpkg-full.txt", True), ("pip-full.txt", True),
    ("buildkit-engine-disk-full.log", True), ("apt-refused.txt", False),
    ("gcc-error.txt", False), ("git-refused.txt", False),
])
def test_a_full_disk_is_seen_in_any_tools_words(name: str, full: bool) -> None:
    assert faults.disk_full(sample(name)) is full


@pytest.mark.parametrize("name, url, reason", [
    ("apt-refused.txt", "http://127.0.0.1:9/debian/dists/bookworm/InRelease",
     "Could not connect to 127.0.0.1:9: Connection refused"),
    ("apt-unresolvable.txt", "http://no-such-mirror.invalid/debian/dists/bookworm/InRelease",
     "Could not resolve 'no-such-mirror.invalid'"),
    ("apt-fetch-archive.txt", "http://deb.debian.org/debian/pool/main/c/curl/"
     "curl_7.88.1-10%2bdeb12u15_amd64.deb", "Could not connect to 127.0.0.1:9: Connection refused"),
    ("pip-refused.txt", "http://127.0.0.1:9/simple/catkin-pkg-nonexistent-xyz/",
     "Connection refused"),
    ("git-refused.txt", "http://127.0.0.1:9/ros/missing.git/",
     "Failed to connect to 127.0.0.1 port 9: Couldn't connect to server"),
    ("git-daemon-refused.txt", "127.0.0.1", "Connection refused"),
    ("apt-full.txt", "", ""), ("gcc-error.txt", "", ""), ("pip-unresolvable.txt", "", ""),
])
def test_the_url_that_could_not_be_reached_is_named(name: str, url: str, reason: str) -> None:
    assert faults.unreachable(sample(name)) == (url, reason)


def test_vcs_names_the_url_of_a_clone_whose_server_went_away() -> None:
    lines = ["=== src/upstream/dep (git) ===",
             "Could not clone repository 'git://127.0.0.1:9418/dep.git': Cloning into '.'...",
             "fatal: the remote end hung up unexpectedly", "fatal: early EOF"]
    assert faults.unreachable(lines) == ("git://127.0.0.1:9418/dep.git",
                                         "the remote end hung up unexpectedly")


def test_a_failed_build_names_the_tools_lines_and_the_engines_data_root() -> None:
    lines = sample("buildkit-engine-disk-full.log")
    shown = host_faults.build_lines(lines, lambda: ("/var/lib/docker", 96_400_000))
    assert shown[:3] == ["E: Write error - write (28: No space left on device)",
                         "E: IO Error saving source cache",
                         "E: The package lists or status file could not be parsed or opened."]
    assert shown[3].startswith("the disk is full: the engine's data root /var/lib/docker "
                               "(96 MB free); see what takes the room with `docker system df`")
    assert shown[3].endswith("docker-ros removes nothing itself")


def test_a_full_disk_in_buildkits_own_export_is_named() -> None:
    lines = ["#14 exporting to image", "#14 exporting layers",
             "#14 ERROR: write /var/lib/docker/tmp/x: no space left on device",
             "ERROR: failed to solve: failed to export image: write /var/lib/docker/tmp/x: "
             "no space left on device"]
    shown = host_faults.build_lines(lines, lambda: ("", None))
    assert shown == ["ERROR: failed to solve: failed to export image: write "
                     "/var/lib/docker/tmp/x: no space left on device",
                     faults.engine_disk_line("", None)]
    assert "the engine's disk (" not in shown[1]


def test_an_unreachable_mirror_in_a_build_is_named_with_its_url() -> None:
    lines = [f"#11 1.{n} {line}" for n, line in enumerate(sample("apt-refused.txt"))]
    shown = host_faults.build_lines(lines + ["#11 ERROR: exit code: 100"], lambda: ("", None))
    assert shown[-1].startswith("could not reach http://127.0.0.1:9/debian/dists/bookworm/"
                                "InRelease (Could not connect to 127.0.0.1:9: Connection refused): "
                                "check that the server is up")


def test_nothing_is_added_for_output_that_names_no_fault() -> None:
    assert faults.tool_lines(["Reading package lists...", "W: --force-yes is deprecated"]) == []
    assert host_faults.build_lines(["#3 1.0 hello", "#3 ERROR: exit code: 1"],
                                   lambda: ("", None)) == []


@pytest.mark.parametrize("free, shown", [
    (None, "free space unknown"), (0, "0 bytes free"), (233_472, "233 kB free"),
    (96_400_000, "96 MB free"), (12_345_678_901, "12.3 GB free")])
def test_room_is_said_in_round_units(free: object, shown: str) -> None:
    assert faults.size(free) == shown  # type: ignore[arg-type]


def test_a_host_step_names_the_url_git_could_not_reach(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """A real git on the host (a host step's run): its fatal line and the URL."""
    monkeypatch.delenv("DOCKER_ROS", raising=False)
    with pytest.raises(StepError) as failed:
        run(["git", "clone", "-q", "http://127.0.0.1:9/ros/missing.git", str(tmp_path / "x")],
            step="clone")
    lines = failed.value.message.splitlines()
    assert lines[0] == ("failed with exit code 128: git clone -q http://127.0.0.1:9/ros/"
                        f"missing.git {tmp_path / 'x'}")
    assert lines[1].startswith("  fatal: unable to access 'http://127.0.0.1:9/ros/missing.git/'")
    assert lines[2].startswith("  could not reach http://127.0.0.1:9/ros/missing.git/ ")


def test_a_host_steps_full_disk_names_where_it_writes(monkeypatch: pytest.MonkeyPatch,
                                                      tmp_path: Path) -> None:
    monkeypatch.delenv("DOCKER_ROS", raising=False)
    shown = fault_lines(sample("pip-full.txt"), tmp_path)
    assert shown[-1].startswith(f"the disk is full: {tmp_path} (")
    monkeypatch.setenv("DOCKER_ROS", "1")  # in an image: the host names the engine's disk
    assert fault_lines(sample("pip-full.txt"), tmp_path) == faults.tool_lines(
        sample("pip-full.txt"))


def test_a_commands_output_still_reaches_the_user(capfd: pytest.CaptureFixture[str]) -> None:
    run(["sh", "-c", "echo out; echo err >&2"], step="custom")
    assert capfd.readouterr().out.splitlines()[-2:] == ["out", "err"]


def test_an_engine_that_no_longer_listens_is_named_as_lost(tmp_path: Path) -> None:
    """The Engine API's transport error for a socket nobody listens on (a stopped engine), as
    the docker SDK raises it: no DockerException, and named in our words."""
    gone = docker.DockerClient(base_url=f"unix://{tmp_path}/docker.sock", version="1.41")
    with pytest.raises(Exception) as raised:
        gone.images.get("x")
    assert host_faults.lost_engine(raised.value)
    assert host_faults.request_detail(raised.value) == "No such file or directory"
    assert host_faults.engine_lost_line("push", "Response ended prematurely") == (
        "the connection to the Docker engine was lost during push (Response ended "
        "prematurely); an image is tagged or pushed only once it is complete, so rerunning is "
        "safe once `docker info` answers")


def test_a_tasks_failure_after_its_engine_went_away_names_the_lost_engine() -> None:
    """A task's failure after the engine it reached stopped answering (here: slim's trace
    container as the engine's shutdown would stop it; not seen in the suite, where slim's next
    request fails first) is named as the lost engine with the failure as its detail; a
    failure while the engine answers, or of a task that never reached it, is the task's own."""
    failure = "the tracer stopped early (exit code 143): docker-ros slimtrace: stopped\nmore"
    asked: List[bool] = []

    def gone() -> bool:
        asked.append(True)
        return False

    lost = host_faults.lost_during(host_faults.task_doing("slim"), failure, answered=True,
                                   answers=gone)
    assert lost == (
        "the connection to the Docker engine was lost during the slim run (the tracer stopped "
        "early (exit code 143): docker-ros slimtrace: stopped); an image is tagged or pushed "
        "only once it is complete, so rerunning is safe once `docker info` answers")
    assert host_faults.lost_during("the push", failure, answered=True,
                                   answers=lambda: True) is None
    assert host_faults.lost_during("the push", failure, answered=False, answers=gone) is None
    assert len(asked) == 1  # (an engine never reached is not asked about)
    built = ("failed: the connection to the Docker engine was lost (ERROR: EOF); nothing was "
             "tagged, so rerunning is safe once `docker info` answers")
    assert host_faults.lost_during("the push", built, answered=True, answers=gone) is None


def test_each_task_names_what_it_was_doing_when_the_engine_went_away() -> None:
    assert [host_faults.task_doing(name) for name in ("push", "slim", "test", "dev-shell")] == [
        "the push", "the slim run", "the test run", "the dev shell"]
    assert host_faults.task_doing("build-base") == "`docker-ros build-base`"


def test_a_response_cut_short_by_the_engine_is_named_by_its_reason() -> None:
    """As the SDK raised it when the engine was killed while a container ran (measured)."""
    cut = requests.exceptions.ChunkedEncodingError(
        urllib3.exceptions.ProtocolError("Response ended prematurely"))
    refused = requests.exceptions.ConnectionError(urllib3.exceptions.ProtocolError(
        "Connection aborted.", ConnectionRefusedError(111, "Connection refused")))
    assert host_faults.request_detail(cut) == "Response ended prematurely"
    assert host_faults.request_detail(refused) == "Connection refused"


def test_a_push_stream_cut_by_the_engine_is_named_as_a_lost_engine() -> None:
    """urllib3's own error, as the SDK raised it reading a push's progress when the engine was
    stopped in the middle of the push (measured: no requests error around it)."""
    cut = urllib3.exceptions.ProtocolError("Connection broken: IncompleteRead(0 bytes read)",
                                           http.client.IncompleteRead(b""))
    assert host_faults.lost_engine(cut)
    assert host_faults.request_detail(cut) == "Connection broken: IncompleteRead(0 bytes read)"


def test_vcs_names_the_url_of_a_git_daemon_that_is_gone() -> None:
    lines = ["=== src/upstream/libs (git) ===",
             "Could not clone repository 'git://127.0.0.1:9418/libs.git': Cloning into '.'...",
             "fatal: unable to connect to 127.0.0.1:",
             "127.0.0.1[0: 127.0.0.1]: errno=Connection refused"]
    assert faults.unreachable(lines) == ("git://127.0.0.1:9418/libs.git", "Connection refused")


def test_what_a_hook_adds_stays_on_the_first_line(tmp_path: Path) -> None:
    """A failed hook's `it stopped at line N` goes to the message's first line, the tool's
    lines (a real git's) below it."""
    script = tmp_path / "hook.sh"
    script.write_text("true\ngit clone -q file:///srv/missing/repo.git x\n")
    with pytest.raises(StepError) as failed:
        run_script(["bash", "-e", str(script)], script, step="custom", dry_run=False,
                   cwd=tmp_path, what=str(script))
    first, *rest = failed.value.message.splitlines()
    assert "it stopped at line 2" in first, failed.value.message
    assert rest == ["  fatal: '/srv/missing/repo.git' does not appear to be a git repository",
                    "  fatal: Could not read from remote repository."]
