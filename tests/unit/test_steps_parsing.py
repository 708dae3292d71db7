"""Pure decisions of the steps: list files, rosdep output, pip argv, .repos, vcs/colcon output."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from docker_ros.core.loading import load_settings
from docker_ros.in_image.runtime import pipinstall
from docker_ros.in_image.runtime.files import read_list_file
from docker_ros.in_image.runtime.lockfile import dump_repos
from docker_ros.in_image.runtime.packages import Package
from docker_ros.in_image.runtime.repos import interpreters, read_repos, repos_problem
from docker_ros.in_image.runtime.requirements import nested_file, read_requirement_file
from docker_ros.in_image.runtime.rosenv import (
    parse_env0,
    read_secret,
    ros_setup_files,
    ros_version,
    sourced_env,
)
from docker_ros.in_image.runtime.workspace import StepError, Workspace, phases
from docker_ros.in_image.steps import clone, colcon, debs, rosdep


def test_read_list_file_comments_blanks_and_spaces(tmp_path):
    """A comment starts at any '#' (docker-ros's awk): `bad_pkg# old` blacklisted 'bad_pkg#'
    and 'old', and left bad_pkg in the build."""
    path = tmp_path / "list.txt"
    path.write_text(
        "# heading\n\n  pkg-a  \npkg-b # trailing comment\n\t\n"
        "pkg-c# no space before it\n   # indented comment\n"
    )
    assert read_list_file(path, "debs") == ["pkg-a", "pkg-b", "pkg-c"]


def test_debs_plan_splits_words_sorts_and_dedupes():
    assert debs.plan_debs(["tree", "jq curl", "tree", "libfoo=1.2-3"]) == {
        "packages": ["curl", "jq", "libfoo=1.2-3", "tree"]
    }


# --- rosdep ---

MULTI = """#ROSDEP[jq_key]
#apt
jq
#ROSDEP[six_key]
#pip
six
#ROSDEP[multi]
#apt
jq tree
#ROSDEP[nothing]
#apt

"""


def test_parse_resolve_output_multi_and_single():
    keys = ["jq_key", "six_key", "multi", "nothing"]
    assert rosdep.parse_resolve_output(MULTI, keys) == {
        "jq_key": {"apt": ["jq"]},
        "six_key": {"pip": ["six"]},
        "multi": {"apt": ["jq", "tree"]},
        "nothing": {"apt": []},
    }
    # One key: rosdep prints no #ROSDEP header.
    assert rosdep.parse_resolve_output("#apt\nlibboost-dev\n", ["boost"]) == {
        "boost": {"apt": ["libboost-dev"]}
    }


def test_parse_resolve_errors():
    stderr = (
        "WARNING: ROS_PYTHON_VERSION is unset. Defaulting to 3\n"
        "ERROR: no rosdep rule for 'nope'\n"
        "ERROR: no rosdep rule for 'nope2'\n"
        "ERROR: No definition of [ubonly] for OS [debian]\n\n"
        "No definition of [ubonly] for OS [debian]\n\trosdep key : ubonly\n\tOS name    : debian\n"
    )
    assert rosdep.parse_resolve_errors(stderr) == {
        "nope": "no rosdep rule for 'nope'",
        "nope2": "no rosdep rule for 'nope2'",
        "ubonly": "No definition of [ubonly] for OS [debian]",
    }


def test_plan_rosdep_sorted_unique_per_set():
    resolved = {
        "a": {"apt": ["zlib", "jq"]},
        "b": {"apt": ["jq"], "pip": ["six"]},
        "c": {"apt": []},
    }
    selected = {"all": {"a": ["p"], "b": ["p"], "c": ["q"]}, "exec": {"a": ["p"]}}
    assert rosdep.plan_rosdep(selected, resolved) == {
        "all": {"apt": ["jq", "zlib"], "pip": ["six"]},
        "exec": {"apt": ["jq", "zlib"], "pip": []},
    }
    assert rosdep.unsupported_installers({}, {"x": {"source": ["y"]}}) == ["x (source: y)"]


def test_format_failures_names_key_and_packages():
    text = rosdep.format_failures({"k": "no rosdep rule for 'k'"}, {"k": ["a", "b"]})
    assert text.startswith("cannot resolve rosdep key 'k' needed by a, b: no rosdep rule for 'k'")


def test_resolve_argv():
    assert rosdep.resolve_argv(["a", "b"], None) == ["rosdep", "resolve", "a", "b"]
    assert rosdep.resolve_argv(["a"], "jazzy") == ["rosdep", "resolve", "--rosdistro", "jazzy", "a"]


# --- pip ---


MAIN_REQUIREMENTS = """# heading
pkg>=1.2  # trailing comment
pkg[extra1,extra2]==2.0
pkg-b; python_version > "3"
name @ https://host/pkg.whl
--extra-index-url https://mirror/simple
long-name \\
    >=1.0 \\
    ; python_version >= "3"
pkg-c==1.0 --hash=sha256:abc
git+https://host/x.git#egg=x
-r sub/more.txt
--requirement=sub/other.txt
token-${PIP_TOKEN}-pkg
"""
NESTED = {
    "sub/more.txt": "more-a\n-c pins/c.txt\n",
    "sub/other.txt": "other-a==1 \\\n# a comment ends the continuation\nother-b\n",
    "sub/pins/c.txt": "more-a<2\n-r ../../from-constraints.txt\n",
    "from-constraints.txt": "required-from-constraints\n",
}


@pytest.fixture
def requirement_tree(tmp_path):
    for name, text in {"main.txt": MAIN_REQUIREMENTS, **NESTED}.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    return tmp_path / "main.txt"


def test_requirement_files_read_as_pip_reads_them(requirement_tree, tmp_path):
    read = read_requirement_file(requirement_tree, step="pip")
    assert read.requirements == [
        "pkg>=1.2",
        "pkg[extra1,extra2]==2.0",
        'pkg-b; python_version > "3"',
        "name @ https://host/pkg.whl",
        "--extra-index-url https://mirror/simple",
        'long-name     >=1.0     ; python_version >= "3"',
        "pkg-c==1.0 --hash=sha256:abc",
        "git+https://host/x.git#egg=x",
        "more-a",
        "required-from-constraints",  # -r in a constraint file: requirements, as in pip
        "other-a==1",
        "other-b",
        "token-${PIP_TOKEN}-pkg",  # pip expands it when it installs (never in the plan)
    ]
    assert read.constraints == ["more-a<2"]
    assert [p.relative_to(tmp_path).as_posix() for p in read.files] == [
        "main.txt", "sub/more.txt", "sub/pins/c.txt", "from-constraints.txt", "sub/other.txt"]


def test_requirement_files_agree_with_pips_own_parser(requirement_tree, monkeypatch):
    """pip's parser (an internal API: this test only) finds the same requirements."""
    from pip._internal.network import session as network
    from pip._internal.req import req_file
    monkeypatch.delenv("PIP_TOKEN", raising=False)
    parsed = list(req_file.parse_requirements(str(requirement_tree),
                                              session=network.PipSession()))
    ours = read_requirement_file(requirement_tree, step="pip")
    theirs = [(r.requirement, r.constraint) for r in parsed]
    mine = [(line.split(" --hash")[0], False) for line in ours.requirements
            if not line.startswith("-")] + [(line, True) for line in ours.constraints]
    assert sorted(theirs) == sorted(mine)


@pytest.mark.parametrize("line, nested", [
    ("-r a.txt", (False, "a.txt")), ("-ra.txt", (False, "a.txt")),
    ("--requirement a.txt", (False, "a.txt")), ("--constraint=c.txt", (True, "c.txt")),
    ("-c 'with space.txt'", (True, "with space.txt")), ("pkg>=1", None),
    ("pkg==1 --hash=sha256:x", None), ("--index-url https://x/simple", None),
])
def test_nested_file_lines(line, nested):
    assert nested_file(line) == nested


def test_find_links_relative_to_the_requirement_file_when_there(tmp_path):
    (tmp_path / "sub" / "wheels").mkdir(parents=True)
    (tmp_path / "sub" / "req.txt").write_text(
        "--find-links wheels\n-f ./missing\n--find-links=https://h/links\n-fwheels\n")
    wheels = str(tmp_path / "sub" / "wheels")
    assert read_requirement_file(tmp_path / "sub" / "req.txt", step="pip").requirements == [
        f"--find-links {wheels}", "-f ./missing", "--find-links=https://h/links", f"-f{wheels}"]


def test_missing_nested_file_and_cycles_name_file_and_line(tmp_path):
    (tmp_path / "a.txt").write_text("x\n-r b.txt\n")
    with pytest.raises(StepError) as err:
        read_requirement_file(tmp_path / "a.txt", step="pip")
    assert err.value.message.startswith(f"{tmp_path / 'a.txt'}:2: `-r b.txt`: ")
    assert f"{tmp_path / 'b.txt'} not found" in err.value.message
    assert read_requirement_file(tmp_path / "a.txt", step="pip", missing_ok=True).files == [
        tmp_path / "a.txt"]
    (tmp_path / "b.txt").write_text("-r a.txt\n")
    with pytest.raises(StepError, match="includes a file that includes it again"):
        read_requirement_file(tmp_path / "a.txt", step="pip")


def test_requirement_files_for_pip(tmp_path):
    path = pipinstall.requirement_files(tmp_path, ["a>=1", "--no-index"], ["a<2"])
    assert path.read_text() == "-c constraints.txt\na>=1\n--no-index\n"
    assert (tmp_path / "constraints.txt").read_text() == "a<2\n"


@pytest.mark.parametrize(
    ("probe", "root", "flags"),
    [
        (
            {"externally_managed": True, "in_venv": False, "pip": "23.0.1"},
            True,
            ["--break-system-packages"],
        ),
        (
            {"externally_managed": True, "in_venv": False, "pip": "24.0"},
            True,
            ["--break-system-packages"],
        ),
        ({"externally_managed": True, "in_venv": False, "pip": "22.0.2"}, True, []),
        ({"externally_managed": False, "in_venv": False, "pip": "24.0"}, True, []),
        ({"externally_managed": False, "in_venv": True, "pip": "24.0"}, False, []),
        ({"externally_managed": False, "in_venv": False, "pip": "20.0.2"}, False, ["--user"]),
        (
            {"externally_managed": True, "in_venv": False, "pip": "23.3"},
            False,
            ["--break-system-packages", "--user"],
        ),
    ],
)
def test_pep668_flags(probe, root, flags):
    assert pipinstall.install_flags(probe, root=root) == flags


def test_pip_install_argv_and_versions():
    argv = pipinstall.pip_install_argv("python3", ["a>=1"], ["--break-system-packages"])
    assert argv == ["python3", "-m", "pip", "install", "--break-system-packages", "a>=1"]
    assert pipinstall.version_tuple("23.0.1") == (23, 0, 1)
    assert pipinstall.version_tuple("24.1b1") == (24, 1)
    assert pipinstall.version_tuple(None) == ()


def test_probe_of_this_interpreter():
    import sys

    data = pipinstall.probe_python(sys.executable, step="pip")
    assert set(data) == {"externally_managed", "in_venv", "pip"}
    assert pipinstall.python_command({"DOCKER_ROS_PYTHON": "/x/python"}) == "/x/python"
    assert pipinstall.python_command({}) == "python3"


# --- clone ---

BLOCK = """# comment
repositories:
  lib_a:
    type: git
    url: https://github.com/org/lib_a.git  # trailing
    version: main
  "nested/lib b":
    type: git
    url: 'git@host:org/lib_b.git'
  flow: {type: git, url: "https://h/flow,comma.git", version: v1}
  number: {type: git, url: https://h/n.git, version: 1.0}
"""
ROSINSTALL = """# rosinstall format
- git: {local-name: lib_a, uri: 'https://h/a,b.git', version: main}
- git:
    local-name: nested/lib_b  # comment
    uri: https://h/b.git
"""


def write(tmp_path, text, name="x.repos"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_read_repos_vcs_format(tmp_path):
    assert read_repos(write(tmp_path, BLOCK), step="clone") == {
        "lib_a": {"type": "git", "url": "https://github.com/org/lib_a.git", "version": "main"},
        "nested/lib b": {"type": "git", "url": "git@host:org/lib_b.git"},
        "flow": {"type": "git", "url": "https://h/flow,comma.git", "version": "v1"},
        "number": {"type": "git", "url": "https://h/n.git", "version": "1.0"},
    }


def test_read_repos_rosinstall_format(tmp_path):
    assert read_repos(write(tmp_path, ROSINSTALL), step="clone") == {
        "lib_a": {"type": "git", "url": "https://h/a,b.git", "version": "main"},
        "nested/lib_b": {"type": "git", "url": "https://h/b.git"},
    }


@pytest.mark.parametrize(
    "text", ["", "# nothing\n", "repositories: {}\n", "repositories:\n", "---\nrepositories:\n\n"]
)
def test_empty_repos(tmp_path, text):
    assert read_repos(write(tmp_path, text), step="clone") == {}


def test_unreadable_repos_names_the_file_and_line(tmp_path):
    path = write(tmp_path, "repositories:\n  a: {type: git, url: [\n")
    with pytest.raises(StepError) as err:
        read_repos(path, step="clone")
    assert str(path) in err.value.message and "line 3" in err.value.message
    with pytest.raises(StepError, match="not a .repos file vcstool can read"):
        read_repos(write(tmp_path, "just: text\n"), step="clone")


@pytest.mark.parametrize("text,said", [
    ("repositories:\n  good: {type: git, url: /x}\n  bad: {type: git, version: main}\n",
     "repository 'bad' has no url"),
    ("repositories:\n  bad: {url: /x}\n", "repository 'bad' has no type"),
    ("- git: {local-name: ok, uri: /x}\n- git: {uri: /y}\n", "repository '#2' has no local-name"),
    ("- git: {local-name: b}\n", "repository 'b' has no uri"),
    ("repositories:\n  ../target/injected: {type: git, url: /x}\n",
     "repository name '../target/injected' leaves src/upstream"),
    ("repositories:\n  a/../../b: {type: git, url: /x}\n", "name 'a/../../b' leaves"),
    ("- git: {local-name: /abs, uri: /x}\n", "repository name '/abs' leaves src/upstream"),
    # YAML's numbers: vcstool would check out the tag 1.1
    ("repositories:\n  up: {type: git, url: /x, version: 1.10}\n",
     "repository 'up': YAML reads version 1.10 as 1.1: quote it (version: '1.10')"),
    ("- git: {local-name: up, uri: /x, version: 3.10, other: 3.10}\n",
     "repository 'up': YAML reads version 3.10 as 3.1: quote it (version: '3.10')"),
    ("repositories:\n  up: {type: git, url: [/x, /y]}\n",
     "repository 'up' has a list as url: give one value"),
])
def test_repos_entries_vcstool_would_skip_or_clone_elsewhere_stop_the_step(tmp_path, text, said):
    """vcstool skips an entry without url with a warning only, and clones a name with '..'
    outside src/upstream: both stop the clone step, and the check before the build, on the
    file's name."""
    path = write(tmp_path, text)
    with pytest.raises(StepError) as err:
        read_repos(path, step="clone", shown="deps.repos")
    assert said in err.value.message and err.value.message.startswith("deps.repos: ")
    assert said in (repos_problem(path, "deps.repos") or "")


def test_repos_names_with_dots_inside_stay_allowed(tmp_path):
    """(and values vcstool does not read are not checked: `recursive: true`, a list of tags)"""
    text = ("repositories:\n  a..b/c.d: {type: git, url: /x}\n  ./e: {type: git, url: /y, "
            "version: 2}\n  f: {type: git, url: /z, version: 1.0, recursive: on, tags: [a]}\n")
    assert sorted(read_repos(write(tmp_path, text), step="clone")) == ["./e", "a..b/c.d", "f"]
    assert repos_problem(write(tmp_path, text), "x.repos") is None


def test_dump_repos_reads_back(tmp_path):
    repos = read_repos(write(tmp_path, BLOCK), step="clone")
    assert read_repos(write(tmp_path, dump_repos(repos), "y.repos"), step="clone") == repos


def test_interpreters_of_the_vcs_script(tmp_path):
    script = write(tmp_path, "#!/opt/venv/bin/python3.11\nimport re\n", "vcs")
    assert interpreters(str(script)) == [["/opt/venv/bin/python3.11"], ["python3"]]
    shim = write(tmp_path, "#!/usr/bin/env bash\nexec x\n", "shim")
    assert interpreters(str(shim)) == [["python3"]]
    env = write(tmp_path, "#!/usr/bin/env python3\n", "env")
    assert interpreters(str(env)) == [["/usr/bin/env", "python3"], ["python3"]]


def test_parse_vcs_failures():
    dest = Path("/ws/src/upstream")
    lines = [
        "E.E",
        "=== /ws/src/upstream/bad (git) ===",
        "Could not clone repository 'file:///x.git': Cloning into '.'...",
        "fatal: '/x.git' does not appear to be a git repository",
        "fatal: Could not read from remote repository.",
        "=== /ws/src/upstream/badver (git) ===",
        "Could not checkout ref 'nosuch': fatal: invalid reference: nosuch",
        "=== /ws/src/upstream/good (git) ===",
        "Cloning into '.'...",
    ]
    assert clone.parse_vcs_failures(lines, dest, ["bad", "badver", "good"]) == {
        "bad": "Could not clone repository 'file:///x.git': "
        "fatal: '/x.git' does not appear to be a git repository",
        "badver": "Could not checkout ref 'nosuch': fatal: invalid reference: nosuch",
    }


def test_import_argv():
    argv = clone.import_argv(Path("/r/.repos"), Path("/ws/src/upstream"), skip_existing=True)
    assert argv == [
        "vcs",
        "import",
        "--recursive",
        "--input",
        "/r/.repos",
        "/ws/src/upstream",
        "--skip-existing",
    ]


def test_https_askpass_answers_only_for_the_server(tmp_path):
    settings = load_settings(
        environ={
            "GIT_HTTPS_SERVER": "git.example.com",
            "GIT_HTTPS_USER": "robot",
            "GIT_HTTPS_PASSWORD": "s3cr3t-value",
        },
        project_dir=tmp_path,
    )
    with clone.git_credentials(settings, secrets_dir=tmp_path / "none") as env:
        askpass = env["GIT_ASKPASS"]
        full = {**os.environ, **env}

        def ask(prompt):
            return subprocess.run([askpass, prompt], env=full, capture_output=True, text=True)

        assert ask("Username for 'https://git.example.com': ").stdout == "robot\n"
        assert ask("Password for 'https://robot@git.example.com': ").stdout == "s3cr3t-value\n"
        assert ask("Password for 'https://other.org': ").returncode != 0
        assert ask("Username for 'https://git.example.com:8443': ").stdout == "robot\n"
        # a host that only starts with the server's name gets nothing
        for prompt in ("Username for 'https://git.example.com.evil.org': ",
                       "Password for 'https://robot@git.example.com.evil.org': ",
                       "Password for 'https://robot@git.example.community': "):
            assert ask(prompt).stdout == "" and ask(prompt).returncode != 0, prompt
        # The secret lives in the environment only, never in a file.
        for path in Path(askpass).parent.iterdir():
            assert "s3cr3t-value" not in path.read_text()
        assert oct(Path(askpass).parent.stat().st_mode & 0o777) == "0o700"
    assert not Path(askpass).parent.exists()


def test_secrets_come_from_secret_files_when_unset(tmp_path):
    (tmp_path / "GIT_HTTPS_PASSWORD").write_text("from-file\n")
    settings = load_settings(environ={}, project_dir=tmp_path)
    assert read_secret(settings, "git_https_password", tmp_path) == "from-file"
    assert read_secret(settings, "GIT_SSH_PRIVATE_KEY", tmp_path) is None
    set_ = load_settings(environ={"GIT_HTTPS_PASSWORD": "env"}, project_dir=tmp_path)
    assert read_secret(set_, "git_https_password", tmp_path) == "env"
    with clone.git_credentials(settings, secrets_dir=tmp_path) as env:
        assert env == {}  # a password without a server is not used


@pytest.mark.parametrize(
    ("url", "ssh"),
    [
        ("ssh://git@host:2222/org/repo.git", True),
        ("git+ssh://host/repo.git", True),
        ("git@github.com:org/repo.git", True),
        ("host:repo.git", True),
        ("https://user@host/org/repo.git", False),
        ("http://127.0.0.1:8080/repo.git", False),
        ("file:///srv/repo.git", False),
        ("/srv/git/repo.git", False),
        ("../sibling/repo.git", False),
    ],
)
def test_uses_ssh_follows_gits_url_rules(url, ssh):
    assert clone.uses_ssh(url) is ssh


# --- colcon ---


def test_colcon_argv():
    assert colcon.build_argv("-DCMAKE_BUILD_TYPE=Release '-DX=a b' --trace", ["bad"]) == [
        "colcon",
        "build",
        "--base-paths",
        "src",
        "--event-handlers",
        "console_cohesion+",
        "--packages-ignore",
        "bad",
        "--cmake-args",
        "-DCMAKE_BUILD_TYPE=Release",
        "-DX=a b",
        " --trace",
    ]
    assert colcon.build_argv("", [])[-2:] == ["--event-handlers", "console_cohesion+"]


def test_colcon_failed_packages():
    lines = [
        "Starting >>> a",
        "Finished <<< a [0.5s]",
        "Failed   <<< broken_pkg [1.2s, exited with code 2]",
        "Aborted  <<< other [0.9s]",
        "Summary: 1 package finished [2.0s]",
    ]
    assert colcon.failed_packages(lines) == ["broken_pkg"]


# colcon build of three packages, one of which does not compile, another finds no CMake
# package (console_cohesion+'s blocks, then console_stderr's, then the summary; an image build)
COLCON_FAILURE = """\
Starting >>> base_pkg
--- output: base_pkg
-- The CXX compiler identification is GNU 12.2.0
[100%] Built target base_node
---
Finished <<< base_pkg [2.1s]
Starting >>> broken_pkg
Starting >>> lost_pkg
--- output: broken_pkg
[ 50%] Building CXX object CMakeFiles/node.dir/src/node.cpp.o
/docker-ros/ws/src/target/broken/src/node.cpp: In function 'int main()':
/docker-ros/ws/src/target/broken/src/node.cpp:3:3: error: 'undeclared' was not declared in \
this scope
    3 |   undeclared();
      |   ^~~~~~~~~~
/docker-ros/ws/src/target/broken/src/node.cpp:4:10: error: expected ';' before '}' token
gmake[2]: *** [CMakeFiles/node.dir/build.make:76: CMakeFiles/node.dir/src/node.cpp.o] Error 1
gmake: *** [Makefile:136: all] Error 2
---
--- stderr: broken_pkg
/docker-ros/ws/src/target/broken/src/node.cpp:3:3: error: 'undeclared' was not declared in \
this scope
---
Failed   <<< broken_pkg [3.0s, exited with code 2]
--- output: lost_pkg
CMake Error at CMakeLists.txt:4 (find_package):
  By not providing "Findno_such_dep.cmake" in CMAKE_MODULE_PATH this project
  has asked CMake to find a package configuration file provided by
  "no_such_dep", but CMake did not find one.

-- Configuring incomplete, errors occurred!
---
Failed   <<< lost_pkg [1.0s, exited with code 1]

Summary: 1 package finished [4.1s]
  2 packages failed: broken_pkg lost_pkg
  2 packages had stderr output: broken_pkg lost_pkg
""".splitlines()


def test_colcon_failure_names_the_packages_and_their_first_errors():
    """The one-line error of a failed colcon build quotes the compiler's and CMake's first
    error lines (in an image build the output is far above, between BuildKit's lines), with
    the repository's paths as the user knows them."""
    ws = Workspace("/docker-ros/ws")
    assert colcon.error_lines(COLCON_FAILURE, ["broken_pkg", "lost_pkg"]) == [
        "/docker-ros/ws/src/target/broken/src/node.cpp:3:3: error: 'undeclared' was not "
        "declared in this scope",
        "/docker-ros/ws/src/target/broken/src/node.cpp:4:10: error: expected ';' before '}' "
        "token",
        'CMake Error at CMakeLists.txt:4 (find_package): By not providing '
        '"Findno_such_dep.cmake" in CMAKE_MODULE_PATH this project has asked CMake to find a '
        'package configuration file provided by "no_such_dep", but CMake did not find one.',
    ]
    assert colcon.failure_message(ws, COLCON_FAILURE, 2) == (
        "package broken_pkg, lost_pkg failed to build (exit code 2): broken/src/node.cpp:3:3: "
        "error: 'undeclared' was not declared in this scope | broken/src/node.cpp:4:10: error: "
        "expected ';' before '}' token (and 1 more error line); see the output above")
    lost = COLCON_FAILURE[COLCON_FAILURE.index("--- output: lost_pkg"):]
    assert colcon.failure_message(ws, lost, 1) == (
        "package lost_pkg failed to build (exit code 1): CMake Error at CMakeLists.txt:4 "
        '(find_package): By not providing "Findno_such_dep.cmake" in CMAKE_MODULE_PATH this '
        "project has asked CMake to find a package configuration file provided by "
        '"no_such_dep", but CMake did not find one.; a dependency CMake cannot find is '
        "installed when the package.xml declares it (<depend>, <build_depend>: rosdep "
        "installs it) or ADDITIONAL_DEBS_FILE lists it; see the output above")
    assert colcon.error_lines(COLCON_FAILURE, ["base_pkg"]) == []
    assert colcon.failure_message(ws, ["Summary: 0 packages finished"], 1) == (
        "colcon build failed (exit code 1); see the output above")


def test_a_library_the_linker_cannot_find_is_named(tmp_path: Path):
    """GNU ld says `cannot find -lfoo` without `error:`; the one-line error quoted only
    collect2's `error: ld returned 1 exit status`, not which library is missing. Real gcc."""
    gcc = shutil.which("gcc")
    assert gcc, "no gcc: run `bash scripts/setup.sh` first"
    (tmp_path / "main.c").write_text("int main(void) { return 0; }\n")
    linked = subprocess.run([gcc, "main.c", "-lno_such_lib_here", "-o", "main"], cwd=tmp_path,
                            capture_output=True, text=True)
    assert linked.returncode != 0
    lines = ["--- output: app_pkg", *linked.stderr.splitlines(), "---",
             "Failed   <<< app_pkg [1.0s, exited with code 2]"]
    message = colcon.failure_message(Workspace("/docker-ros/ws"), lines, 2)
    assert "cannot find -lno_such_lib_here" in message, message


# --- common ---


def test_phases():
    assert phases("x", "all") == (True, True)
    assert phases("x", "collect") == (True, False)
    assert phases("x", "apply") == (False, True)
    with pytest.raises(StepError):
        phases("x", "install")


def test_parse_env0():
    data = b"A=1\0B=x=y\0_=/usr/bin/env\0SHLVL=1\0MULTI=a\nb\0"
    assert parse_env0(data) == {"A": "1", "B": "x=y", "MULTI": "a\nb"}


def test_sourced_env_sources_in_order_and_reports_failures(tmp_path):
    first = tmp_path / "first.bash"
    first.write_text('export ROS_DISTRO=test\nexport CHAIN="a"\necho noise\n')
    second = tmp_path / "second.bash"
    second.write_text('export CHAIN="$CHAIN:b"\n')
    env = sourced_env([first, second], step="t", base_env={"PATH": os.environ["PATH"]})
    assert env["ROS_DISTRO"] == "test" and env["CHAIN"] == "a:b"
    assert sourced_env([], step="t", base_env={"X": "1"}) == {"X": "1"}
    broken = tmp_path / "broken.bash"
    broken.write_text("return 4\n")
    with pytest.raises(StepError) as err:
        sourced_env([first, broken], step="t")
    assert str(broken) in err.value.message


def test_ros_setup_files(tmp_path):
    settings = load_settings(environ={}, project_dir=tmp_path)
    assert ros_setup_files(settings, environ={}, root=tmp_path) == []
    humble = tmp_path / "opt/ros/humble/setup.bash"
    humble.parent.mkdir(parents=True)
    humble.write_text("")
    base = tmp_path / "opt/ws_base_image/install/setup.bash"
    base.parent.mkdir(parents=True)
    base.write_text("")
    assert ros_setup_files(settings, environ={}, root=tmp_path) == [humble, base]
    jazzy = load_settings(environ={"ROS_DISTRO": "jazzy"}, project_dir=tmp_path)
    assert ros_setup_files(jazzy, environ={}, root=tmp_path) == [base]


def test_ros_version():
    assert ros_version("noetic", {}) == "1"
    assert ros_version("jazzy", {}) == "2"
    assert ros_version(None, {}) == "1"
    assert ros_version("jazzy", {"ROS_VERSION": "1"}) == "1"


def test_workspace_relative_and_state(tmp_path):
    ws = Workspace(tmp_path)
    assert ws.relative(ws.target / "x") == "src/target/x"
    with pytest.raises(StepError) as err:
        ws.require_state("debs", "debs.json")
    assert "collect" in err.value.message
    ws.write_state("b.json", {"z": 1, "a": [2]})
    assert (ws.state / "b.json").read_text() == '{\n  "a": [\n    2\n  ],\n  "z": 1\n}\n'


def test_colcon_stamps_only_files_whose_content_changed(tmp_path):
    import os

    from docker_ros.in_image.runtime.workspace import Workspace
    from docker_ros.in_image.steps import colcon

    ws = Workspace(tmp_path)
    (ws.src / "pkg").mkdir(parents=True)
    (ws.root / "build").mkdir()
    same, edited = ws.src / "pkg" / "same.cpp", ws.src / "pkg" / "edited.cpp"
    same.write_text("a")
    edited.write_text("b")
    first, changed = colcon.stamp_changed_sources(ws)
    assert changed == {"pkg/same.cpp", "pkg/edited.cpp"}
    (ws.root / "build" / colcon.STAMP_FILE).write_text(__import__("json").dumps(first))
    for path in (same, edited):
        os.utime(path, (1000, 1000))  # old times, as COPY may give
    edited.write_text("c")
    os.utime(edited, (1000, 1000))
    second, changed = colcon.stamp_changed_sources(ws)
    assert changed == {"pkg/edited.cpp"}
    assert same.stat().st_mtime == first["pkg/same.cpp"][1]  # the time of the last build
    assert edited.stat().st_mtime > 1000
    (ws.root / "build" / colcon.STAMP_FILE).write_text(__import__("json").dumps(second))
    # A fresh clone gives unchanged files new times: they get their recorded times back.
    for path in (same, edited):
        os.utime(path, (4e9, 4e9))
    assert colcon.stamp_changed_sources(ws)[1] == set()
    assert same.stat().st_mtime == second["pkg/same.cpp"][1]
    assert edited.stat().st_mtime == second["pkg/edited.cpp"][1] < 4e9
    same.unlink()
    assert colcon.stamp_changed_sources(ws)[1] == {"pkg/same.cpp"}  # a removed file counts


def test_colcon_builds_only_changed_packages_and_dependents_when_nothing_else_changed():
    dirs = {"a": "target/a", "b": "target/b", "sub": "target/a/sub"}
    same = {"argv": ["colcon", "build"], "environment": "e1", "packages": dirs,
            "platform": "x86_64"}

    def select(previous, current, changed):
        return colcon.incremental_selection(previous, current, changed, dirs)

    assert select(same, dict(same), {"target/a/src/x.cpp"}) == (["a"], "")
    assert select(same, dict(same), {"target/a/sub/x.cpp", "target/b/y"}) == (["b", "sub"], "")
    assert select(same, dict(same), set()) == ([], "")
    # full builds, each with its reason
    assert select({}, same, {"target/a/x"}) == (
        None, "no build state (first build with this cache)")
    assert select(same, dict(same), {"target/CMakeLists.txt"}) == (
        None, "target/CMakeLists.txt changed outside every package")
    assert select(same, {**same, "environment": "e2"}, set())[1] == "the dependencies changed"
    assert select(same, {**same, "packages": {"a": "target/a"}}, set())[1] == (
        "the package set changed")
    assert "CMAKE_ARGS" in select(same, {**same, "argv": ["colcon", "build", "-x"]}, set())[1]
    assert select(same, {**same, "platform": "aarch64"}, set())[1] == (
        "the build state is for another platform")
    # a state written before the platform was recorded
    assert select({k: v for k, v in same.items() if k != "platform"}, same, set())[0] is None


def test_colcon_seeds_an_empty_build_cache_from_a_pulled_state_only(tmp_path):
    cache, seed = tmp_path / "build", tmp_path / "seed"
    cache.mkdir()
    (seed / colcon.INSTALL_COPY).mkdir(parents=True)
    (seed / colcon.INSTALL_RECORD).write_text("{}")
    (seed / colcon.INSTALL_COPY / "lib.so").write_text("seed")
    colcon.seed_build_state(cache, seed)
    assert (cache / colcon.INSTALL_COPY / "lib.so").read_text() == "seed"
    (cache / colcon.INSTALL_COPY / "lib.so").write_text("own")
    colcon.seed_build_state(cache, seed)  # the cache's own state wins
    assert (cache / colcon.INSTALL_COPY / "lib.so").read_text() == "own"
    colcon.seed_build_state(tmp_path / "other", tmp_path / "missing")  # nothing to seed from
    assert not (tmp_path / "other").exists()


def test_colcon_dependents_follow_every_dependency_kind():
    pkgs = [Package("a", Path("a"), 2, "ament_cmake", {"depend": ()}),
            Package("b", Path("b"), 2, "ament_cmake", {"build_depend": ("a",)}),
            Package("c", Path("c"), 2, "ament_cmake", {"exec_depend": ("b", "std_msgs")}),
            Package("d", Path("d"), 2, "ament_cmake", {"depend": ("std_msgs",)})]
    assert colcon.dependents(["a"], pkgs) == {"a", "b", "c"}
    assert colcon.dependents(["d"], pkgs) == {"d"}
