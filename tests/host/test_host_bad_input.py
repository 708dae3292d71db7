"""Bad input on a real repository: caught before anything runs, one last line naming the
culprit and what to do (issue 11). The steps run as the image runs them (steps CLI)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.rosfixtures import free_port, make_package, tree_snapshot, write_repos

pytestmark = pytest.mark.host
SRC = Path(__file__).resolve().parents[2] / "src"


def run(args: list, cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if k not in ("TARGET", "COMMAND", "IMAGE")}
    full.update({"PYTHONPATH": str(SRC), **(env or {})})
    return subprocess.run([sys.executable, "-m", *args], cwd=cwd, env=full,
                          capture_output=True, text=True, timeout=300)


def last_line(proc: subprocess.CompletedProcess) -> str:
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc.stderr.strip().splitlines()[-1]


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    repo = tmp_path / "repo"
    make_package(repo / "pkg_a", "pkg_a")
    (repo / ".env").write_text(f"WORKSPACE={tmp_path / 'ws'}\nBASE_IMAGE=none:1\nCOMMAND=x\n")
    return repo


def test_files_dir_symlinked_to_etc_is_refused_on_host_and_in_image_steps(repo: Path,
                                                                          tmp_path: Path) -> None:
    (repo / "docker").mkdir()
    (repo / "docker" / "additional-files").symlink_to("/etc")
    before = tree_snapshot(repo)
    for args in (["docker_ros", "files"], ["docker_ros", "build"]):
        proc = run(args, repo)
        assert proc.returncode == 1, proc.stdout
        assert last_line(proc).endswith(
            "ADDITIONAL_FILES_DIR='docker/additional-files' leads to /etc through a symlink: "
            "give a path inside the repository"), proc.stderr
    assert not (tmp_path / "ws" / "additional-files").exists()
    # The step itself (as the image's resolve stage runs it) refuses too.
    ws = tmp_path / "image-ws"
    (ws / "src").mkdir(parents=True)
    (ws / "src" / "target").symlink_to(repo)
    proc = run(["docker_ros.in_image.steps", "files", "--workspace", str(ws),
                "--phase", "collect"], repo)
    assert proc.returncode == 1
    assert "leads to /etc through a symlink" in last_line(proc)
    assert not (ws / ".docker-ros" / "additional-files" / "passwd").exists()
    assert tree_snapshot(repo) == before


def test_build_context_and_image_checked_before_buildkit(repo: Path, tmp_path: Path) -> None:
    missing = run(["docker_ros", "build", "--build-context", str(tmp_path / "nope")], repo)
    assert missing.returncode == 1
    assert f"BUILD_CONTEXT '{tmp_path / 'nope'}' is not a folder" in last_line(missing)
    bad = run(["docker_ros", "build"], repo, env={"IMAGE": "My Robot:v1"})
    assert bad.returncode == 1
    assert "IMAGE_NAME (from IMAGE): 'my robot' is not a valid image name" in last_line(bad)
    assert "#1 [internal]" not in bad.stdout  # BuildKit never started


def test_explicit_list_files_must_exist_defaults_stay_silent(repo: Path, tmp_path: Path) -> None:
    silent = run(["docker_ros", "clone"], repo)
    assert silent.returncode == 0, silent.stderr
    assert "no .repos files, nothing to import" in silent.stderr
    for env in ({"VCS_IMPORT_FILE": "deps.repos", "ENABLE_RECURSIVE_VCS_IMPORT": "false"},
                {"VCS_IMPORT_FILE": "deps.repos"}):
        proc = run(["docker_ros", "clone"], repo, env=env)
        assert proc.returncode == 1, proc.stderr
        assert "VCS_IMPORT_FILE 'deps.repos' not found in the repository" in last_line(proc)


@pytest.mark.parametrize("args", [["build", "--dry-run"], ["run", "--host", "--dry-run"],
                                  ["run", "--in-container", "--dry-run"]])
def test_missing_values_and_bad_paths_are_told_at_once(repo: Path, tmp_path: Path,
                                                       args: list) -> None:
    """A missing COMMAND and a wrong file name: one message names both (it took two runs)."""
    dotenv = f"WORKSPACE={tmp_path / 'ws'}\nBASE_IMAGE=none:1\n"
    (repo / ".env").write_text(dotenv + "ADDITIONAL_DEBS_FILE=debs.txt\n")
    proc = run(["docker_ros", *args], repo)
    assert proc.returncode == 1, proc.stderr
    said = proc.stderr.strip().splitlines()[-3:]
    assert said == [
        f"docker-ros {args[0]}: invalid configuration:",
        "  missing required configuration: COMMAND (set it in .env, the environment, "
        "invoke.yaml under docker_ros: or as flags)",
        "  ADDITIONAL_DEBS_FILE 'debs.txt' not found in the repository, but set explicitly: "
        "fix the path or unset it"], proc.stderr
    (repo / ".env").write_text(dotenv)
    alone = run(["docker_ros", *args], repo)
    assert last_line(alone).startswith(f"docker-ros {args[0]}: missing required configuration: "
                                       "COMMAND (set it in"), alone.stderr


def test_a_dev_shell_without_docker_is_one_line(repo: Path, tmp_path: Path) -> None:
    """No docker on PATH: the GPU runtime lookup ended in a FileNotFoundError traceback."""
    (tmp_path / "bin").mkdir()
    proc = run(["docker_ros", "dev-shell", "--dry-run"], repo,
               env={"PATH": str(tmp_path / "bin")})
    assert proc.returncode == 1
    assert last_line(proc) == ("docker-ros dev-shell: no `docker` command: install Docker "
                               "(scripts/setup.sh)")


def test_a_missing_extra_ca_certs_stops_the_dry_run_too(repo: Path) -> None:
    """EXTRA_CA_CERTS is a path on this machine: the build stopped on it, the dry run not."""
    proc = run(["docker_ros", "build", "--dry-run", "--extra-ca-certs", "/nonexistent/ca"], repo,
               env={"COMMAND": "true"})
    assert proc.returncode == 1, proc.stderr
    assert last_line(proc) == ("  EXTRA_CA_CERTS '/nonexistent/ca' not found: give a PEM file or "
                               "a folder of them"), proc.stderr


def test_duplicate_package_names_fail_before_anything_runs_naming_both(repo: Path,
                                                                       tmp_path: Path) -> None:
    make_package(repo / "copy" / "pkg_a", "pkg_a")
    for args in (["rosdep", "--dry-run"], ["build", "--dry-run"], ["config"]):
        proc = run(["docker_ros", *args], repo)
        assert proc.returncode == 1
        assert last_line(proc) == (
            "  two packages with the same name: pkg_a in copy/pkg_a and pkg_a (colcon cannot "
            "build both: remove one, or put a COLCON_IGNORE file in its folder)"), proc.stderr
        assert "#1 [internal]" not in proc.stdout  # BuildKit never started
    # A duplicate an imported repository brings: the collect phase stops (as in the image).
    ws = tmp_path / "image-ws"
    (ws / "src").mkdir(parents=True)
    (ws / "src" / "target").symlink_to(repo)
    proc = run(["docker_ros.in_image.steps", "rosdep", "--workspace", str(ws), "--phase",
                "collect"], repo)
    assert proc.returncode == 1
    assert last_line(proc) == (
        "docker-ros rosdep: two packages with the same name: pkg_a in src/target/copy/pkg_a and "
        "src/target/pkg_a (colcon cannot build both: remove one, or put a COLCON_IGNORE file in "
        "its folder)")


def test_dotenv_look_alike_warns_and_config_prints_invalid_values(repo: Path) -> None:
    with (repo / ".env").open("a") as env:
        env.write("ENABLE_RECURSIVE_VCS_IMPRT=false\nENABLE_SLIM=maybe\nROS_DOMAIN_ID=7\n")
    proc = run(["docker_ros", "config"], repo)
    assert ("unknown variable ENABLE_RECURSIVE_VCS_IMPRT ignored (did you mean "
            "ENABLE_RECURSIVE_VCS_IMPORT?)") in proc.stderr
    assert "ROS_DOMAIN_ID" not in proc.stderr
    assert proc.returncode == 1
    rows = {line.split()[0]: line.split() for line in proc.stdout.splitlines()}
    assert rows["ENABLE_SLIM"][1:] == ["maybe", ".env", "<-", "INVALID"]
    assert rows["COMMAND"][1:] == ["x", ".env"]
    assert "ENABLE_SLIM='maybe' is not a boolean" in last_line(proc)


def test_refused_git_connection_keeps_its_cause(repo: Path) -> None:
    write_repos(repo / ".repos", {"dep": {"type": "git", "version": "main",
                                          "url": f"git://127.0.0.1:{free_port()}/dep.git"}})
    proc = run(["docker_ros", "clone"], repo)
    assert proc.returncode != 0
    line = last_line(proc)
    assert line.startswith("docker-ros clone: vcs import of ") and "repository 'dep'" in line
    assert line.endswith("errno=Connection refused"), line  # on the host: no BUILD_NETWORK hint


def test_crlf_hook_says_so(repo: Path) -> None:
    (repo / "docker").mkdir()
    (repo / "docker" / "before_dependency_installation.sh").write_bytes(
        b"set -e\r\necho hook\r\n")
    proc = run(["docker_ros", "scripts"], repo)
    assert proc.returncode != 0
    assert "the script has Windows (CRLF) line endings" in last_line(proc), proc.stderr


@pytest.mark.parametrize("task,flag,variable", [
    ("build", "--git-https-password", "GIT_HTTPS_PASSWORD"),
    ("clone", "--git-ssh-private-key", "GIT_SSH_PRIVATE_KEY"),
    ("push", "--registry-password", "REGISTRY_PASSWORD"),
])
def test_a_secret_given_as_a_flag_says_where_it_goes(repo: Path, task: str, flag: str,
                                                     variable: str) -> None:
    for args in ([flag, "hunter2"], [f"{flag}=hunter2"], [flag]):
        proc = run(["docker_ros", task, *args], repo)
        assert proc.returncode == 2, proc.stderr
        assert last_line(proc) == (
            f"docker-ros {task}: {flag}: a secret is never a flag (a command line is visible to "
            f"every process on this machine); set {variable} in the environment or in the "
            "project's .env file")
        assert "hunter2" not in proc.stdout + proc.stderr
    shown = run(["docker_ros", task, "--help"], repo, env={"COLUMNS": "200"})
    assert shown.returncode == 0
    assert flag not in shown.stdout and "secret" not in shown.stdout  # (--help shows none)


def test_bad_volume_and_slim_args_are_refused_before_any_build(repo: Path) -> None:
    """BASE_IMAGE=none:1 cannot be built: each message below comes before the build would."""
    proc = run(["docker_ros", "dev-shell", "--volume", "bad:::"], repo)
    assert proc.returncode == 1
    assert last_line(proc) == (
        "docker-ros dev-shell: --volume 'bad:::': 3 ':' (one or two belong); use "
        "HOST:CONTAINER[:MODE], e.g. ./data:/data:ro or a volume name, ccache:/ccache")
    # (a name push can push: one without a namespace is refused before, see below)
    unknown = {"ADDITIONAL_SLIM_BUILD_ARGS": "--unknown", "IMAGE": "me/repo:1"}
    for args in (["build", "--enable-slim"], ["build", "--target", "slim"], ["push"], ["slim"],
                 ["ci"]):
        proc = run(["docker_ros", *args], repo, env=unknown)
        assert proc.returncode == 1, args
        assert last_line(proc).startswith(
            f"docker-ros {args[0]}: ADDITIONAL_SLIM_BUILD_ARGS: unknown "
            "option(s) --unknown; supported: --include-path"), (args, proc.stderr)
    # checked only where the run image is slimmed
    unslimmed = run(["docker_ros", "build", "--dry-run"], repo, env={**unknown, "ENABLE_SLIM": "0"})
    assert unslimmed.returncode == 0, unslimmed.stderr


def test_unreadable_dotenv_line_stops_naming_the_file_and_line(repo: Path) -> None:
    """By line and name, never the line's text: it may be a secret with an unclosed quote."""
    with (repo / ".env").open("a") as env:
        env.write('THIS IS NOT VALID\nexport GIT_HTTPS_PASSWORD="s3cr3t-env\nENABLE_SLIM=1\n')
    for task in ("config", "build"):
        proc = run(["docker_ros", task, "--dry-run"] if task == "build" else ["docker_ros", task],
                   repo)
        assert proc.returncode == 1
        assert last_line(proc) == (
            f"docker-ros {task}: {repo / '.env'}: line 4: cannot read it (no NAME=VALUE); "
            "line 5: cannot read the value of GIT_HTTPS_PASSWORD: write NAME=VALUE (quote a "
            "value with spaces or #, and close the quotes)")
        assert "s3cr3t-env" not in proc.stdout + proc.stderr


