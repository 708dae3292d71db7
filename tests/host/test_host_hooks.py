"""scripts and custom: hook scripts copied into the state, run with bash, failures named."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from docker_ros.in_image.runtime.workspace import StepError
from docker_ros.in_image.steps import custom, scripts
from tests.processes import left_after
from tests.rosfixtures import make_package, tree_snapshot

SRC = Path(__file__).resolve().parents[2] / "src"

pytestmark = pytest.mark.host


def write(path, text):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_scripts_run_in_order_from_the_workspace_root(project, tmp_path, environ):
    """docker-ros's WORKDIR, as in images: a hook's relative writes stay out of the repository
    (they ran in the script's folder on the host)."""
    log = tmp_path / "log.txt"
    environ({"HOOK_LOG": str(log)})
    write(
        project.repo / "docker" / "before_dependency_installation.sh",
        'echo "top $(basename "$PWD")" >> "$HOOK_LOG"\n',
    )
    write(
        project.repo / "pkg" / "before_dependency_installation.sh",
        'echo "nested $(basename "$PWD")" >> "$HOOK_LOG"\n',
    )
    before = tree_snapshot(project.repo)
    settings = project.settings(enable_recursive_before_dependency_installation_script="true")

    scripts.main(project.ws, settings)

    assert log.read_text() == f"top {project.ws.root.name}\nnested {project.ws.root.name}\n"
    assert project.ws.read_state("scripts.json") == {
        "hooks": [
            {
                "file": "hooks/scripts/01-before_dependency_installation.sh",
                "source": "src/target/docker/before_dependency_installation.sh",
            },
            {
                "file": "hooks/scripts/02-before_dependency_installation.sh",
                "source": "src/target/pkg/before_dependency_installation.sh",
            },
        ]
    }
    assert tree_snapshot(project.repo) == before


def test_custom_failure_names_original_script_and_exit_code(project):
    script = write(project.repo / "docker" / "custom.sh", "true\nfalse\necho not reached\n")
    with pytest.raises(StepError) as err:
        custom.main(project.ws, project.settings())
    assert "src/target/docker/custom.sh" in err.value.message
    assert str(script) not in err.value.message  # the image's path, not this machine's
    assert "exit code 1" in err.value.message
    assert err.value.step == "custom"

    write(project.repo / "docker" / "custom.sh", "exit 42\n")
    with pytest.raises(StepError) as err:
        custom.main(project.ws, project.settings())
    assert err.value.returncode == 42 and "exit code 42" in err.value.message


def test_failure_names_the_line_and_command_that_stopped_the_script(project, tmp_path, environ):
    """Under bash -e the error says which line stopped the hook, in the repository's file, also
    for a failure in a function or in a file the hook sources; a script that runs on after a
    failure (`set +e`) ends as before, and a user's own BASH_ENV is still read."""
    def failure(text: str) -> str:
        write(project.repo / "docker" / "custom.sh", text)
        with pytest.raises(StepError) as err:
            custom.main(project.ws, project.settings())
        return err.value.message

    message = failure('echo start\nx=$(false; echo hi)\nfalse || true\n'
                      'grep -q "no such text" /etc/hostname\necho not reached\n')
    assert "src/target/docker/custom.sh failed with exit code 1" in message
    assert message.endswith('; it stopped at line 4: `grep -q "no such text" /etc/hostname` '
                            "(exit code 1)"), message
    message = failure("install() {\n  echo installing\n  ls /no/such/dir\n}\ninstall\n")
    assert message.endswith("; it stopped at line 3: `ls /no/such/dir` (exit code 2)"), message
    sourced = write(tmp_path / "common.sh", "echo common\n\ntest -d /no/such/dir\n")
    assert failure(f"echo first\nsource {sourced}\n").endswith(
        f"; it stopped at line 3 of {sourced}: `test -d /no/such/dir` (exit code 1)")
    assert "stopped at" not in failure("set +e\nfalse\nexit 3\n")

    own = write(tmp_path / "own-env.sh", "export FROM_USER_ENV=yes\n")
    environ({"BASH_ENV": str(own)})
    message = failure('test "$FROM_USER_ENV" = yes && false\n')
    assert "exit code 1" in message and "stopped at" not in message


def test_apply_runs_from_state_without_sources(project, tmp_path, environ):
    """The image's install stage: collect copied the hook; the sources are gone. It runs in
    the workspace root, docker-ros's WORKDIR (the state directory is not in the run image)."""
    out = tmp_path / "cwd.txt"
    environ({"HOOK_OUT": str(out)})
    write(project.repo / "docker" / "custom.sh", 'pwd > "$HOOK_OUT"\n')
    custom.main(project.ws, project.settings(), phase="collect")
    project.ws.target.unlink()

    custom.main(project.ws, project.settings(), phase="apply")

    assert out.read_text().strip() == str(project.ws.root)


def test_apply_without_collect_says_what_to_do(project):
    with pytest.raises(StepError) as err:
        scripts.main(project.ws, project.settings(), phase="apply")
    assert "scripts.json" in err.value.message and "collect" in err.value.message


def test_no_script_and_dry_run(project, capsys, tmp_path):
    scripts.main(project.ws, project.settings())
    assert project.ws.read_state("scripts.json") == {"hooks": []}

    write(project.repo / "docker" / "custom.sh", "touch should-not-exist\n")
    snapshot = tree_snapshot(project.ws.root)
    custom.main(project.ws, project.settings(), dry_run=True)
    out = capsys.readouterr().out
    assert "[dry-run] custom: copy " in out
    assert "[dry-run] custom: bash -e " in out
    assert tree_snapshot(project.ws.root) == snapshot


def test_a_terminated_hook_leaves_nothing_it_started_running(tmp_path):
    """SIGTERM to the task alone (`kill`, a CI runner) while a hook waits on a command it
    started: the task ends as terminated (143), and the hook's command ends with it."""
    repo = tmp_path / "repo"
    make_package(repo / "pkg_a", "pkg_a")
    marker = tmp_path / "started"
    seconds = 30000 + os.getpid() % 1000  # a sleep of this run alone
    write(repo / "docker" / "before_dependency_installation.sh",
          f"sleep {seconds} &\ntouch {marker}\nwait\n")
    env = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    env.update(PYTHONPATH=str(SRC), WORKSPACE=str(tmp_path / "ws"))
    proc = subprocess.Popen([sys.executable, "-m", "docker_ros", "scripts"], cwd=repo, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not marker.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert marker.exists(), "the hook never started"
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, out + err
    assert not left_after(f"sleep {seconds}"), "the hook's command outlived the task"


def test_a_relative_workspace_is_the_callers(tmp_path):
    """WORKSPACE=../ws from the repository: vcs import and the hooks run in other folders, where
    the relative paths named nothing (`can't open '../ws/src/target/.repos'`)."""
    from tests.rosfixtures import make_git_repo, write_repos

    repo = tmp_path / "repo"
    make_package(repo / "pkg_a", "pkg_a")
    url = make_git_repo(tmp_path / "remotes" / "lib_a", {"README": "a\n"})
    write_repos(repo / ".repos", {"lib_a": {"url": url, "version": "main"}})
    write(repo / "docker" / "custom.sh", "echo custom ran in $(pwd)\n")
    env = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    env.update(PYTHONPATH=str(SRC), WORKSPACE="../ws")
    for step in ("clone", "custom"):
        proc = subprocess.run([sys.executable, "-m", "docker_ros", step], cwd=repo, env=env,
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stdout + proc.stderr
    assert (tmp_path / "ws" / "src" / "upstream" / "lib_a" / "README").is_file()
    assert "custom ran in /" in proc.stdout + proc.stderr
