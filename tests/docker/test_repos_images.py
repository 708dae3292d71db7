"""A real repository in image builds (issue 11): C++ packages imported through .repos from a
local git server stay cached and uncompiled on source edits, blacklisted packages are invisible
to colcon in the dev image, the repository's own rosdep rules are used, hooks know they run in
an image. One workspace, built once for dev+run; the source-edit test builds a copy of its own
(its own images), then rebuilds it three times."""

from __future__ import annotations

import subprocess
import uuid
from pathlib import Path
from typing import Dict, Iterator, List

import pytest

from docker_ros.host import buildcontext, engine
from docker_ros.host.engine import image_exists
from tests.docker.buildhelp import (
    cached_vertices,
    docker_ros,
    own_copy,
    remove_image,
    sh,
    write_env,
)
from tests.docker.test_fast_rebuilds import compiled_objects
from tests.rosfixtures import (
    git_http_server,
    make_blacklist_repo,
    make_git_repo,
    make_package,
    write_repos,
)

pytestmark = pytest.mark.docker
IMAGE = "docker-ros-test/repos-ws:1"
USER, PASSWORD = "robot", "repos-test-secret"


def upstream_vertex(log: str) -> Dict[str, bool]:
    return {name: cached for name, cached in cached_vertices(log).items()
            if name.startswith("[upstream") and "clone --imports-only" in name}


@pytest.fixture(scope="module")
def workspace(ros1_base_image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    base = tmp_path_factory.mktemp("repos-ws")
    libs = base / "work" / "upstream_libs"
    make_package(libs / "up_a", "up_a")
    make_package(libs / "up_b", "up_b")
    remotes = base / "remotes"
    remotes.mkdir()
    make_git_repo(libs, {}, bare_copy_to=remotes / "upstream_libs.git")
    server = git_http_server(remotes, USER, PASSWORD)
    host = f"127.0.0.1:{server.server_address[1]}"

    # a new run id in the rules: the resolve stage (which sees only the files resolving reads)
    # runs and logs, however warm the engine is
    rules = f"# run {uuid.uuid4().hex}\nmy_tool:\n  debian: [jq]\n"
    repo = make_blacklist_repo(base / "repo", rules)
    (repo / "docker" / "before_dependency_installation.sh").write_text(
        'echo "$DOCKER_ROS_CONTEXT" > /docker-ros-context\n')
    write_repos(repo / ".repos", {"upstream_libs": {"url": f"http://{host}/upstream_libs.git",
                                                    "version": "main"}})
    write_env(repo, BASE_IMAGE=ros1_base_image, IMAGE=IMAGE, TARGET="dev,run",
              COMMAND="app_node && up_a_node && jq --version", BUILD_NETWORK="host",
              GIT_HTTPS_SERVER=host, GIT_HTTPS_USER=USER)
    env = {"GIT_HTTPS_PASSWORD": PASSWORD}
    first = docker_ros(repo, "build", env=env)
    assert first.returncode == 0, first.stdout[-5000:]
    try:
        yield {"repo": repo, "log": first.stdout, "env": env}
    finally:
        server.shutdown()
        server.server_close()
        for ref in (IMAGE, IMAGE + "-dev"):
            remove_image(ref)


def test_blacklisted_package_is_invisible_to_colcon_in_the_dev_image(workspace: dict) -> None:
    listed = sh(IMAGE + "-dev", "colcon list --names-only --base-paths src")
    assert listed.returncode == 0, listed.stderr
    assert sorted(listed.stdout.split()) == ["app", "meta", "up_a", "up_b"]
    assert sh(IMAGE + "-dev", "test -f src/target/unwanted/COLCON_IGNORE").returncode == 0
    assert not (workspace["repo"] / "unwanted" / "COLCON_IGNORE").exists()
    assert "meta depends on the blacklisted package unwanted" in workspace["log"]


def test_own_rosdep_rules_and_hook_context_in_the_image(workspace: dict) -> None:
    ran = subprocess.run(["docker", "run", "--rm", IMAGE], capture_output=True, text=True,
                         timeout=120)
    assert ran.returncode == 0, ran.stderr
    assert ran.stdout.split()[:2] == ["app", "up_a"] and "jq-" in ran.stdout
    assert "rosdep: my_tool -> apt: jq" in workspace["log"]
    assert sh(IMAGE, "cat /docker-ros-context").stdout.strip() == "image"


def imports_images(repo: Path) -> List[str]:
    """The imports images the tool made for this repository (its label)."""
    owner = buildcontext.imports_owner(repo)
    return sorted(engine.tags_labelled({buildcontext.IMPORTS_LABEL: owner}))


def test_source_edit_keeps_imports_cached_and_uncompiled(workspace: dict, tmp_path: Path) -> None:
    edited = f"{IMAGE}-edited"
    repo, env = own_copy(workspace["repo"], tmp_path / "repo", edited), workspace["env"]
    # a .repos of its own: its imports image is new (the tool labels what it makes)
    with (repo / ".repos").open("a") as repos:
        repos.write(f"# {uuid.uuid4().hex}\n")
    try:
        edit_and_reimport(repo, env, edited)
    finally:
        remove_image(edited)
        engine.remove_quietly(imports_images(repo))


def edit_and_reimport(repo: Path, env: Dict[str, str], image: str) -> None:
    # The copy's colcon build/ cache is its own (per folder and image): fill it first.
    first = docker_ros(repo, "build", "--target", "run", env=env)
    assert first.returncode == 0, first.stdout[-5000:]
    source = repo / "app" / "main.cpp"
    source.write_text(source.read_text().replace('"app', '"app edited'))
    edited = docker_ros(repo, "build", "--target", "run", env=env)
    assert edited.returncode == 0, edited.stdout[-5000:]
    assert list(upstream_vertex(edited.stdout).values()) == [True], upstream_vertex(edited.stdout)
    assert list(compiled_objects(edited.stdout)) == ["app"], compiled_objects(edited.stdout)

    # A changed .repos file imports again: fresh clones, same content, nothing recompiled.
    imports_before = imports_images(repo)
    assert len(imports_before) == 1, imports_before
    original = (repo / ".repos").read_text()
    with (repo / ".repos").open("a") as repos:
        repos.write("# touched\n")
    reimported = docker_ros(repo, "build", "--target", "run", env=env)
    assert reimported.returncode == 0, reimported.stdout[-5000:]
    assert list(upstream_vertex(reimported.stdout).values()) == [False]
    assert compiled_objects(reimported.stdout) == {}, compiled_objects(reimported.stdout)
    # its imports image replaced the repository's earlier one (they do not pile up)
    imports_after = imports_images(repo)
    assert len(imports_after) == 1 and imports_after != imports_before, imports_after
    assert not image_exists(imports_before[0])
    # and an edit back makes that image again, whose import BuildKit still has (by content)
    (repo / ".repos").write_text(original)
    back = docker_ros(repo, "build", "--target", "run", env=env)
    assert back.returncode == 0, back.stdout[-5000:]
    assert list(upstream_vertex(back.stdout).values()) == [True], upstream_vertex(back.stdout)
    assert imports_images(repo) == imports_before
    ran = subprocess.run(["docker", "run", "--rm", image], capture_output=True, text=True,
                         timeout=120)
    assert ran.stdout.split()[:3] == ["app", "edited", "up_a"], ran
