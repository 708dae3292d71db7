"""`docker-ros build` on a real Docker engine: the example's dev and run images, caching,
user mapping, underlaying a docker-ros base image, and bad input (issue: container images).

proves (each line: where; "image" = a test here):
- a build ends with the summary table of both images: image, test_build_ends_with_summary_table
- outside git the images carry the OCI labels known there (version, title, licenses) and
  docker-ros's own under org.docker-ros.: image, test_images_carry_the_labels_known_outside_git
  (in git, from the Action: tests/ci/test_github_action.py)
- the run image runs the node (talker heard): image, test_run_image_runs_the_node
- DEFAULT_CMD replaces the command, sourced: image, test_default_cmd_replaces_the_command_...
- `docker stop` reaches roslaunch, which shuts its nodes down and exits 0 by itself (not killed
  after the grace period: 137, nor a shell in its stead: 143): image, test_docker_stop_shuts_
  the_node_down_cleanly (was: under 8 s; now exit code 0 with a 120 s grace period)
- docker-ros's ENVs and pip configuration in both images: image,
  test_images_have_docker_ros_environment
- the run image has no compiler and no sources: image, test_run_image_has_no_compiler_and_...
- the dev image has the sources and builds them: image, test_dev_image_has_sources_and_builds_them
- a source edit rebuilds without installing and ships the change: image,
  test_rebuild_after_source_edit_installs_nothing_and_ships_the_change
- a rebuild with no change is up to date without starting BuildKit (the record of the last
  build), and fully cached by BuildKit without that record: image,
  test_no_change_rebuild_is_up_to_date_and_fully_cached
- user mapping owns files written in mounts; a collision warns and goes on: image,
  test_host_user_mapping_owns_files_written_in_mounts, test_user_mapping_collision_warns_...
- `docker exec -it ... bash` has the workspace environment: image,
  test_interactive_shell_has_the_workspace_environment
- docker-ros's entrypoint paths (/tini, /entrypoint.sh) work: image,
  test_docker_ros_entrypoint_paths_still_work
- a docker-ros image as BASE_IMAGE underlays its workspace: image,
  test_docker_ros_image_as_base_underlays_its_workspace
- missing BASE_IMAGE and COMMAND are reported together, no traceback: unit,
  tests/unit/test_failure_notes.py (needs no engine: was docker-marked here)
- no daemon is one clear message: unit, tests/unit/test_failure_notes.py (was docker-marked)
- a BASE_IMAGE that does not exist is refused before BuildKit, a typo naming the local image:
  image, test_base_image_that_does_not_exist (no build; the engine's images are the input)
- a failing step names the step and the cause on the last line and tags nothing, for a user's
  script (custom), a repository rosdep rule to a package apt lacks (real rosdep and apt), a
  compile error (real colcon and g++) and a COMMAND the run image cannot run: image,
  test_failing_step_names_step_and_cause_and_tags_nothing (TARGET=run: one outcome)
- the debs step's "apt has no package" wording: unit, tests/unit/test_steps_stdlib.py (apt_reason,
  debs and rosdep-rule variants); it reaches the user as the rosdep-rule case above does. Was a
  failing image build of its own (apt in the image)
- an unresolvable rosdep key names the key and the packages: unit,
  tests/unit/test_steps_parsing.py (the rosdep step's message). Was a failing image build
- a failed bake run names a dev image BuildKit had tagged ("'dev' was built: ..."), else both
  targets as failed: unit, tests/unit/test_failure_notes.py (run_buildx over BuildKit's log),
  and the one-run-per-target case in tests/unit/test_build_plan.py. Was the colcon case with
  TARGET=dev,run, which passed whichever way the race went
- ENABLE_COMMAND_CHECK=false builds and tags a refused COMMAND: image,
  test_command_check_can_be_turned_off
- --until stops after a step, tagging that state; an unknown step is refused: image,
  test_build_until_a_step_stops_there"""

from __future__ import annotations

import json
import re
import subprocess
import time
import uuid
from pathlib import Path

import pytest

