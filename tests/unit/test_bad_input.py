"""Bad input caught before the build, one line naming the culprit (issue 11): the pure checks."""

import io
import logging
from pathlib import Path
from types import SimpleNamespace

import pytest
from docker.errors import APIError, NotFound
from dotenv import dotenv_values

from docker_ros.core import errors
from docker_ros.core.loading import has_bare_set, load_settings, parse_set
from docker_ros.core.settings import SettingsError, explicitly_set
from docker_ros.host import build, buildcontext, engine, refs
from docker_ros.host.config import (
    config_table,
    dotenv_warnings,
    image_problems,
    input_problems,
    path_problems,
    read_settings,
    repository_env_file,
    sourced_ros_overrides,
)
from docker_ros.host.pipeline import TaskError, check_slim_options, host_workspace
from docker_ros.in_image.runtime import pipinstall
from docker_ros.in_image.runtime.files import path_problem
from docker_ros.in_image.runtime.packages import (
    Package,
    duplicate_packages,
    duplicates_message,
)
from docker_ros.in_image.runtime.process import script_hint
from docker_ros.in_image.runtime.workspace import read_user_text
from docker_ros.in_image.steps import clone

TAG_RULE = ": up to 128 letters, digits, _ . and -, not starting with . or -"
NAME_RULE = (
    ": lower-case letters, digits and . _ - between /, after an optional registry host[:port]/")


def settings_for(repository: Path, **env: str):
    return load_settings(environ={"BUILD_CONTEXT": str(repository), **env},
                         project_dir=repository)


def test_path_problem_absolute_dotdot_and_symlinks(tmp_path: Path) -> None:
    (tmp_path / "docker").mkdir()
    (tmp_path / "docker" / "etc").symlink_to("/etc")
    (tmp_path / "docker" / "inside").symlink_to(tmp_path / "docker")
    assert path_problem(tmp_path, "/etc") == "is an absolute path"
    assert path_problem(tmp_path, "docker/../../x") == "leaves the repository through '..'"
    assert path_problem(tmp_path, "docker/etc") == "leads to /etc through a symlink"
    assert path_problem(tmp_path, "docker/etc/passwd") == "leads to /etc/passwd through a symlink"
    for fine in ("docker/inside", "docker/not-there.txt", "docker/../docker/x", ".repos", "."):
        assert path_problem(tmp_path, fine) is None, fine


def test_path_settings_outside_the_repository_are_named(tmp_path: Path) -> None:
    (tmp_path / "files").symlink_to("/etc")
    settings = settings_for(tmp_path, ADDITIONAL_FILES_DIR="files", ADDITIONAL_DEBS_FILE="/x",
                            VCS_IMPORT_FILE="../other.repos")
    problems = path_problems(settings)
    assert sorted(problems) == ["additional_debs_file", "additional_files_dir", "vcs_import_file"]
    assert problems["additional_files_dir"] == (
        "ADDITIONAL_FILES_DIR='files' leads to /etc through a symlink: give a path inside the "
        "repository")


def test_missing_build_context_is_named(tmp_path: Path) -> None:
    problems = path_problems(settings_for(tmp_path / "nope"))
    assert list(problems.values()) == [
        f"BUILD_CONTEXT '{tmp_path / 'nope'}' is not a folder: set it to the ROS repository to "
        "build"]


def test_explicitly_set_files_must_exist_defaults_may_be_absent(tmp_path: Path) -> None:
    assert path_problems(settings_for(tmp_path)) == {}
    # CI integrations pass every default on: a default value from the environment is no choice.
    ci = settings_for(tmp_path, VCS_IMPORT_FILE=".repos", ADDITIONAL_FILES_DIR="docker/"
                      "additional-files")
    assert not explicitly_set(ci, "vcs_import_file") and path_problems(ci) == {}
    problems = path_problems(settings_for(
        tmp_path, VCS_IMPORT_FILE="deps.repos", ENABLE_RECURSIVE_VCS_IMPORT="false",
        BLACKLISTED_PACKAGES_FILE="bl.txt", ADDITIONAL_FILES_DIR="files"))
    assert problems == {
        "vcs_import_file": "VCS_IMPORT_FILE 'deps.repos' not found in the repository, but set "
        "explicitly: fix the path or unset it",
        "blacklisted_packages_file": "BLACKLISTED_PACKAGES_FILE 'bl.txt' not found in the "
        "repository, but set explicitly: fix the path or unset it",
        "additional_files_dir": "ADDITIONAL_FILES_DIR 'files' not found in the repository, but "
        "set explicitly: fix the path or unset it",
    }
    # Recursive discovery may still find the file in imported repositories, when one of that
    # name is there to import them: the step decides. With none anywhere, nothing can.
    assert path_problems(settings_for(tmp_path, VCS_IMPORT_FILE="deps.repos")) == {
        "vcs_import_file": problems["vcs_import_file"]}
    (tmp_path / "third_party").mkdir()
    (tmp_path / "third_party" / "deps.repos").write_text("repositories: {}\n")
    assert "vcs_import_file" not in path_problems(settings_for(tmp_path,
                                                               VCS_IMPORT_FILE="deps.repos"))