def test_a_flag_value_of_the_wrong_type_is_one_line(repo: Path) -> None:
    """invoke's parser turns `--seconds abc` into a ValueError traceback; ours is one line."""
    (repo / "tasks.py").write_text("from docker_ros.tasks import ns  # noqa: F401\n")
    for program in ("docker_ros", "invoke"):
        proc = run([program, "example", "--seconds", "abc"], repo)
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.strip() == (
            "docker-ros example: --seconds takes a whole number, not 'abc'"), program


def test_invoke_yaml_that_is_no_yaml_or_no_mapping_is_one_line(repo: Path) -> None:
    (repo / "invoke.yaml").write_text("docker_ros: [1, 2\n")
    proc = run(["docker_ros", "config"], repo)
    assert proc.returncode == 2
    assert last_line(proc) == ("docker-ros: invoke.yaml (line 2) is not valid YAML: expected ',' "
                               "or ']', but got '<stream end>': fix or remove it")
    # `inv` over the one-line tasks.py reads invoke.yaml itself, after importing it
    (repo / "tasks.py").write_text("from docker_ros.tasks import ns  # noqa: F401\n")
    proc = run(["invoke", "config"], repo)
    assert proc.returncode == 2
    assert last_line(proc) == (f"docker-ros: {repo / 'invoke.yaml'} (line 2) is not valid YAML: "
                               "expected ',' or ']', but got '<stream end>': fix or remove it")
    (repo / "invoke.yaml").write_text("docker_ros: 5\n")
    proc = run(["docker_ros", "config"], repo)
    assert proc.returncode == 1
    assert last_line(proc) == ("docker-ros config: invoke configuration: `docker_ros:` is 5: give "
                               "it the settings as NAME: value lines")
    # `docker-ros:` (as the program is called): its image_tag was ignored without a word
    (repo / "invoke.yaml").write_text("docker-ros:\n  image_tag: v1\n")
    proc = run(["docker_ros", "build", "--dry-run"], repo)
    assert proc.returncode == 1
    assert last_line(proc) == ("docker-ros build: invoke configuration: `docker-ros:` is not "
                               "read; the settings go under `docker_ros:`")