from docker_ros.core.loading import host_platform
from docker_ros.host import engine
from tests.docker.buildhelp import (
    STAGE,
    cached_vertices,
    copy_example,
    docker_ros,
    image_exists,
    not_from_cache,
    own_copy,
    remove_image,
    run_until,
    sh,
    write_env,
)

pytestmark = pytest.mark.docker

EXAMPLE_COMMAND = "roslaunch docker_ros_example talker_listener.launch"


def cmake_package(root: Path, name: str, *, depends: tuple = (), body: str = "") -> Path:
    """A `cmake` build-type ROS package with one executable printing its name."""
    pkg = root / name
    (pkg / "src").mkdir(parents=True)
    deps = "".join(f"  <depend>{d}</depend>\n" for d in depends)
    (pkg / "package.xml").write_text(
        f'<?xml version="1.0"?>\n<package format="3">\n  <name>{name}</name>\n'
        f"  <version>0.0.1</version>\n  <description>test</description>\n"
        f'  <maintainer email="t@example.com">t</maintainer>\n  <license>MIT</license>\n'
        f"{deps}  <export><build_type>cmake</build_type></export>\n</package>\n"
    )
    (pkg / "CMakeLists.txt").write_text(
        f"cmake_minimum_required(VERSION 3.10)\nproject({name} CXX)\n"
        f"add_executable({name} src/main.cpp)\ninstall(TARGETS {name} DESTINATION bin)\n"
    )
    (pkg / "src" / "main.cpp").write_text(
        body or f'#include <cstdio>\nint main() {{ std::puts("{name} says hi"); }}\n'
    )
    return pkg


