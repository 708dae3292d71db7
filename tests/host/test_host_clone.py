"""clone with real vcstool and local bare git repositories."""

import json
import logging
import subprocess
import sys
from pathlib import Path

import pytest

from docker_ros.in_image.runtime.workspace import StepError
from docker_ros.in_image.steps import clone
from tests.rosfixtures import git, make_git_repo, tree_snapshot, write_repos

pytestmark = pytest.mark.host


def head(path: Path) -> str:
    return git(["rev-parse", "HEAD"], path).strip()


@pytest.fixture
def remotes(tmp_path):
    """lib_a (with a nested deps.repos naming lib_b), lib_b (with an empty .repos), lib_c."""
    base = tmp_path / "remotes"
    url_c = make_git_repo(base / "lib_c", {"README": "c\n"})
    url_b = make_git_repo(base / "lib_b", {"README": "b\n", "empty.repos": "repositories: {}\n"})
    deps = tmp_path / "deps.repos"
    write_repos(deps, {"lib_b": {"url": url_b, "version": "main"}})
    url_a = make_git_repo(base / "lib_a", {"README": "a\n", "deps.repos": deps.read_text()})
    return {"a": url_a, "b": url_b, "c": url_c, "base": base}


def test_recursive_import_follows_nested_repos(project, remotes, caplog):
    write_repos(project.repo / ".repos", {"lib_a": {"url": remotes["a"], "version": "main"}})
    before = tree_snapshot(project.repo)
    caplog.set_level(logging.INFO)

    clone.main(project.ws, project.settings())

    assert (project.ws.upstream / "lib_a" / "README").read_text() == "a\n"
    assert (project.ws.upstream / "lib_b" / "README").read_text() == "b\n"
    state = project.ws.read_state("clone.json")
    assert sorted(state["imported"]) == [
        "src/target/.repos",
        "src/upstream/lib_a/deps.repos",
        "src/upstream/lib_b/empty.repos",
    ]
    assert state["imported"]["src/upstream/lib_b/empty.repos"]["repositories"] == []
    assert "lists no repositories, skipped" in caplog.text
    assert tree_snapshot(project.repo) == before  # the user's repository is untouched


def test_non_recursive_imports_only_the_configured_file(project, remotes):
    write_repos(project.repo / "deps" / "my.repos", {"lib_a": {"url": remotes["a"]}})
    settings = project.settings(
        vcs_import_file="deps/my.repos", enable_recursive_vcs_import="false"
    )

    clone.main(project.ws, settings)

    assert (project.ws.upstream / "lib_a").is_dir()
    assert not (project.ws.upstream / "lib_b").exists()


def test_rerun_imports_nothing_again(project, remotes, caplog):
    write_repos(project.repo / ".repos", {"lib_c": {"url": remotes["c"], "version": "main"}})
    clone.main(project.ws, project.settings())
    first = head(project.ws.upstream / "lib_c")
    # A new upstream commit: a second import would fetch and check it out.
    work = remotes["base"] / "lib_c"
    (work / "NEW").write_text("new\n")
    git(["add", "NEW"], work)
    git(["commit", "-q", "-m", "second"], work)
    git(["push", "-q", str(remotes["base"] / "lib_c.git"), "main"], work)
    caplog.set_level(logging.INFO)

    clone.main(project.ws, project.settings())

    assert head(project.ws.upstream / "lib_c") == first
    assert "already imported, skipped" in caplog.text
    assert "vcs import" not in caplog.text


def test_same_content_in_two_files_is_imported_once(project, remotes, caplog):
    write_repos(project.repo / ".repos", {"lib_c": {"url": remotes["c"]}})
    (project.repo / "copy").mkdir()
    (project.repo / "copy" / "again.repos").write_text((project.repo / ".repos").read_text())
    caplog.set_level(logging.INFO)

    clone.main(project.ws, project.settings())

    assert caplog.text.count("importing 1 repositories") == 1
    assert "has the content of a file already imported" in caplog.text