def test_a_folder_where_a_file_belongs_is_named_so(repo: Path) -> None:
    (repo / "docker" / "blacklisted-packages.txt").mkdir(parents=True)
    for args in (["blacklist", "--dry-run"], ["build", "--dry-run"]):
        proc = run(["docker_ros", *args], repo)
        assert proc.returncode == 1
        assert last_line(proc).endswith(
            "BLACKLISTED_PACKAGES_FILE 'docker/blacklisted-packages.txt' is a folder, not a "
            "file: give the path of a file"), proc.stderr


def test_a_repos_file_vcstool_cannot_read_is_caught_before_anything_runs(repo: Path,
                                                                          tmp_path: Path) -> None:
    (repo / ".repos").write_text("repositories:\n  dep:\n    type: git\n   url: x\n")
    for args in (["clone", "--dry-run"], ["build", "--dry-run"], ["config"]):
        proc = run(["docker_ros", *args], repo)
        assert proc.returncode == 1
        assert last_line(proc).strip().startswith(
            "VCS_IMPORT_FILE .repos:4:4: not valid YAML: expected <block end>"), proc.stderr
        assert last_line(proc).endswith("fix the file (vcstool cannot import it)")
    # The step itself (as the image runs it) names the file in the workspace, not a path of
    # this machine.
    ws = tmp_path / "image-ws"
    (ws / "src").mkdir(parents=True)
    (ws / "src" / "target").symlink_to(repo)
    proc = run(["docker_ros.in_image.steps", "clone", "--workspace", str(ws)], repo)
    assert proc.returncode == 1
    assert last_line(proc).startswith(
        "docker-ros clone: src/target/.repos is not a .repos file vcstool can read:"), proc.stderr
    assert last_line(proc).endswith(": fix the file")