def test_a_tag_from_a_flag_over_image_in_env_is_named_by_the_flags_variable(
        tmp_path: Path) -> None:
    """`--image-tag bad:tag` beats `IMAGE` of .env: the dev tag comes from IMAGE_TAG, not
    IMAGE."""
    settings = load_settings(dotenv={"IMAGE": "robot:v1"}, flags={"image_tag": "bad:tag"},
                             environ={"BUILD_CONTEXT": str(tmp_path)}, project_dir=tmp_path)
    # (DEV_IMAGE_TAG, from IMAGE_TAG, is the same mistake: told once)
    assert image_problems(settings, ("dev", "run")) == {
        "image_tag": "IMAGE_TAG: 'bad:tag' is not a valid image tag" + TAG_RULE}


def test_invalid_image_names_name_the_setting(tmp_path: Path) -> None:
    bad = settings_for(tmp_path, IMAGE="my robot:v1")
    assert image_problems(bad, ("run",)) == {
        "image_name": "IMAGE_NAME (from IMAGE): 'my robot' is not a valid image name" + NAME_RULE}
    tag = settings_for(tmp_path, IMAGE_NAME="ok/name", IMAGE_TAG="v1?")
    assert set(image_problems(tag, ("dev", "run"))) == {"image_tag"}
    assert "IMAGE_TAG: 'v1?' is not a valid image tag" + TAG_RULE in image_problems(
        tag, ("run",)).values()
    other = settings_for(tmp_path, IMAGE_TAG="v1?", DEV_IMAGE_TAG="dev?")  # set apart: both
    assert set(image_problems(other, ("dev", "run"))) == {"image_tag", "dev_image_tag"}
    digest = settings_for(tmp_path, IMAGE="x:latest@sha256:abc")
    assert image_problems(digest, ("run",))["image_name"].endswith(
        "(IMAGE takes name[:tag], no @digest)")
    folder = load_settings(environ={}, project_dir=Path("/tmp/My Robot"))
    assert "set IMAGE or IMAGE_NAME" in image_problems(folder, ("run",))["image_name"]
    for good in ("localhost:5000/a/b-c:1.0", "ghcr.io/org/repo_x:latest", "a__b/c.d:tag-1"):
        assert image_problems(settings_for(tmp_path, IMAGE=good), ("dev", "run")) == {}, good


def test_dotenv_look_alikes_warn_with_did_you_mean() -> None:
    warnings = dotenv_warnings({"ENABLE_RECURSIVE_VCS_IMPRT": "true", "ROS_DOMAIN_ID": "3",
                                "BASE_IMAGE": "x", "COMAND": "y"})
    assert warnings == [
        "unknown variable ENABLE_RECURSIVE_VCS_IMPRT ignored (did you mean "
        "ENABLE_RECURSIVE_VCS_IMPORT?)",
        "unknown variable COMAND ignored (did you mean COMMAND?)",
    ]
    # a shorter name: the one docker-ros name of the same first word, with one word more,
    # that has its words in order; the user's own variables stay silent
    warnings = dotenv_warnings({"ENABLE_RECURSIVE_PIP": "true", "GIT_PASSWORD": "s3cr3t",
                                "GIT_SSH_KEY": "k", "VCS_IMPORT": "x.repos",
                                "ROS_VERSION": "2", "ROS_DOMAIN_ID": "3", "DOCKER_HOST": "h",
                                "ENABLE_RECURSIVE": "true", "GIT_TOKEN": "t"})
    assert warnings == [
        "unknown variable ENABLE_RECURSIVE_PIP ignored (did you mean "
        "ENABLE_RECURSIVE_ADDITIONAL_PIP?)",
        "unknown variable GIT_PASSWORD ignored (did you mean GIT_HTTPS_PASSWORD?)",
        "unknown variable GIT_SSH_KEY ignored (did you mean GIT_SSH_PRIVATE_KEY?)",
        "unknown variable VCS_IMPORT ignored (did you mean VCS_IMPORT_FILE?)",
    ]


