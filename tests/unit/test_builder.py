"""Builders and the registry cache (issue 21): which builder, what it can export, where --load
puts the images, and the argv that reaches it; pure, no Docker."""

import hashlib
import json
from pathlib import Path

from docker_ros.core.loading import load_settings
from docker_ros.host import builder, engine
from tests.unit.test_build_plan import plan, settings

LOCAL = "unix:///var/run/docker.sock"
E26 = "unix:///run/docker-ros-engine26/docker.sock"


def make(driver="docker", name="default", host=LOCAL, containerd=False, endpoint=""):
    return builder.Builder(name, driver, endpoint or name, host, containerd)


def values(argv, flag):
    return [argv[i + 1] for i, a in enumerate(argv) if a == flag]


def test_parse_inspect_reads_name_driver_and_the_first_nodes_endpoint():
    text = ("Name:          ctx\nDriver:        docker\nLast Activity: 2026-11-25 00:16:17\n\n"
            "Nodes:\nName:             ctx\nEndpoint:         ctx\nStatus:           running\n")
    assert builder.parse_inspect(text) == ("ctx", "docker", "ctx")


def test_registry_cache_where_the_builder_can_export_it_else_inline():
    assert builder.cache_export(make()) == "inline"  # Engine 20.10's classic store
    assert builder.cache_export(make(containerd=True)) == "registry"
    for driver in ("docker-container", "remote", "kubernetes"):
        assert builder.cache_export(make(driver, "b", host="")) == "registry"


def test_the_line_names_the_builder_what_load_means_and_the_cache_choice():
    line = builder.describe(make(), LOCAL, cache_to=True)
    assert line.startswith("builder: default (docker driver of the local engine")
    assert ("inline cache only (the docker driver of an engine on the classic image store "
            "cannot export a registry cache" in line)
    remote = builder.describe(make(name="e26", host=E26, containerd=True), LOCAL, True)
    assert f"engine at {E26}: --load keeps the images in that engine, not the local one" in remote
    assert "registry cache of every stage (mode=max)" in remote
    container = builder.describe(make("docker-container", "bk", host="", endpoint="tcp://b:1"),
                                 LOCAL, cache_to=False)
    assert f"--load copies each image into the local engine at {LOCAL}" in container
    assert "CACHE_TO" not in container


def test_the_sdk_follows_the_engine_that_holds_the_images():
    assert builder.images_host(make(), LOCAL) is None
    assert builder.images_host(make(name="e26", host=E26), LOCAL) == E26
    assert builder.images_host(make("docker-container", "bk", host=""), LOCAL) is None


def test_a_contexts_builder_is_reached_through_docker_context():
    assert builder.buildx_command(make(), "") == ["docker", "buildx"]
    assert builder.buildx_command(make(name="e26", host=E26), "e26") == [
        "docker", "--context", "e26", "buildx"]
    assert builder.buildx_command(make("docker-container", "bk", host=""), "bk") == [
        "docker", "buildx", "--builder", "bk"]
    # BUILDX_BUILDER (no BUILDER): buildx reads it itself
    assert builder.buildx_command(make("docker-container", "bk", host=""), "") == [
        "docker", "buildx"]


def test_endpoint_host_of_default_contexts_and_addresses(tmp_path: Path):
    assert builder.endpoint_host("default", {}) == engine.DEFAULT_HOST
    assert builder.endpoint_host("default", {"DOCKER_HOST": "tcp://h:1"}) == "tcp://h:1"
    assert builder.endpoint_host("unix:///s.sock", {}) == "unix:///s.sock"
    write_context(tmp_path, "e26", E26)
    assert builder.endpoint_host("e26", {"DOCKER_CONFIG": str(tmp_path)}) == E26


def write_context(config: Path, name: str, host: str) -> None:
    """A context as the docker CLI stores it (tests/docker/test_engine26 checks the real CLI)."""
    meta = config / "contexts" / "meta" / hashlib.sha256(name.encode()).hexdigest()
    meta.mkdir(parents=True)
    (meta / "meta.json").write_text(json.dumps(
        {"Name": name, "Metadata": {}, "Endpoints": {"docker": {"Host": host}}}))


