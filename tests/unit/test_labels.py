"""Image labels (issue 46): the OCI ones from git and the package.xml files, the user's LABELS,
docker-ros's own namespace; how they reach the build (metadata, never a cache key)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from docker_ros.core.labels import NAMESPACE, LabelsError, parse_labels
from docker_ros.core.loading import load_settings
from docker_ros.core.settings import SettingsError
from docker_ros.host import baseimage, buildcontext, buildplan, buildstate, container, lockpins
from docker_ros.host import slim as slim_module
from docker_ros.host.labels import (
    GitFacts,
    agreed_license,
    created_time,
    image_labels,
    package_licenses,
    source_url,
    web_url,
)

FACTS = GitFacts("0123456789abcdef0123456789abcdef01234567", 1764374400,
                 "https://github.com/Org/Robot.git")


def settings(**environ):
    return load_settings(environ={"BASE_IMAGE": "base:1", "COMMAND": "run me", **environ},
                         project_dir=Path("/tmp/robot"))


def test_labels_are_comma_separated_or_one_a_line():
    assert parse_labels("") == {}
    assert parse_labels("a=1, b.c=two words ,") == {"a": "1", "b.c": "two words"}
    # one a line: a value may hold a comma (and `=`)
    assert parse_labels("team=robots, drives\nurl=https://x.example/?a=b\n\n") == {
        "team": "robots, drives", "url": "https://x.example/?a=b"}
    assert parse_labels("a=1,a=2") == {"a": "2"}  # (the last, as docker build --label)
    assert parse_labels("empty=") == {"empty": ""}


@pytest.mark.parametrize("raw", ["novalue", "=x", "bad key=1", "a=1,b"])
def test_a_bad_label_is_one_message_naming_labels_and_the_format(raw):
    with pytest.raises(SettingsError) as raised:
        settings(LABELS=raw)
    message = str(raised.value)
    assert message.count("\n") == 1 and "LABELS: " in message, message
    assert "give `key=value` entries, comma-separated or one a line" in message
    assert "(from environment)" in message


def test_docker_ros_s_own_labels_are_not_the_user_s():
    with pytest.raises(LabelsError, match=r"'org.docker-ros.lock': labels under org.docker-ros"
                                          r". are docker-ros's own: choose a key of your own"):
        parse_labels("org.docker-ros.lock=x")
    assert parse_labels("org.docker-rosy=x") == {"org.docker-rosy": "x"}


def test_docker_ros_s_labels_share_one_namespace():
    ours = [buildstate.SEED_LABEL, buildstate.INPUTS_LABEL, container.STATE_LABEL,
            buildcontext.IMPORTS_LABEL, buildcontext.INPUTS_LABEL, baseimage.RECIPE_LABEL,
            lockpins.LOCK_LABEL, slim_module.LABEL_SOURCE, slim_module.LABEL_FINGERPRINT]
    assert all(label.startswith(NAMESPACE + ".") for label in ours), ours
    assert len(set(ours)) == len(ours)
    source = "\n".join(p.read_text() for p in Path(buildplan.__file__).parent.glob("*.py"))
    # the old prefixes stand only where an image of an earlier version is still read
    old = [name for name in re.findall(
        r'"((?:io\.github\.docker-ros|io\.docker-ros|docker-ros)\.[\w.-]+)"', source)
        if not name.endswith(".json")]
    assert sorted(old) == ["docker-ros.imports-of", "io.github.docker-ros.build-state.inputs",
                           "io.github.docker-ros.build-state.seed",
                           "io.github.docker-ros.dependency-inputs"]


def test_a_build_state_of_an_earlier_version_is_still_read():
    attrs = {"Architecture": "amd64", "RepoDigests": [],
             "Config": {"Labels": {"io.github.docker-ros.build-state.inputs": "f1",
                                   "io.github.docker-ros.build-state.seed": buildstate.EMPTY}}}
    seed = buildstate.choose_seed("reg/x:1-build-state-amd64", attrs, "amd64", "f1", True)
    assert seed.reuse == "reg/x:1-build-state-amd64"
    assert buildcontext.stale_dev_image({"io.github.docker-ros.dependency-inputs": "a"}, "b",
                                        "x:1-dev")


@pytest.mark.parametrize("remote, url", [
    ("https://github.com/Org/Robot.git", "https://github.com/Org/Robot"),
    ("git@github.com:Org/Robot.git", "https://github.com/Org/Robot"),
    ("ssh://git@gitlab.example.com:2222/group/robot.git", "https://gitlab.example.com/group/robot"),
    # never a credential: GitLab's job token in its clone URL, a token in a user's remote
    ("https://gitlab-ci-token:glcbt-SECRET@gitlab.example.com/group/robot.git",
     "https://gitlab.example.com/group/robot"),
    ("https://user:ghp_SECRET@github.com/Org/Robot/?token=SECRET#x", "https://github.com/Org/Robot"),
    ("http://localhost:3000/me/robot", "http://localhost:3000/me/robot"),
    ("/srv/git/robot.git", ""),
    ("../robot", ""),
    ("", ""),
])
def test_the_source_is_the_remote_s_web_address_without_credentials(remote, url):
    assert web_url(remote) == url
    assert "SECRET" not in web_url(remote)


def test_the_ci_names_the_source_first():
    github = {"GITHUB_SERVER_URL": "https://github.com", "GITHUB_REPOSITORY": "Org/Robot"}
    assert source_url("/local/path", github) == "https://github.com/Org/Robot"
    gitlab = {"CI_PROJECT_URL": "https://gitlab.example.com/group/robot"}
    assert source_url("https://gitlab-ci-token:x@gitlab.example.com/group/robot.git",
                      gitlab) == "https://gitlab.example.com/group/robot"
    assert source_url("git@github.com:Org/Robot.git", {}) == "https://github.com/Org/Robot"


def test_created_is_the_commit_s_time_or_source_date_epoch():
    assert created_time(1764374400, {}) == "2025-11-29T00:00:00Z"
    assert created_time(1764374400, {"SOURCE_DATE_EPOCH": "0"}) == "1970-01-01T00:00:00Z"
    assert created_time(1764374400, {"SOURCE_DATE_EPOCH": "soon"}) == "2025-11-29T00:00:00Z"
    assert created_time(1764374400, {"SOURCE_DATE_EPOCH": "86400"}) == "1970-01-02T00:00:00Z"
    assert created_time(0, {}) == ""  # (not in git: no label rather than the clock's time)


@pytest.mark.parametrize("licenses, agreed", [
    ([("Apache-2.0",), ("Apache-2.0",)], "Apache-2.0"),
    ([("MIT", "BSD-3-Clause"), ("BSD-3-Clause", "MIT")], "BSD-3-Clause AND MIT"),
    ([("Apache-2.0",), ("MIT",)], ""),
    ([("Apache-2.0",), ()], ""),
    ([()], ""),
    ([], ""),
])
def test_licenses_only_where_every_package_agrees(licenses, agreed):
    assert agreed_license(licenses) == agreed


def test_licenses_are_read_from_the_repository_s_package_xml_files(tmp_path):
    for name, license in (("a", "MIT"), ("b", "MIT"), ("ignored", "GPL-3.0")):
        (tmp_path / name).mkdir()
        (tmp_path / name / "package.xml").write_text(
            f"<package format='3'><name>{name}</name><license>{license}</license></package>")
    (tmp_path / "ignored" / "COLCON_IGNORE").write_text("")
    assert sorted(package_licenses(tmp_path)) == [("MIT",), ("MIT",)]
    (tmp_path / "b" / "package.xml").write_text("<package><name>b</name>")  # (broken)
    assert agreed_license(package_licenses(tmp_path)) == ""


def test_dev_run_and_slim_images_get_the_oci_labels_then_the_user_s():
    s = settings(IMAGE="ghcr.io/org/robot:1.2", LABELS="team=drives,org.opencontainers."
                                                       "image.licenses=Proprietary")
    github = {"GITHUB_SERVER_URL": "https://github.com", "GITHUB_REPOSITORY": "Org/Robot"}
    run = image_labels(s, "run", FACTS, "Apache-2.0", github)
    assert run == {
        "org.opencontainers.image.source": "https://github.com/Org/Robot",
        "org.opencontainers.image.revision": FACTS.revision,
        "org.opencontainers.image.created": "2025-11-29T00:00:00Z",
        "org.opencontainers.image.version": "1.2",
        "org.opencontainers.image.title": "robot",
        "org.opencontainers.image.licenses": "Proprietary",  # (the user's wins)
        "team": "drives",
    }
    assert image_labels(s, "dev", FACTS, "", {})["org.opencontainers.image.title"] == \
        "robot (dev)"
    assert image_labels(s, "slim", FACTS, "", {})["org.opencontainers.image.title"] == \
        "robot (slim)"
    # not in git, no CI: only what is known
    assert image_labels(settings(), "run", GitFacts(), "", {}) == {
        "org.opencontainers.image.version": "latest",
        "org.opencontainers.image.title": "robot"}
    assert image_labels(s, "build-state", FACTS, "", {}) == {}
    assert image_labels(s, "test-results", FACTS, "", {}) == {}


def test_labels_are_the_final_image_s_metadata_never_a_build_argument():
    """A changed label (a new commit's created and revision) must not reach a RUN's cache key:
    a label goes as --label (bake: labels), never as a build argument, and the Dockerfile has
    no LABEL instruction that a build argument could feed."""
    s = settings(IMAGE="reg/robot:1", LABELS="team=drives")
    labels = image_labels(s, "run", FACTS, "MIT", {})
    spec = buildplan.definition(s, target="run", platform="amd64", tools_image="tools:x",
                                tag="reg/robot:1", secrets={}, labels=labels)
    assert labels.items() <= spec["labels"].items()
    assert not set(labels.values()) & set(spec["args"].values())
    argv = buildplan.build_argv(spec, metadata_file="/tmp/m.json")
    created = "org.opencontainers.image.created=2025-11-29T00:00:00Z"
    assert argv[argv.index(created) - 1] == "--label"
    assert argv[argv.index("--metadata-file") + 1] == "/tmp/m.json"
    assert "--metadata-file" not in buildplan.build_argv(spec)
    assert not re.search(r"^\s*LABEL\s", buildplan.DOCKERFILE.read_text(), flags=re.MULTILINE)
    # docker-ros's own labels stay: the user's cannot stand for them
    dev = buildplan.definition(s, target="dev", platform="amd64", tools_image="tools:x",
                               tag="reg/robot:1-dev", secrets={},
                               labels=image_labels(s, "dev", FACTS, "", {}))
    assert buildcontext.INPUTS_LABEL in dev["labels"]


def test_bake_writes_one_metadata_file():
    argv = buildplan.plan_bake({"dev": {}, "run": {}}, "/t/bake.json", ("docker", "buildx"),
                               metadata_file="/t/metadata.json")
    assert argv == ["docker", "buildx", "bake", "--progress=plain", "--metadata-file",
                    "/t/metadata.json", "--file", "/t/bake.json", "dev", "run"]