def test_dotenv_ci_only_variables_are_said_to_have_no_effect() -> None:
    """The Action's checkout inputs and the template's docker-ros ref are read before any
    .env: there, they were shown by `inv config` as if they applied."""
    assert dotenv_warnings({"ENABLE_CHECKOUT": "false", "DOCKER_ROS_GIT_REF": "v1.8.2",
                            "ENABLE_SLIM": "false"}) == [
        f"{key} has no effect in .env: it is read by the CI integrations only, as the GitHub "
        "Action's input or the GitLab template's variable"
        for key in ("ENABLE_CHECKOUT", "DOCKER_ROS_GIT_REF")]


def test_lenient_load_keeps_bad_values_for_config() -> None:
    with pytest.raises(SettingsError):
        load_settings(environ={"ENABLE_SLIM": "maybe"})
    settings = load_settings(environ={"ENABLE_SLIM": "maybe", "IMAGE_TAG": "v2"},
                             invoke_config={"imgae_tag": "x"}, lenient=True)
    assert settings.enable_slim is True and settings.image_tag == "v2"
    assert set(settings.problems) == {"enable_slim", "invoke.yaml:imgae_tag"}
    rows = {line.split()[0]: line.split() for line in config_table(settings).splitlines()}
    assert rows["ENABLE_SLIM"][1:] == ["maybe", "environment", "<-", "INVALID"]
    assert rows["IMAGE_TAG"][1:] == ["v2", "environment"]


def test_config_shows_where_the_tests_results_go_by_default(tmp_path: Path) -> None:
    """TEST_RESULTS_DIR unset: `inv config` shows the folder `inv test` writes to (in
    WORKSPACE), as it shows the other derived defaults; set, its value and source."""
    plain = load_settings(environ={"WORKSPACE": str(tmp_path / "ws")})
    rows = {line.split()[0]: line.split() for line in config_table(plain).splitlines()}
    assert rows["TEST_RESULTS_DIR"][1:4] == [str(tmp_path / "ws" / "test-results"), "derived",
                                             "from"]
    named = load_settings(environ={"WORKSPACE": str(tmp_path / "ws"),
                                   "TEST_RESULTS_DIR": str(tmp_path / "r")})
    rows = {line.split()[0]: line.split() for line in config_table(named).splitlines()}
    assert rows["TEST_RESULTS_DIR"][1:] == [str(tmp_path / "r"), "environment"]


def test_duplicate_packages_name_every_path() -> None:
    def package(name: str, path: str) -> Package:
        return Package(name, Path(path), 3, "cmake", {})

    found = [package("a", "src/target/a"), package("b", "src/target/b"),
             package("a", "src/upstream/x/a")]
    assert duplicate_packages(found) == {"a": [Path("src/target/a"), Path("src/upstream/x/a")]}
    assert duplicate_packages(found[:2]) == {}


def test_git_errors_keep_their_cause_and_loopback_hint() -> None:
    lines = ["=== /ws/src/upstream/x (git) ===",
             "Could not determine ref type of version: fatal: unable to connect to 127.0.0.1:",
             "127.0.0.1[0: 127.0.0.1]: errno=Connection refused"]
    reason = clone.parse_vcs_failures(lines, Path("/ws/src/upstream"), ["x"])["x"]
    assert reason.endswith("unable to connect to 127.0.0.1: 127.0.0.1[0: 127.0.0.1]: "
                           "errno=Connection refused")
    url = "git://127.0.0.1:9418/x.git"
    assert "BUILD_NETWORK=host" in clone.failure_hint(url, reason, in_image=True)
    # the step cannot know whether BUILD_NETWORK=host is set: the hint also covers a build
    # that has it (where only a server that is down refuses)
    assert "is the server running?" in clone.failure_hint(url, reason, in_image=True)
    assert clone.failure_hint(url, reason, in_image=False) == ""
    assert clone.failure_hint("https://example.com/x.git", reason, in_image=True) == ""
    assert clone.failure_hint(url, "fatal: invalid reference: main", in_image=True) == ""
    for url, host in (("http://u@localhost:8080/x", "localhost"), ("git@127.0.0.1:x.git",
                      "127.0.0.1"), ("ssh://[::1]:22/x", "[::1]"), ("/srv/x.git", "")):
        assert clone.url_host(url) == host