def test_changed_file_updates_to_its_new_version(project, remotes):
    work = remotes["base"] / "lib_c"
    git(["tag", "v1"], work)
    git(["push", "-q", "--tags", str(remotes["base"] / "lib_c.git")], work)
    write_repos(project.repo / ".repos", {"lib_c": {"url": remotes["c"], "version": "v1"}})
    clone.main(project.ws, project.settings())
    (work / "NEW").write_text("new\n")
    git(["add", "NEW"], work)
    git(["commit", "-q", "-m", "second"], work)
    git(["tag", "v2"], work)
    git(["push", "-q", "--tags", str(remotes["base"] / "lib_c.git"), "main"], work)

    write_repos(project.repo / ".repos", {"lib_c": {"url": remotes["c"], "version": "v2"}})
    clone.main(project.ws, project.settings())

    assert (project.ws.upstream / "lib_c" / "NEW").is_file()


def test_no_repos_file_is_fine(project, caplog):
    caplog.set_level(logging.INFO)
    clone.main(project.ws, project.settings())
    assert project.ws.upstream.is_dir()
    assert "no .repos files" in caplog.text


def test_bad_url_names_the_repository_and_cleans_up(project, remotes, tmp_path):
    missing = (tmp_path / "nowhere.git").as_uri()
    write_repos(
        project.repo / ".repos",
        {"good": {"url": remotes["c"], "version": "main"}, "broken": {"url": missing}},
    )
    with pytest.raises(StepError) as err:
        clone.main(project.ws, project.settings())
    message = err.value.message
    assert "repository 'broken'" in message and missing in message
    assert "does not appear to be a git repository" in message
    assert "'good'" not in message
    assert not (project.ws.upstream / "broken").exists()

    # Fixed: the next run clones what is missing.
    write_repos(
        project.repo / ".repos", {"good": {"url": remotes["c"]}, "broken": {"url": remotes["a"]}}
    )
    clone.main(project.ws, project.settings())
    assert (project.ws.upstream / "broken" / "README").read_text() == "a\n"


def test_bad_version_names_repository_and_version(project, remotes):
    write_repos(
        project.repo / ".repos", {"lib_c": {"url": remotes["c"], "version": "nosuchbranch"}}
    )
    with pytest.raises(StepError) as err:
        clone.main(project.ws, project.settings())
    assert "repository 'lib_c'" in err.value.message
    assert "nosuchbranch" in err.value.message


def test_before_dependency_identification_hook_runs_first(project, remotes):
    # The hook writes the .repos file that is then imported (cwd: workspace root).
    (project.repo / "docker").mkdir()
    (project.repo / "docker" / "before_dependency_identification.sh").write_text(
        "mkdir -p src/upstream/generated\n"
        f"printf 'repositories:\\n  lib_c:\\n    type: git\\n    url: {remotes['c']}\\n'"
        " > src/upstream/generated/gen.repos\n"
    )
    clone.main(project.ws, project.settings())
    assert (project.ws.upstream / "lib_c" / "README").is_file()


def test_before_dependency_identification_hook_runs_with_its_interpreter(project):
    """docker-ros executed the hook (chmod +x): a `#!` line other than bash's is honoured."""
    (project.repo / "docker").mkdir()
    hook = project.repo / "docker" / "before_dependency_identification.sh"
    hook.write_text("#!/usr/bin/env python3\nimport pathlib\n"
                    "pathlib.Path('from-python').write_text('yes')\n")
    mode = hook.stat().st_mode
    clone.main(project.ws, project.settings())
    assert (project.ws.root / "from-python").read_text() == "yes"
    assert hook.stat().st_mode == mode  # the repository's file is not made executable


def test_failing_hook_names_script_and_exit_code(project):
    (project.repo / "docker").mkdir()
    hook = project.repo / "docker" / "before_dependency_identification.sh"
    hook.write_text("exit 7\n")
    with pytest.raises(StepError) as err:
        clone.main(project.ws, project.settings())
    assert "before_dependency_identification.sh" in err.value.message
    assert err.value.returncode == 7


def test_dry_run_prints_and_changes_nothing(project, remotes, capsys):
    write_repos(project.repo / ".repos", {"lib_c": {"url": remotes["c"]}})
    clone.main(project.ws, project.settings(), dry_run=True)
    out = capsys.readouterr().out
    assert "[dry-run] clone: vcs import --recursive --input" in out
    assert not project.ws.upstream.exists()
    assert not project.ws.state.exists()