@pytest.fixture(scope="module")
def example(ros1_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The example workspace (a copy), built once for dev and run."""
    project = copy_example(tmp_path_factory.mktemp("example") / "example")
    write_env(project, BASE_IMAGE=ros1_base_image, COMMAND=EXAMPLE_COMMAND,
              IMAGE="docker-ros-test/example:latest", TARGET="dev,run")
    result = docker_ros(project, "build")
    assert result.returncode == 0, result.stdout[-5000:]
    return {"project": project, "log": result.stdout, "base": ros1_base_image,
            "dev": "docker-ros-test/example:latest-dev", "run": "docker-ros-test/example:latest"}


def test_build_ends_with_summary_table(example: dict) -> None:
    table = example["log"][example["log"].rindex("IMAGE "):]
    assert "IMAGE" in table and "BUILD TIME" in table
    assert "docker-ros-test/example  latest-dev  amd64" in table
    assert "docker-ros-test/example  latest      amd64" in table


def test_images_carry_the_labels_known_outside_git(example: dict) -> None:
    """Not a git repository: no source, revision or created; the example's one package.xml
    names MIT."""
    for ref, title in ((example["run"], "example"), (example["dev"], "example (dev)")):
        labels = json.loads(subprocess.run(
            ["docker", "image", "inspect", "--format", "{{json .Config.Labels}}", ref],
            capture_output=True, text=True, check=True).stdout)
        oci = {k: v for k, v in labels.items() if k.startswith("org.opencontainers.")}
        assert oci == {"org.opencontainers.image.version": "latest",
                       "org.opencontainers.image.title": title,
                       "org.opencontainers.image.licenses": "MIT"}, labels
        assert all(k.startswith("org.docker-ros.") for k in set(labels) - set(oci)), labels


def test_run_image_runs_the_node(example: dict) -> None:
    out = run_until(example["run"], "I heard: hello from docker-ros", 60)
    assert "I heard: hello from docker-ros" in out, out[-3000:]


def test_default_cmd_replaces_the_command_as_in_docker_ros(example: dict) -> None:
    """`docker run -e DEFAULT_CMD=... <image>` (docker-ros's variable) runs that, sourced."""
    result = subprocess.run(
        ["docker", "run", "--rm", "-e", "DEFAULT_CMD=rospack find docker_ros_example",
         example["run"]],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.strip().endswith("/share/docker_ros_example")


def test_docker_stop_shuts_the_node_down_cleanly(example: dict) -> None:
    """`docker stop` of the default command: SIGTERM (through tini and the entrypoint) reaches
    roslaunch, which stops its nodes and exits 0 at once. (Under `eval` in a bash only the
    shell got it: exit 143, and the nodes were SIGKILLed with the container, no shutdown.)"""
    name = f"docker-ros-test-stop-{uuid.uuid4().hex[:8]}"
    subprocess.run(["docker", "run", "-d", "--name", name, example["run"]],
                   capture_output=True, text=True, check=True)
    try:
        deadline = time.monotonic() + 60
        logs = ""
        while "I heard" not in logs and time.monotonic() < deadline:
            time.sleep(1)
            logs = subprocess.run(["docker", "logs", name], capture_output=True,
                                  text=True).stdout
        assert "I heard" in logs, logs[-3000:]
        # A grace period far longer than any shutdown: exit code 0 is roslaunch's own after
        # SIGTERM; a container SIGKILLed after the grace period ends with 137, a shell that got
        # the signal in roslaunch's stead with 143 (and neither shuts the nodes down).
        subprocess.run(["docker", "stop", "-t", "120", name], capture_output=True, check=True)
        state = json.loads(subprocess.run(["docker", "inspect", "-f", "{{json .State}}", name],
                                          capture_output=True, text=True, check=True).stdout)
        logs = subprocess.run(["docker", "logs", name], capture_output=True, text=True).stdout
    finally:
        subprocess.run(["docker", "rm", "-f", name], capture_output=True)
    assert (state["ExitCode"], state["OOMKilled"]) == (0, False), (state, logs[-2000:])
    assert "shutting down processing monitor complete" in logs, logs[-2000:]


def test_images_have_docker_ros_environment(example: dict) -> None:
    """docker-ros's ENVs: the architecture (hooks fetch files for it), ROS_DISTRO, coloured
    ROS 2 logs, the default middleware."""
    for ref in (example["dev"], example["run"]):
        env = subprocess.run(["docker", "image", "inspect", "-f", "{{json .Config.Env}}", ref],
                             capture_output=True, text=True, check=True).stdout
        for pair in (f"TARGETARCH={host_platform()}", "RCUTILS_COLORIZED_OUTPUT=1",
                     "RMW_IMPLEMENTATION=rmw_fastrtps_cpp"):
            assert f'"{pair}"' in env, (ref, env)
        # the base (Debian's ROS) has none, nor does this build set one: defined, empty
        assert "ROS_DISTRO=" in json.loads(env), (ref, env)
    # docker-ros's pip configuration: hooks and dev containers may pip install (PEP 668)
    pip = sh(example["dev"], "python3 -m pip config list", "--entrypoint", "")
    assert "global.break-system-packages='true'" in pip.stdout.splitlines(), pip.stdout


def test_run_image_has_no_compiler_and_no_sources(example: dict) -> None:
    probe = "command -v gcc g++ cc c++ || true; ls /docker-ros/ws"
    base = sh(example["base"], probe, "--entrypoint", "")
    assert "gcc" not in base.stdout, "the base image must lack a compiler for this test"
    run = sh(example["run"], probe)
    assert run.returncode == 0, run.stderr
    assert not any(tool in run.stdout for tool in ("/gcc", "/g++", "/cc", "/c++")), run.stdout
    assert run.stdout.split() == ["install"]
    talker = sh(example["run"], "ls install/docker_ros_example/lib/docker_ros_example")
    assert "talker" in talker.stdout and "listener.py" in talker.stdout


def test_dev_image_has_sources_and_builds_them(example: dict) -> None:
    check = sh(example["dev"], "ls src/target/docker_ros_example/package.xml && "
               "command -v g++ && colcon build 2>&1 | tail -3")
    assert check.returncode == 0, check.stdout + check.stderr
    assert "1 package finished" in check.stdout


def test_rebuild_after_source_edit_installs_nothing_and_ships_the_change(
    example: dict, tmp_path: Path
) -> None:
    edited_image = "docker-ros-test/example-edited:latest"
    project = own_copy(example["project"], tmp_path / "example", edited_image)
    talker = project / "docker_ros_example" / "src" / "talker.cpp"
    talker.write_text(talker.read_text().replace("hello from docker-ros", "edited message"))
    try:
        result = docker_ros(project, "build", "--target", "run")
        assert result.returncode == 0, result.stdout[-5000:]
        # The dependency installation layer is reused from cache: nothing is installed again.
        installs = {name: cached for name, cached in cached_vertices(result.stdout).items()
                    if "rosdep debs pip files custom --phase apply" in name}
        assert installs and all(installs.values()), installs
        assert "apt-get install" not in result.stdout
        out = run_until(edited_image, "I heard: edited message", 60)
        assert "I heard: edited message" in out, out[-3000:]
    finally:
        remove_image(edited_image)


def test_no_change_rebuild_is_up_to_date_and_fully_cached(example: dict, tmp_path: Path) -> None:
    """Nothing changed since the module's build: the rebuild finds the record of that build
    (host/unchanged.py) and does not start BuildKit; the image stays the one built. Without
    the record (another cache folder: a user who cleared it), BuildKit runs and takes every
    step from its cache."""
    image_id = engine.inspect_image(example["run"])["Id"]
    result = docker_ros(example["project"], "build", "--target", "run")
    assert result.returncode == 0, result.stdout[-3000:]
    assert ("==> docker-ros build (amd64) run: up to date, built from these same inputs "
            f"({example['run']}); not rebuilt (NO_CACHE=true rebuilds)") in result.stdout
    assert "exporting to image" not in result.stdout and not cached_vertices(result.stdout)
    assert re.search(r"latest +amd64 +\d+ MB +up to date", result.stdout), result.stdout
    assert engine.inspect_image(example["run"])["Id"] == image_id

    result = docker_ros(example["project"], "build", "--target", "run",
                        env={"XDG_CACHE_HOME": str(tmp_path)})
    assert result.returncode == 0, result.stdout[-3000:]
    # Every RUN came from cache: no step started, and the log does show the steps.
    assert "Starting >>>" not in result.stdout, result.stdout[-3000:]
    steps = [n for n in cached_vertices(result.stdout) if STAGE.match(n) and " RUN " in n]
    assert len(steps) >= 5 and not_from_cache(result.stdout) == [], result.stdout[-3000:]
    assert engine.inspect_image(example["run"])["Id"] == image_id


def test_host_user_mapping_owns_files_written_in_mounts(example: dict, tmp_path: Path) -> None:
    tmp_path.chmod(0o777)
    result = sh(example["run"], "touch /data/made-inside && id -un",
                "-e", "DOCKER_UID=4321", "-e", "DOCKER_GID=4322", "-e", "DOCKER_USER=robot",
                "-v", f"{tmp_path}:/data")
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "robot"
    made = (tmp_path / "made-inside").stat()
    assert (made.st_uid, made.st_gid) == (4321, 4322)


def test_interactive_shell_has_the_workspace_environment(example: dict) -> None:
    """`docker exec -it <container> bash` starts no entrypoint: /etc/bash.bashrc sources ROS
    and the workspace, as docker-ros's ~/.bashrc did (bash -i: what docker exec -it runs)."""
    result = subprocess.run(
        ["docker", "run", "--rm", "--entrypoint", "bash", example["run"], "-ic",
         "rospack find docker_ros_example"],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.strip().endswith("/install/docker_ros_example/share/docker_ros_example")


def test_docker_ros_entrypoint_paths_still_work(example: dict) -> None:
    """An ENTRYPOINT of docker-ros's (`/tini -- /entrypoint.sh`, in images derived from ours)."""
    result = subprocess.run(
        ["docker", "run", "--rm", "--entrypoint", "/tini", example["run"], "--",
         "/entrypoint.sh", "rospack", "find", "docker_ros_example"],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.strip().endswith("/share/docker_ros_example")


def test_user_mapping_collision_warns_and_goes_on(example: dict) -> None:
    result = sh(example["run"], "id -u", "-e", "DOCKER_UID=0", "-e", "DOCKER_GID=0")
    assert result.returncode == 0
    assert result.stdout.strip() == "0"
    assert "exists already" in result.stderr


def test_docker_ros_image_as_base_underlays_its_workspace(
    ros1_base_image: str, tmp_path: Path
) -> None:
    repo_a = tmp_path / "a"
    cmake_package(repo_a, "lib_a")
    write_env(repo_a, BASE_IMAGE=ros1_base_image, COMMAND="lib_a", IMAGE="docker-ros-test/a:1")
    built = docker_ros(repo_a, "build")
    assert built.returncode == 0, built.stdout[-4000:]
    repo_b = tmp_path / "b"
    cmake_package(repo_b, "app_b", depends=("lib_a",))
    write_env(repo_b, BASE_IMAGE="docker-ros-test/a:1", COMMAND="lib_a && app_b",
              IMAGE="docker-ros-test/b:1")
    built = docker_ros(repo_b, "build")
    assert built.returncode == 0, built.stdout[-4000:]
    ran = subprocess.run(["docker", "run", "--rm", "docker-ros-test/b:1"],
                         capture_output=True, text=True, timeout=120)
    assert ran.stdout.split("\n")[:2] == ["lib_a says hi", "app_b says hi"], ran
    underlay = sh("docker-ros-test/b:1", "ls /opt/ws_base_image/install/lib_a/bin")
    assert "lib_a" in underlay.stdout


# ---------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("typo", [False, True], ids=["unknown", "typo"])
def test_base_image_that_does_not_exist(typo: bool, ros1_base_image: str, tmp_path: Path) -> None:
    """Refused before the build; a typo of a local image's name (two letters swapped) names
    that image."""
    base = ros1_base_image[:-2] + ros1_base_image[:-3:-1] if typo else (
        "docker-ros-test/no-such-image:1")
    cmake_package(tmp_path, "pkg")
    write_env(tmp_path, BASE_IMAGE=base, COMMAND="pkg", IMAGE="docker-ros-test/never:1")
    result = docker_ros(tmp_path, "build")
    assert result.returncode != 0
    line = result.stdout.strip().splitlines()[-1]
    assert f"BASE_IMAGE '{base}' is neither a local image nor pullable (" in line, \
        result.stdout[-3000:]
    hint = f": did you mean the local image {ros1_base_image}? Else check the name;"
    assert (hint in line) if typo else ("did you mean" not in line and ": check the name;" in line)
    assert "[internal]" not in result.stdout  # refused before BuildKit starts
    assert not image_exists("docker-ros-test/never:1")


@pytest.mark.parametrize(
    "case, step, needles",
    [
        ("custom", "custom", ["docker/custom.sh", "exit code 3",
                              "; it stopped at line 2: `sh -c 'exit 3'` (exit code 3)"]),
        # a rule of the repository's resolving to a package apt does not have: the key named
        ("rosdep-rule", "rosdep", ["apt has no package no-such-deb-of-a-rule (rosdep key "
                                   "my_sdk of needs_sdk)"]),
        # the compiler's error line itself, with the file as the repository has it
        ("colcon", "colcon", ["package broken_pkg failed to build (exit code 2): "
                              "broken_pkg/src/main.cpp:1:", ": error: "]),
        # a typo of an installed package's name (the base's Debian ROS): that one is named
        ("command", "command", ["`rosrun rostopik node`: package rostopik is not in the run "
                                "image: neither built in the workspace nor installed; did you "
                                "mean rostopic? (", "`pkg_typo` is not a program on PATH"]),
    ],
)
def test_failing_step_names_step_and_cause_and_tags_nothing(
    ros1_base_image: str, tmp_path: Path, case: str, step: str, needles: list
) -> None:
    """One real failing build per kind of failure whose cause only an image shows (a user's
    script, real rosdep and apt, real colcon and g++, the run image's packages): the last line
    names the step and the cause, and the run image is not tagged. TARGET=run alone: the
    failure is the run image's only (with dev,run in one bake, whether BuildKit had tagged dev
    before run failed was a race, and the test took either; the note naming a tagged dev image:
    tests/unit/test_failure_notes.py). The wording of the debs step's and of rosdep's
    unresolved-key messages: unit tests (see the module docstring)."""
    tag = f"docker-ros-test/bad-{case}:1"
    remove_image(tag)
    command = "true"
    if case == "custom":
        cmake_package(tmp_path, "pkg")
        (tmp_path / "docker").mkdir()
        (tmp_path / "docker" / "custom.sh").write_text(
            "echo failing on purpose\nsh -c 'exit 3'\necho not reached\n")
    elif case == "rosdep-rule":
        cmake_package(tmp_path, "needs_sdk", depends=("my_sdk",))
        (tmp_path / "docker").mkdir()
        (tmp_path / "docker" / "rosdep.yaml").write_text(
            "my_sdk:\n  debian: [no-such-deb-of-a-rule]\n  ubuntu: [no-such-deb-of-a-rule]\n")
    elif case == "command":
        # the run image has pkg (a program on PATH) and rosrun, not the rest COMMAND names
        cmake_package(tmp_path, "pkg")
        command = "pkg && rosrun rostopik node; pkg_typo --now"
    else:
        cmake_package(tmp_path, "broken_pkg", body="int main() { this is not C++; }\n")
    write_env(tmp_path, BASE_IMAGE=ros1_base_image, COMMAND=command, IMAGE=tag, TARGET="run")
    result = docker_ros(tmp_path, "build")
    assert result.returncode != 0
    # the message: its first line, then the failing tool's own lines (host/faults.py)
    lines = result.stdout.strip().splitlines()
    first = max(i for i, line in enumerate(lines) if line.startswith("docker-ros build: "))
    last = "\n".join(lines[first:])
    assert f"building target 'run' (amd64) failed in step {step}" in lines[first], (
        result.stdout[-3000:])
    assert all(line.startswith("  ") for line in lines[first + 1:]), last
    for needle in needles:
        assert needle in last, last
    assert "was built" not in last, last
    assert not image_exists(tag)


def test_command_check_can_be_turned_off(ros1_base_image: str, tmp_path: Path) -> None:
    """ENABLE_COMMAND_CHECK=false: the run image of a COMMAND the check refuses is built and
    tagged, as docker-ros would (the way out should the check be wrong about an image)."""
    tag = "docker-ros-test/unchecked:1"
    remove_image(tag)
    cmake_package(tmp_path, "pkg")
    # (a COMMAND of its own: the RUN of the check never comes from an earlier run's cache)
    write_env(tmp_path, BASE_IMAGE=ros1_base_image,
              COMMAND=f"pkg && rosrun no_such_pkg node {uuid.uuid4().hex}", IMAGE=tag,
              ENABLE_COMMAND_CHECK="false")
    result = docker_ros(tmp_path, "build")
    assert result.returncode == 0, result.stdout[-3000:]
    assert "command: not checked (ENABLE_COMMAND_CHECK=false)" in result.stdout
    assert image_exists(tag)
    remove_image(tag)


def test_build_until_a_step_stops_there(ros1_base_image: str, tmp_path: Path) -> None:
    cmake_package(tmp_path, "pkg")
    (tmp_path / "docker").mkdir()
    (tmp_path / "docker" / "additional-debs.txt").write_text("jq\n")
    write_env(tmp_path, BASE_IMAGE=ros1_base_image, COMMAND="pkg", IMAGE="docker-ros-test/until:1")
    result = docker_ros(tmp_path, "build", "--until", "debs")
    assert result.returncode == 0, result.stdout[-3000:]
    assert "Starting >>> colcon" not in result.stdout
    tag = "docker-ros-test/until:1-until-debs"
    state = sh(tag, "jq --version && ls .docker-ros/debs.json && ls /docker-ros/ws")
    assert state.returncode == 0, state.stderr
    assert "install" not in state.stdout.split()
    assert not image_exists("docker-ros-test/until:1")
    bad = docker_ros(tmp_path, "build", "--until", "nope")
    assert bad.returncode != 0 and "--until 'nope': use one of clone" in bad.stdout