def test_a_clone_that_wants_credentials_says_which_to_set() -> None:
    """git says `terminal prompts disabled` or `Permission denied (publickey)`; the message
    says which settings give it the login (and when GIT_HTTPS_SERVER names another host)."""
    url = "https://git.example.com/group/private.git"
    prompt = ["Could not clone repository 'https://git.example.com/group/private.git': Cloning "
              "into '.'...", "fatal: could not read Username for 'https://git.example.com': "
              "terminal prompts disabled"]
    assert clone.login_hint(url, prompt, {}) == (
        " (the server asks for a login: set GIT_HTTPS_SERVER=git.example.com, GIT_HTTPS_USER "
        "and GIT_HTTPS_PASSWORD in the environment or .env)")
    other = {"DOCKER_ROS_GIT_HTTPS_HOST": "gitlab.example.com:8443"}
    assert clone.login_hint(url, prompt, other) == (
        " (the server asks for a login; GIT_HTTPS_SERVER is gitlab.example.com:8443, and the "
        "password is given to that host only: set it to git.example.com)")
    refused = ["remote: HTTP Basic: Access denied", "fatal: Authentication failed for "
               f"'{url}/'"]
    assert "check GIT_HTTPS_USER and GIT_HTTPS_PASSWORD" in clone.login_hint(url, refused, other)
    denied = ["git@git.example.com: Permission denied (publickey).",
              "fatal: Could not read from remote repository."]
    ssh = "git@git.example.com:group/private.git"
    unknown = ["Host key verification failed.", "fatal: Could not read from remote repository."]
    for output in (denied, unknown):  # (without a key, the known host keys are not used)
        assert clone.login_hint(ssh, output, {}) == (
            " (the server wants an SSH login: set GIT_SSH_PRIVATE_KEY and GIT_SSH_KNOWN_HOST_KEYS"
            " (its lines from `ssh-keyscan git.example.com`) in the environment or .env)")
    key = {"GIT_SSH_COMMAND": "ssh -i /tmp/x/id"}
    assert "refused GIT_SSH_PRIVATE_KEY" in clone.login_hint(ssh, denied, key)
    assert "set GIT_SSH_KNOWN_HOST_KEYS to its lines from `ssh-keyscan git.example.com`" in (
        clone.login_hint(ssh, unknown, key))
    assert clone.login_hint(url, ["fatal: invalid reference: v9"], {}) == ""


def test_a_local_repository_url_in_an_image_build_gets_a_hint() -> None:
    """A .repos URL to a folder of this machine cannot be cloned in an image build: the
    failure says why and what to do (git only says it is no git repository)."""
    lines = ["=== /ws/src/upstream/x (git) ===",
             "Could not determine ref type of version: fatal: '/srv/x' does not appear to be "
             "a git repository", "fatal: Could not read from remote repository."]
    reason = clone.parse_vcs_failures(lines, Path("/ws/src/upstream"), ["x"])["x"]
    for url in ("file:///srv/x", "/srv/x", "../x"):
        hint = clone.failure_hint(url, reason, in_image=True)
        assert "not on this machine" in hint and "BUILD_NETWORK=host" in hint, url
        assert clone.failure_hint(url, reason, in_image=False) == ""
    for url in ("https://example.com/x.git", "git@example.com:x.git"):
        assert clone.failure_hint(url, reason, in_image=True) == ""
    assert clone.failure_hint("file:///srv/x", "fatal: invalid reference: v9",
                              in_image=True) == ""


def test_pip_tls_failure_is_recognised_with_the_hint() -> None:
    line = ("WARNING: Retrying (Retry(total=4, connect=None, read=None, redirect=None, "
            "status=None)) after connection broken by 'SSLError(SSLCertVerificationError(1, "
            "'[SSL: CERTIFICATE_VERIFY_FAILED] certificate verify failed: unable to get local "
            "issuer certificate (_ssl.c:1006)'))': /simple/tomli-w/")
    assert "set EXTRA_CA_CERTS" in pipinstall.tls_failure(line)
    assert pipinstall.tls_failure("Collecting tomli-w") == ""


# pip 23's output for a requirement whose metadata cannot be made (its setup.py raises), and
# for one whose C extension does not compile (shortened: the traceback's frames left out)
PIP_METADATA_FAILURE = """\
Processing ./badmeta
  Preparing metadata (pyproject.toml): started
  Preparing metadata (pyproject.toml): finished with status 'error'
  error: subprocess-exited-with-error

  × Preparing metadata (pyproject.toml) did not run successfully.
  │ exit code: 1
  ╰─> [18 lines of output]
      Traceback (most recent call last):
        File "<string>", line 1, in <module>
      RuntimeError: boom: this package needs libfoo
      [end of output]

  note: This error originates from a subprocess, and is likely not a problem with pip.
error: metadata-generation-failed

× Encountered error while generating package metadata.
╰─> See above for output.

note: This is an issue with the package mentioned above, not pip.
hint: See above for details.
""".splitlines()
PIP_WHEEL_FAILURE = """\
  × python setup.py bdist_wheel did not run successfully.
  │ exit code: 1
  ╰─> [14 lines of output]
      running build_ext
      gcc -c nope.c -o build/temp.linux-x86_64-cpython-311/nope.o
      nope.c:2:10: fatal error: nosuch.h: No such file or directory
      compilation terminated.
      error: command '/usr/bin/gcc' failed with exit code 1
      [end of output]

  note: This error originates from a subprocess, and is likely not a problem with pip.
  ERROR: Failed building wheel for badbuild
  Running setup.py clean for badbuild
Failed to build badbuild
ERROR: Could not build wheels for badbuild, which is required to install pyproject.toml-based \
projects
""".splitlines()