def test_cli_host_follows_docker_host_then_the_current_context(tmp_path: Path):
    write_context(tmp_path, "e26", E26)
    environ = {"DOCKER_CONFIG": str(tmp_path)}
    assert engine.cli_host(environ) == engine.DEFAULT_HOST
    (tmp_path / "config.json").write_text(json.dumps({"currentContext": "e26"}))
    assert engine.cli_host(environ) == E26
    assert engine.cli_host({**environ, "DOCKER_CONTEXT": "default"}) == engine.DEFAULT_HOST
    assert engine.cli_host({**environ, "DOCKER_HOST": "unix:///x"}) == "unix:///x"


def test_cache_to_exports_every_stage_per_target_where_the_builder_can():
    s = settings(CACHE_TO="r/x:1-cache")
    dev = plan(s, target="dev", cache_export="registry")
    assert values(dev, "--cache-to") == ["type=registry,ref=r/x:1-cache-dev-amd64,mode=max"]
    assert values(dev, "--cache-from") == ["type=registry,ref=r/x:1-cache-dev-amd64"]
    run = plan(s, target="run", platform="arm64", cache_export="registry")
    assert values(run, "--cache-to") == ["type=registry,ref=r/x:1-cache-run-arm64,mode=max"]
    state = plan(s, target="build-state", cache_export="registry")
    assert values(state, "--cache-to") == []  # imports run's, exports nothing of its own
    assert values(state, "--cache-from") == ["type=registry,ref=r/x:1-cache-run-amd64"]


def test_cache_to_falls_back_to_inline_cache_in_the_images():
    s = settings(CACHE_TO="r/x:1-cache")
    run = plan(s, target="run", tag="r/x:1")
    assert values(run, "--cache-to") == ["type=inline"]
    assert values(run, "--cache-from") == ["r/x:1"]
    assert plan(settings(), target="run").count("--cache-to") == 0


def test_cache_to_and_builder_are_derived_in_ci_only():
    gitlab = {"GITLAB_CI": "true", "CI_COMMIT_BRANCH": "feature", "CI_DEFAULT_BRANCH": "main",
              "CI_REGISTRY_IMAGE": "reg/g/p", "BASE_IMAGE": "b:1", "TARGET": "dev,run"}
    ci = load_settings(environ=gitlab, project_dir=Path("/tmp/p"))
    assert ci.cache_to == "reg/g/p:latest_feature_ci-cache"
    assert ci.source_of("cache_to").startswith("derived from the CI pipeline")
    assert {"reg/g/p:latest_feature_ci-cache-dev-amd64", "reg/g/p:latest-cache-run-amd64"} <= set(
        ci.cache_from), ci.cache_from
    local = load_settings(environ={"BASE_IMAGE": "b:1"}, project_dir=Path("/tmp/p"))
    assert local.cache_to is None and local.builder is None
    given = load_settings(environ={**gitlab, "CACHE_TO": "x/y:c", "BUILDER": "bk"},
                          project_dir=Path("/tmp/p"))
    assert (given.cache_to, given.builder) == ("x/y:c", "bk")


def test_a_builder_is_chosen_elsewhere_by_env_context_or_buildx_use(tmp_path: Path):
    environ = {"DOCKER_CONFIG": str(tmp_path)}
    assert not builder.chosen_elsewhere(environ)
    assert builder.chosen_elsewhere({**environ, "BUILDX_BUILDER": "bk"})
    assert builder.chosen_elsewhere({**environ, "DOCKER_CONTEXT": "e26"})
    (tmp_path / "buildx").mkdir()
    current = tmp_path / "buildx" / "current"
    current.write_text(json.dumps({"Key": LOCAL, "Name": "", "Global": False}))
    assert not builder.chosen_elsewhere(environ)
    current.write_text(json.dumps({"Key": LOCAL, "Name": "bk", "Global": False}))
    assert builder.chosen_elsewhere(environ)