def test_ssh_key_reaches_git_only_through_a_temporary_file(project, remotes, tmp_path):
    """The environment the clone gives git: GIT_SSH_COMMAND carries a private key file (no ssh
    runs here: test_host_clone_ssh clones over a real sshd); it is gone afterwards."""
    key = tmp_path / "id_test"
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(key)], check=True)
    settings = project.settings(
        git_ssh_private_key=key.read_text().replace("\n", "\\n"),
        git_ssh_known_host_keys="localhost ssh-ed25519 AAAA",
    )
    with clone.git_credentials(settings, secrets_dir=tmp_path / "none") as env:
        command = env["GIT_SSH_COMMAND"]
        key_file = Path(command.split(" -i ", 1)[1].split()[0])
        assert key_file.read_text() == key.read_text()
        assert oct(key_file.stat().st_mode & 0o777) == "0o600"
        assert oct(key_file.parent.stat().st_mode & 0o777) == "0o700"
        assert "UserKnownHostsFile=" in command
    assert not key_file.exists() and not key_file.parent.exists()


FORMS = {
    # the rosinstall format, which `vcs import` reads too
    "rosinstall": "- git: {{local-name: lib_a, uri: '{a}', version: main}}\n"
                  "- git:\n    local-name: lib_c  # a comment\n    uri: {c}\n",
    # flow-style entries, a quoted URL with a comma, comments
    "flow": "# heading\nrepositories:\n  lib_a: {{type: git, url: '{a}', version: main}}\n"
            "  lib_c: {{type: git, url: \"{c}\"}}  # trailing\n",
}


@pytest.mark.parametrize("form", sorted(FORMS))
def test_real_import_of_each_form(project, tmp_path, form):
    base = tmp_path / "with,comma"
    make_git_repo(base / "lib_a", {"README": "a\n"})
    make_git_repo(base / "lib_c", {"README": "c\n"})
    # local paths (a file:// URL would escape the comma)
    urls = {"a": str(base / "lib_a.git"), "c": str(base / "lib_c.git")}
    (project.repo / ".repos").write_text(FORMS[form].format(**urls))

    clone.main(project.ws, project.settings())

    assert (project.ws.upstream / "lib_a" / "README").read_text() == "a\n"
    assert (project.ws.upstream / "lib_c" / "README").read_text() == "c\n"
    state = project.ws.read_state("clone.json")
    assert state["imported"]["src/target/.repos"]["repositories"] == ["lib_a", "lib_c"]


def test_malformed_repos_stops_before_vcs_naming_file_and_line(project):
    (project.repo / ".repos").write_text("repositories:\n  lib_a: {type: git, url: [\n")
    with pytest.raises(clone.StepError) as err:
        clone.main(project.ws, project.settings())
    assert "src/target/.repos is not a .repos file vcstool can read" in err.value.message
    assert "line 3" in err.value.message
    assert not list(project.ws.upstream.iterdir())


def test_read_without_vcstool_in_our_interpreter(project, tmp_path):
    """Our interpreter without site-packages (no vcstool, no PyYAML): the file is read by the
    python3 that has vcstool, with the same result."""
    (project.repo / ".repos").write_text(FORMS["rosinstall"].format(a="file:///a", c="file:///c"))
    src = Path(clone.__file__).resolve().parents[3]
    code = (f"import sys, json; sys.path.insert(0, {str(src)!r})\n"
            "from docker_ros.in_image.runtime.repos import read_repos\n"
            "print(json.dumps(read_repos(sys.argv[1], step='clone')))\n"
            "import importlib.util; print(importlib.util.find_spec('yaml'))")
    proc = subprocess.run([sys.executable, "-I", "-S", "-c", code,
                           str(project.repo / ".repos")], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout.splitlines()
    assert out[1] == "None"  # no yaml in that interpreter
    assert json.loads(out[0]) == {
        "lib_a": {"type": "git", "url": "file:///a", "version": "main"},
        "lib_c": {"type": "git", "url": "file:///c"}}