def test_config_marks_what_a_build_misses_and_still_shows_the_table(repo: Path) -> None:
    (repo / ".env").write_text("TARGET=dev,run\n")
    proc = run(["docker_ros", "config"], repo)
    assert proc.returncode == 0, proc.stderr
    rows = {line.split()[0]: line for line in proc.stdout.splitlines()}
    assert rows["BASE_IMAGE"].endswith("<- MISSING (a build needs it)")
    assert rows["COMMAND"].endswith("<- MISSING (a build needs it)")


@pytest.mark.parametrize("where,said", [
    (".", "is inside the repository"),
    ("pkg_a", "is inside the repository"),
    ("..", "holds the repository"),
    ("../user-folder", "holds other files (notes.txt) and is no docker-ros workspace"),
    ("../colcon-ws", "holds other files (src) and is no docker-ros workspace"),
])
def test_workspace_of_the_users_files_is_refused_and_nothing_is_written(
        repo: Path, tmp_path: Path, where: str, said: str) -> None:
    """The host steps write src/, .docker-ros/ and additional-files/ into WORKSPACE: in the
    repository, around it or in a folder of other files they would change the user's files
    (measured: `files --workspace .` overwrote the repository's additional-files/)."""
    (repo / "additional-files").mkdir()
    (repo / "additional-files" / "config.yaml").write_text("the user's\n")
    (repo / "docker" / "additional-files").mkdir(parents=True)
    (repo / "docker" / "additional-files" / "config.yaml").write_text("the image's\n")
    (tmp_path / "user-folder").mkdir()
    (tmp_path / "user-folder" / "notes.txt").write_text("the user's\n")
    make_package(tmp_path / "colcon-ws" / "src" / "theirs", "theirs")  # a colcon workspace
    before, around = tree_snapshot(repo), tree_snapshot(tmp_path / "user-folder")
    workspace = (repo / where).resolve()
    for args in (["files"], ["clone", "--dry-run"]):
        proc = run(["docker_ros", *args, "--workspace", str(workspace)], repo)
        assert proc.returncode == 1, proc.stdout
        assert f"WORKSPACE '{workspace}' {said}" in last_line(proc)
    assert tree_snapshot(repo) == before
    assert tree_snapshot(tmp_path / "user-folder") == around
    assert not (tmp_path / "src").exists()