def test_a_pip_requirement_that_fails_to_build_is_named_with_its_error() -> None:
    """pip's last line for a package it cannot build says `hint: See above for details.`
    (before: the whole cause in the message); the message names the requirement and the
    build's own error line."""
    assert pipinstall.pip_reason(PIP_METADATA_FAILURE) == (
        "Encountered error while generating package metadata (./badmeta); the build's output "
        "says: RuntimeError: boom: this package needs libfoo")
    assert pipinstall.pip_reason(PIP_WHEEL_FAILURE) == (
        "Could not build wheels for badbuild, which is required to install "
        "pyproject.toml-based projects; the build's output says: nope.c:2:10: fatal error: "
        "nosuch.h: No such file or directory")
    # psycopg2 from source in an image without libpq-dev (pip 23.0.1 of Debian 12)
    psycopg2 = ["Collecting psycopg2==2.9.9", "  × python setup.py egg_info did not run "
                "successfully.", "  ╰─> [23 lines of output]", "      running egg_info",
                "      Error: pg_config executable not found.", "      or with the pg_config "
                "option in 'setup.cfg'.", "      [end of output]",
                "error: metadata-generation-failed",
                "× Encountered error while generating package metadata.",
                "hint: See above for details."]
    assert pipinstall.pip_reason(psycopg2) == (
        "Encountered error while generating package metadata (psycopg2==2.9.9); the build's "
        "output says: Error: pg_config executable not found.")
    assert pipinstall.pip_reason(["Collecting nosuch==9", "ERROR: No matching distribution "
                                  "found for nosuch==9"]) == (
        "No matching distribution found for nosuch==9")
    assert pipinstall.pip_reason([]) == "no output"


def test_crlf_scripts_get_a_hint() -> None:
    assert "CRLF" in script_hint(b"#!/bin/bash\r\necho hi\r\n")
    assert script_hint(b"#!/bin/bash\necho hi\n") == ""


def load_error(**sources: object) -> str:
    """The message load_settings stops with for these sources (e.g. environ={...})."""
    with pytest.raises(SettingsError) as raised:
        load_settings(**sources)  # type: ignore[arg-type]
    return str(raised.value)


def test_shell_split_settings_with_an_unclosed_quote_are_named_when_loaded() -> None:
    for name in ("CMAKE_ARGS", "SLIM_BUILD_ARGS", "ADDITIONAL_SLIM_BUILD_ARGS"):
        message = load_error(flags={name.lower(): "'-DFOO=unclosed"})
        assert message.endswith(f"{name}=\"'-DFOO=unclosed\": No closing quotation: close or "
                                "escape the quote (from flag)"), message
    assert load_settings(environ={"CMAKE_ARGS": "-DA='x y'"}).cmake_args == "-DA='x y'"


def test_empty_invoke_yaml_keys_are_unset_and_build_network_is_checked() -> None:
    settings = load_settings(invoke_config={"cmake_args": None, "build_network": None,
                                            "ros_distro": None, "image_tag": ""})
    assert settings.cmake_args == "-DCMAKE_BUILD_TYPE=Release"
    assert settings.build_network is None and settings.ros_distro is None
    assert settings.image_tag == "latest" and settings.source_of("cmake_args") == "default"
    assert load_error(flags={"build_network": "bogusnet"}) == (
        "invalid configuration:\n  BUILD_NETWORK='bogusnet' not allowed; allowed values: host, "
        "none, default (from flag)")
    assert load_settings(environ={"BUILD_NETWORK": "host"}).build_network == "host"
    assert not load_settings(flags={"build_network": ""}).build_network


def test_an_empty_target_is_refused() -> None:
    for raw in ("", ",", " , "):
        assert load_error(flags={"target": raw}) == (
            f"invalid configuration:\n  TARGET={raw!r} is empty: give one or more of dev, run, "
            "slim (comma-separated), or leave it unset (from flag)")
    assert "TARGET=',' is empty" in load_error(dotenv={"TARGET": ","})
    assert load_settings(dotenv={"TARGET": ""}).target == ("run",)  # empty: unset
    assert load_settings(flags={"platform": ","}).platform  # PLATFORM: this machine's


def test_a_bare_set_is_refused() -> None:
    with pytest.raises(SettingsError, match="--set without a value: use --set NAME=VALUE"):
        parse_set([True])


