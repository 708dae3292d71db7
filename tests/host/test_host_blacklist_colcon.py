"""blacklist, colcon and command with real colcon/cmake builds of cmake packages."""

import logging
import re
import subprocess

import pytest

from docker_ros.in_image.runtime.workspace import StepError
from docker_ros.in_image.steps import blacklist, colcon, command
from tests.rosfixtures import make_package, tree_snapshot

pytestmark = pytest.mark.host

GREETING_CPP = """\
#include <cstdio>
int main() { std::printf("%s\\n", GREETING); return 0; }
"""
GREETING_CMAKE = 'target_compile_definitions(greeter_node PRIVATE GREETING="${GREETING}")\n'


@pytest.fixture
def packages(project):
    make_package(project.repo / "base_pkg", "base_pkg")
    make_package(
        project.repo / "greeter",
        "greeter",
        depends=["base_pkg"],
        cpp_source=GREETING_CPP,
        cmake_extra=GREETING_CMAKE,
    )
    make_package(project.repo / "nested" / "unwanted", "unwanted", depends=["tree_key"])
    (project.repo / "docker").mkdir()
    (project.repo / "docker" / "blacklisted-packages.txt").write_text(
        "# not needed in images\nunwanted   \n\nno_such_package # typo\n"
    )
    return project


def test_blacklist_records_packages_and_warns_about_unknown_names(packages, caplog):
    before = tree_snapshot(packages.repo)
    caplog.set_level(logging.INFO)

    blacklist.main(packages.ws, packages.settings())

    data = packages.ws.read_state("blacklist.json")
    assert data == {
        "names": ["no_such_package", "unwanted"],
        "packages": {"unwanted": ["src/target/nested/unwanted"]},
        "unknown": ["no_such_package"],
    }
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert any("no_such_package" in r.getMessage() for r in warnings)
    assert tree_snapshot(packages.repo) == before


def test_recursive_blacklist_files(packages):
    (packages.repo / "nested" / "blacklisted-packages.txt").write_text("greeter\n")
    settings = packages.settings(enable_recursive_blacklisted_packages="true")
    blacklist.main(packages.ws, settings)
    assert sorted(packages.ws.read_state("blacklist.json")["packages"]) == ["greeter", "unwanted"]


def test_colcon_builds_with_cmake_args_and_ignores_blacklisted(packages):
    settings = packages.settings(cmake_args="-DCMAKE_BUILD_TYPE=Release '-DGREETING=hello world'")
    blacklist.main(packages.ws, settings)
    before = tree_snapshot(packages.repo)

    colcon.main(packages.ws, settings)

    install = packages.ws.install
    assert (install / "base_pkg" / "bin" / "base_pkg_node").is_file()
    assert not (install / "unwanted").exists()
    out = subprocess.run(
        [str(install / "greeter" / "bin" / "greeter_node")],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert out == "hello world\n"
    assert tree_snapshot(packages.repo) == before  # build/install/log are outside the repo

    # command: runs in the sourced workspace (install/setup.bash puts the nodes on PATH).
    out_file = packages.ws.root / "out.txt"
    settings = packages.settings(
        command=f"greeter_node > {out_file} && echo $COLCON_PREFIX_PATH >> {out_file}"
    )
    command.main(packages.ws, settings)
    assert out_file.read_text() == f"hello world\n{install}\n"


def test_colcon_failure_names_the_package(packages):
    make_package(packages.repo / "broken", "broken_pkg", cpp_source="int main( { syntax error\n")
    with pytest.raises(StepError) as err:
        colcon.main(packages.ws, packages.settings())
    assert "broken_pkg" in err.value.message
    assert err.value.returncode != 0
    # the compiler's first error line, with the file and line, is in the message itself
    assert re.search(r"failed to build \(exit code 2\): broken/\w+\.cpp:1:\d+: error: ",
                     err.value.message), err.value.message


def test_a_missing_cmake_package_is_named_with_cmakes_error(packages):
    make_package(packages.repo / "lost", "lost_pkg",
                 cmake_extra="find_package(no_such_dep_docker_ros REQUIRED)\n")
    with pytest.raises(StepError) as err:
        colcon.main(packages.ws, packages.settings())
    assert "package lost_pkg failed to build" in err.value.message
    assert "CMake Error at CMakeLists.txt:" in err.value.message, err.value.message
    assert '"no_such_dep_docker_ros"' in err.value.message, err.value.message


def test_command_exit_code_is_the_steps(project):
    # Nothing built, no /opt/ros here: missing setup files are tolerated.
    with pytest.raises(StepError) as err:
        command.main(project.ws, project.settings(command='test -z "$NOPE" && exit 5'))
    assert err.value.returncode == 5
    assert "COMMAND" in err.value.message


def test_command_collect_runs_nothing_and_accepts_a_dev_only_build(project):
    command.main(project.ws, project.settings(command="false"), phase="collect")
    command.main(project.ws, project.settings(), phase="collect")  # dev only: no COMMAND
    with pytest.raises(StepError) as err:
        command.main(project.ws, project.settings())
    assert "COMMAND is not set" in err.value.message


def test_colcon_dry_run_builds_nothing(packages, capsys):
    colcon.main(packages.ws, packages.settings(cmake_args="-DX=1 --trace"), dry_run=True)
    out = capsys.readouterr().out
    assert (
        "[dry-run] colcon: colcon build --base-paths src --event-handlers console_cohesion+"
        " --packages-ignore unwanted"
        " --cmake-args -DX=1 ' --trace'" in out
    )
    assert not packages.ws.install.exists()
    assert not packages.ws.state.exists()


def test_colcon_takes_the_dev_shells_defaults_merged_with_the_users(tmp_path):
    """What `inv dev-shell` gives colcon when the user passes a colcon defaults file of the
    repository (--env COLCON_DEFAULTS_FILE=...): real colcon reads the merged file, ignores
    the blacklisted package and the user's own ignored one, and keeps the user's settings."""
    import os

    from docker_ros.host import devshell

    repo = tmp_path / "repo"
    for name in ("keep_me", "blacklisted", "users_ignored"):
        make_package(repo / name, name)
    (repo / "colcon-defaults.yaml").write_text(
        "list:\n  packages-ignore: [users_ignored]\n  names-only: true\n")
    options = devshell.ShellOptions(
        env=(f"COLCON_DEFAULTS_FILE={devshell.TARGET}/colcon-defaults.yaml",))
    shell, warning = devshell.shell_colcon_defaults(["blacklisted"], options, repo, tmp_path,
                                                    {}, tmp_path / "ours.yaml")
    assert "is merged" in warning and shell.env == []
    listed = subprocess.run(["colcon", "list", "--base-paths", str(repo)], cwd=tmp_path,
                            capture_output=True, text=True, check=True,
                            env={**os.environ, "COLCON_DEFAULTS_FILE": shell.colcon_defaults})
    assert listed.stdout.split() == ["keep_me"]  # names only: the user's setting