def test_a_new_empty_or_docker_ros_workspace_is_used(repo: Path, tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    (tmp_path / "tested" / "test-results").mkdir(parents=True)  # `inv test` made only these
    for folder in ("new", "empty", "tested", "new"):  # "new" again: one of ours (src/target)
        proc = run(["docker_ros", "files", "--workspace", str(tmp_path / folder)], repo)
        assert proc.returncode == 0, proc.stderr
        assert (tmp_path / folder / "src" / "target").resolve() == repo.resolve()


def test_a_folder_with_nothing_to_build_is_refused(tmp_path: Path) -> None:
    """No package.xml, no .repos and no docker-ros input file: a wrong folder, refused before
    anything runs (measured before: the build tagged an image whose COMMAND was not found)."""
    folder = tmp_path / "notes"
    folder.mkdir()
    (folder / "README.txt").write_text("not a ROS repository\n")
    env = {"BASE_IMAGE": "none:1", "COMMAND": "x", "WORKSPACE": str(tmp_path / "ws")}
    for args in (["build", "--dry-run"], ["clone"]):
        proc = run(["docker_ros", *args], folder, env)
        assert proc.returncode == 1, proc.stdout
        assert last_line(proc).strip() == (
            f"BUILD_CONTEXT '{folder}' holds no ROS package (package.xml), no .repos file and "
            "none of docker-ros's input files: run this in your ROS repository, or set "
            "BUILD_CONTEXT to it")
    # An image of apt packages alone (no ROS package) is docker-ros's to build.
    (folder / "docker").mkdir()
    (folder / "docker" / "additional-debs.txt").write_text("procps\n")
    proc = run(["docker_ros", "build", "--dry-run"], folder, env)
    assert proc.returncode == 0, proc.stderr


def test_a_bare_set_and_an_empty_target_are_refused(repo: Path) -> None:
    for args in (["build", "--dry-run", "--set"], ["build", "--set", "--dry-run"],
                 ["build", "--dry-run", "--set", "ENABLE_SLIM=true", "--set"]):
        proc = run(["docker_ros", *args], repo)
        assert proc.returncode == 1, proc.stdout
        assert last_line(proc).strip() == "--set without a value: use --set NAME=VALUE"
    proc = run(["docker_ros", "build", "--dry-run", "--target", ","], repo)
    assert proc.returncode == 1, proc.stdout
    assert last_line(proc).strip() == ("TARGET=',' is empty: give one or more of dev, run, slim "
                               "(comma-separated), or leave it unset (from flag)")


def test_bad_base_image_and_slim_tag_stop_the_dry_run(repo: Path) -> None:
    proc = run(["docker_ros", "build", "--dry-run", "--base-image", "UPPER/img:tag",
                "--target", "dev"], repo)
    assert proc.returncode == 1, proc.stdout
    assert last_line(proc).strip() == (
        "BASE_IMAGE (flag): 'UPPER/img:tag' is not a valid image reference: give "
        "[registry/]name[:tag][@digest], the name in lower case")
    proc = run(["docker_ros", "build", "--dry-run", "--target", "run", "--enable-slim", "--set",
                "SLIM_IMAGE_TAG=bad tag!"], repo)
    assert proc.returncode == 1, proc.stdout
    assert last_line(proc).strip() == ("SLIM_IMAGE_TAG: 'bad tag!' is not a valid image tag: up "
                                       "to 128 letters, digits, _ . and -, not starting with . "
                                       "or -")
    assert "[dry-run]" not in proc.stdout


def test_an_unusable_workspace_or_results_dir_is_one_line(repo: Path) -> None:
    proc = run(["docker_ros", "clone", "--workspace", "/dev/null"], repo)
    assert proc.returncode == 1
    assert last_line(proc) == ("docker-ros clone: WORKSPACE '/dev/null' cannot be created/used: "
                               "Not a directory; give a writable folder")
    proc = run(["docker_ros", "test", "--dry-run", "--set", "TEST_RESULTS_DIR=/dev/null/res"],
               repo)
    assert proc.returncode == 1
    assert last_line(proc) == ("docker-ros test: TEST_RESULTS_DIR (flag): /dev/null/res cannot be "
                               "made: /dev/null is not a folder; give a writable folder")


LATIN1 = "# café\n".encode("latin-1")


@pytest.mark.parametrize("file, args", [
    (".env", ["docker_ros", "config"]),
    ("invoke.yaml", ["docker_ros", "build", "--dry-run"]),
    ("invoke.yaml", ["invoke", "build", "--dry-run"]),
    (".repos", ["docker_ros", "clone", "--dry-run"]),
    ("docker/rosdep.yaml", ["docker_ros", "rosdep", "--dry-run"]),
    ("docker/additional-debs.txt", ["docker_ros", "debs", "--dry-run"]),
    ("docker/additional-pip-requirements.txt", ["docker_ros", "pip", "--dry-run"]),
    ("docker/blacklisted-packages.txt", ["docker_ros", "blacklist", "--dry-run"]),
])
def test_a_file_that_is_not_utf8_is_named(repo: Path, file: str, args: list) -> None:
    (repo / "tasks.py").write_text("from docker_ros.tasks import ns  # noqa: F401\n")
    (repo / "docker").mkdir()
    env = (repo / ".env").read_text()
    content = (env + "# café\n").encode("utf-16") if file == ".env" else LATIN1  # (PowerShell)
    (repo / file).write_bytes(content)
    proc = run(args, repo)
    assert proc.returncode in (1, 2), proc.stdout
    reason = "invalid start byte at byte 0" if file == ".env" else "invalid continuation byte " \
        "at byte 5"
    assert f"{file} is not UTF-8 text ({reason}): save it as UTF-8" in last_line(proc)


@pytest.mark.parametrize("args", [["docker_ros", "build", "--dry-run"],
                                  ["invoke", "build", "--dry-run"]])
def test_an_invoke_yaml_whose_top_level_is_a_list_is_one_line(repo: Path, args: list) -> None:
    (repo / "tasks.py").write_text("from docker_ros.tasks import ns  # noqa: F401\n")
    (repo / "invoke.yaml").write_text("- just\n")
    proc = run(args, repo)
    assert proc.returncode == 2
    assert last_line(proc).endswith("invoke.yaml: the top level must be a mapping (key "
                                    "docker_ros:)")


@pytest.mark.parametrize("args", [["docker_ros", "config"], ["invoke", "config"]])
def test_an_invoke_yaml_key_given_twice_in_two_cases_is_one_line(repo: Path, args: list) -> None:
    """invoke's environment loader refused it with a traceback (two keys, one variable)."""
    (repo / "tasks.py").write_text("from docker_ros.tasks import ns  # noqa: F401\n")
    (repo / "invoke.yaml").write_text("docker_ros:\n  image_tag: a\n  IMAGE_TAG: b\n")
    proc = run(args, repo)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert last_line(proc) == ("docker-ros: invoke.yaml: image_tag is given twice under "
                               "docker_ros: (keys that differ in case only, as image_tag and "
                               "IMAGE_TAG, are one setting): keep one")


def test_push_of_a_name_docker_hub_refuses_stops_before_the_build(repo: Path) -> None:
    with (repo / ".env").open("a") as env:
        env.write("IMAGE=my-image:latest\n")
    proc = run(["docker_ros", "push"], repo)
    assert proc.returncode == 1
    assert last_line(proc).startswith("docker-ros push: IMAGE_NAME 'my-image' names no registry "
                                      "and no namespace: docker would push it to "
                                      "docker.io/library/my-image")
    assert "==> docker-ros build" not in proc.stdout  # (nothing built)


def test_bootstrap_base_image_names_a_bad_flavor_or_ca_bundle_before_debootstrap(
        tmp_path: Path) -> None:
    """Both stop at once (no debootstrap, no image): one line naming the option and what to
    give."""
    flavor = run(["docker_ros", "bootstrap-base-image", "--flavor", "ros3"], tmp_path)
    assert flavor.returncode == 1
    assert last_line(flavor).endswith("--flavor 'ros3': use one of ros1, ros2, ros1-ubuntu")
    missing = tmp_path / "no-such-ca.pem"
    ca = run(["docker_ros", "bootstrap-base-image", "--flavor", "ros1-ubuntu",
              "--extra-ca-certs", str(missing), "--tag", "docker-ros-test/never:1"], tmp_path)
    assert ca.returncode == 1
    assert last_line(ca).endswith(f"EXTRA_CA_CERTS '{missing}' not found: give a PEM file or a "
                                  "folder of them")