@pytest.mark.parametrize("argv, bare", [
    (["config", "--set", "A=1", "--set"], True),  # invoke drops this one
    (["config", "--set", "--dry-run"], True),
    (["config", "--set", "A=1", "--set", "B=2"], False),
    (["config", "--command", "--set=x"], False),
])
def test_a_bare_set_on_the_command_line_is_found(argv, bare) -> None:
    assert has_bare_set(argv) is bare


def test_a_setting_only_the_ci_integrations_read_is_refused_as_set() -> None:
    """ENABLE_CHECKOUT and the like are inputs of the Action (docker-ros's too): a `--set` of
    one would change nothing."""
    with pytest.raises(SettingsError, match="--set ENABLE_CHECKOUT: read by the CI integrations "
                                            "only"):
        parse_set(["ENABLE_CHECKOUT=false"])
    assert parse_set(["ENABLE_SLIM=false"]) == {"enable_slim": "false"}


def test_base_image_reference_is_checked_naming_its_source(tmp_path: Path) -> None:
    for bad in ("UPPER/img:tag", "Bad Base::x", "ubuntu@sha256:abc", "ros:bad tag"):
        problems = image_problems(settings_for(tmp_path, BASE_IMAGE=bad), ("dev",))
        assert problems == {"base_image": (
            f"BASE_IMAGE (environment): {bad!r} is not a valid image reference: give "
            "[registry/]name[:tag][@digest], the name in lower case")}, bad
    for good in ("ros:noetic", "localhost/x", "reg.io:5000/a/b:1", "Reg.IO/a", "host:5000/img",
                 "docker-ros/ros1:bookworm-arm64", "ubuntu@sha256:" + "ab" * 32):
        assert image_problems(settings_for(tmp_path, BASE_IMAGE=good), ("dev",)) == {}, good


def test_slim_image_names_are_checked_when_slimmed(tmp_path: Path) -> None:
    bad = settings_for(tmp_path, SLIM_IMAGE_TAG="bad tag!")
    assert image_problems(bad, ("run",)) == {}
    assert image_problems(bad, ("run", "slim")) == {
        "slim_image_tag": "SLIM_IMAGE_TAG: 'bad tag!' is not a valid image tag" + TAG_RULE}
    with pytest.raises(SettingsError, match="SLIM_IMAGE_TAG: 'bad tag!' is not a valid"):
        check_slim_options(bad)


def test_a_bad_image_postfix_is_named(tmp_path: Path) -> None:
    bad = load_settings(environ={"BUILD_CONTEXT": str(tmp_path)}, project_dir=tmp_path,
                        flags={"image_postfix": "bad/post", "image": "x:y"})
    assert image_problems(bad, ("run",)) == {"image_tag": (
        "IMAGE_TAG (from IMAGE) + IMAGE_POSTFIX (flag): 'ybad/post' is not a valid image tag"
        + TAG_RULE)}


def test_inspect_image_turns_a_refused_reference_into_an_engine_error(
        monkeypatch: pytest.MonkeyPatch) -> None:
    class Images:
        def get(self, ref: str) -> None:
            raise APIError("400 Client Error", explanation="invalid reference format")

    monkeypatch.setattr(engine, "client", lambda: SimpleNamespace(images=Images()))
    with pytest.raises(engine.EngineError, match="^docker image inspect UPPER/x: invalid "
                       "reference format$"):
        engine.inspect_image("UPPER/x")


def test_a_workspace_that_cannot_be_made_is_one_line(tmp_path: Path) -> None:
    for workspace, reason in (("/dev/null", "Not a directory"),
                              ("/proc/nonexistent", "No such file or directory")):
        settings = settings_for(tmp_path, WORKSPACE=workspace)
        with pytest.raises(TaskError) as raised, host_workspace(settings, dry_run=False):
            pass
        assert str(raised.value) == (f"WORKSPACE '{workspace}' cannot be created/used: {reason}; "
                                     "give a writable folder")


def test_read_user_text_raises_the_callers_error(tmp_path: Path) -> None:
    path = tmp_path / "list.txt"
    path.write_bytes("pkg # é\n".encode())
    assert read_user_text(path, SettingsError) == "pkg # é\n"
    path.write_bytes("pkg # é\n".encode("latin-1"))
    with pytest.raises(SettingsError, match=r"^x.txt is not UTF-8 text \(invalid continuation "
                       r"byte at byte 6\): save it as UTF-8$"):
        read_user_text(path, SettingsError, "x.txt")


def test_a_ca_bundle_with_a_latin1_comment_is_read(tmp_path: Path) -> None:
    pem = "-----BEGIN CERTIFICATE-----\nMIIB\n-----END CERTIFICATE-----\n"
    (tmp_path / "ca.pem").write_bytes("# Zertifikat für den Proxy\n".encode("latin-1")
                                      + pem.encode())
    bundle = buildcontext.ca_bundle(tmp_path / "ca.pem", tmp_path / "bundle.pem")
    assert pem in bundle.read_text()


def test_a_base_image_the_registry_refuses_names_why_and_the_login_settings(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """A private BASE_IMAGE pulled without credentials: the registry's answer and the settings
    docker-ros logs in with (REGISTRY_USER/REGISTRY_PASSWORD, as a CI job sets them), not only
    `docker login`, which a job's own login would not use."""
    class Images:
        def get(self, ref: str) -> None:
            raise NotFound("No such image")

        def pull(self, repository: str, tag: str) -> None:
            raise APIError("500 Server Error", explanation=f"Head \"{repository}\": no basic "
                           "auth credentials")

    local = [{"RepoTags": ["127.0.0.1:5000/private/base:2"]}]  # no typo: another version
    monkeypatch.setattr(engine, "client", lambda: SimpleNamespace(
        images=Images(), api=SimpleNamespace(images=lambda: local)))
    settings = settings_for(tmp_path, BASE_IMAGE="127.0.0.1:5000/private/base:1")
    with pytest.raises(errors.BuildError) as raised:
        refs.platform_base(settings, "amd64")
    message = str(raised.value)
    assert "(Head \"127.0.0.1:5000/private/base\": no basic auth credentials)" in message
    assert "REGISTRY_USER and REGISTRY_PASSWORD" in message
    assert "did you mean" not in message


def test_dotenv_command_substitution_warns_that_it_is_not_run() -> None:
    """docker-ros's build.sh sourced .env with bash, which ran `$(git ...)`; here it is text."""
    text = ('IMAGE="my/image:$(git rev-parse --short HEAD)"\nCMAKE_ARGS=-DV=`date`\n'
            "COMMAND='roslaunch p x.launch ip:=$(hostname -i)'\nNAME=x\nIMAGE_TAG=${NAME}\n")
    warnings = dotenv_warnings(dotenv_values(stream=io.StringIO(text)))
    assert [w.split(":")[0] for w in warnings] == ["IMAGE", "CMAKE_ARGS"], warnings
    assert warnings[0].startswith("IMAGE: its command substitution ($(...) or `...`) is not "
                                  "run: .env is read as NAME=VALUE lines")
    assert warnings[0].endswith('set IMAGE in the environment instead (IMAGE="$(...)" inv build)')


def test_dotenv_old_docker_ros_names_name_the_new_ones() -> None:
    """docker-ros v1.6's custom.sh variables (v1.7 renamed them; both ignore the old names)."""
    assert dotenv_warnings({"CUSTOM_SCRIPT_FILE": "docker/setup.sh",
                            "ENABLE_RECURSIVE_CUSTOM_SCRIPT": "true"}) == [
        "CUSTOM_SCRIPT_FILE ignored: docker-ros's earlier name, now "
        "AFTER_DEPENDENCY_INSTALLATION_SCRIPT",
        "ENABLE_RECURSIVE_CUSTOM_SCRIPT ignored: docker-ros's earlier name, now "
        "ENABLE_RECURSIVE_AFTER_DEPENDENCY_INSTALLATION_SCRIPT",
    ]


def test_running_in_a_package_folder_names_the_repository_s_env(tmp_path, caplog):
    """invoke finds tasks.py above the folder it runs in; .env is read from that folder only:
    a user who runs docker-ros in a package folder is told where it should run."""
    repo = tmp_path / "repo"
    (repo / ".git").mkdir(parents=True)
    (repo / ".env").write_text("BASE_IMAGE=b:1\n")
    (repo / "src" / "pkg").mkdir(parents=True)
    assert repository_env_file(repo / "src" / "pkg") == repo / ".env"
    assert repository_env_file(repo) is None  # its own .env is read
    (tmp_path / ".env").write_text("X=1\n")  # above the repository: not its
    (repo / ".env").unlink()
    assert repository_env_file(repo / "src" / "pkg") is None
    (repo / ".env").write_text("BASE_IMAGE=b:1\n")
    caplog.set_level(logging.WARNING)
    settings = read_settings({}, {}, project_dir=repo / "src" / "pkg", environ={})
    assert not settings.base_image
    assert (f"no .env in {repo / 'src' / 'pkg'}, but {repo} has one: run docker-ros in "
            f"{repo}") in caplog.text


def test_broken_manifests_and_list_files_that_are_not_text_are_found_before_the_build(
        tmp_path: Path) -> None:
    """What the blacklist and debs steps would stop on, in the image, after BuildKit started."""
    for name, text in (("good", "<package><name>good</name></package>"),
                       ("cut", "<package><name>cut</name>"), ("nameless", "<package/>"),
                       ("other", "<project><name>x</name></project>")):
        (tmp_path / name).mkdir()
        (tmp_path / name / "package.xml").write_text(text)
    (tmp_path / "folder" / "package.xml").mkdir(parents=True)
    (tmp_path / "docker").mkdir()
    (tmp_path / "docker" / "additional-debs.txt").write_bytes("libf\xf6\n".encode("latin-1"))
    problems = input_problems(settings_for(tmp_path), (), images=False)
    assert problems == {
        "packages": "cut/package.xml is not valid XML (no element found: line 1, column 25); "
        "folder/package.xml is not a file; nameless/package.xml has no <name>; "
        "other/package.xml holds <project>, not <package>: fix it, or put a CATKIN_IGNORE file "
        "in its folder (colcon and rosdep would stop on it)",
        "additional_debs_file": "ADDITIONAL_DEBS_FILE docker/additional-debs.txt is not UTF-8 "
        "text (invalid start byte at byte 4): save it as UTF-8",
    }


def test_many_duplicates_are_counted_not_all_listed() -> None:
    many = {f"pkg_{i}": [f"a/pkg_{i}", f"b/pkg_{i}"] for i in range(7)}
    message = duplicates_message(many)
    assert message.startswith("two packages with the same name: pkg_0 in a/pkg_0 and b/pkg_0; ")
    assert "pkg_4 in a/pkg_4 and b/pkg_4; and 2 more (colcon cannot build both" in message
    assert "pkg_5" not in message and message.endswith(
        "so many look like a folder of several checkouts: run docker-ros in one repository, or "
        "set BUILD_CONTEXT to it")


def test_a_build_error_naming_ros_distro_says_where_it_comes_from() -> None:
    """A shell with ROS sourced exports ROS_DISTRO; the image's prepare step cannot know that."""
    failed = errors.BuildError("building target 'run' (amd64) failed in step prepare: "
                              "ROS_DISTRO=noetic, but BASE_IMAGE has ROS humble in /opt/ros: "
                              "set ROS_DISTRO=humble, or leave it unset", 1, step="prepare")
    shell = load_settings(environ={"ROS_DISTRO": "noetic"})
    told = build.with_sources(failed, shell)
    assert str(told).endswith("leave it unset (ROS_DISTRO=noetic comes from the environment, "
                              "where a sourced ROS setup file exports it)")
    assert told.step == "prepare"
    assert build.with_sources(failed, load_settings(environ={})) is failed
    other = errors.BuildError("failed in step colcon: x")
    assert build.with_sources(other, shell) is other


def test_passwords_and_tokens_in_urls_are_hidden_wherever_they_are_in_a_text() -> None:
    from docker_ros.in_image.steps.clone import hide_url_passwords as hide
    assert hide("Could not clone repository 'http://bob:s3cret@h:80/x.git': fatal") == (
        "Could not clone repository 'http://bob:***@h:80/x.git': fatal")
    assert hide("https://ghp_T0KEN@github.com/o/r.git") == "https://***@github.com/o/r.git"
    assert hide("https://a@b.com:p@ss@host/x") == "https://a@b.com:***@host/x"
    assert hide("ssh://git@host/x and https://host/x@y") == "ssh://git@host/x and https://host/x@y"
    assert hide("ssh://root@127.0.0.1:22/r.git") == "ssh://root@127.0.0.1:22/r.git"
    assert hide("git@github.com:o/r.git") == "git@github.com:o/r.git"


def test_a_sourced_ros_distro_beating_dotenv_is_said() -> None:
    """Environment > .env: a shell where ROS is sourced overrode .env's ROS_DISTRO unseen."""
    dotenv = {"ROS_DISTRO": "jazzy", "RMW_IMPLEMENTATION": "rmw_zenoh_cpp", "IMAGE_TAG": "a"}
    assert sourced_ros_overrides(dotenv, {"ROS_DISTRO": "humble", "IMAGE_TAG": "b",
                                          "RMW_IMPLEMENTATION": "rmw_zenoh_cpp"}) == [
        "ROS_DISTRO=jazzy is overridden by the environment's ROS_DISTRO=humble (a shell where "
        "ROS is sourced exports it): `unset ROS_DISTRO` to build with .env's"]
    assert sourced_ros_overrides(dotenv, {"ROS_DISTRO": "humble", "CI": "true"}) == []
    assert sourced_ros_overrides({}, {"ROS_DISTRO": "humble"}) == []
