"""Push planning: docker-ros tag rules, latest tags, manifest lists for several platforms."""

from pathlib import Path

from docker_ros.push import insecure, latest_ref, plan_push
from docker_ros.settings import load_settings


def settings(**environ):
    return load_settings(environ={"BASE_IMAGE": "b:1", "COMMAND": "c", **environ},
                         project_dir=Path("/tmp/repo"))


def test_single_platform_pushes_the_built_names():
    s = settings(IMAGE="reg.example/org/img:v1", TARGET="dev,run", PLATFORM="amd64")
    assert plan_push(s, s.target) == [
        ["docker", "push", "reg.example/org/img:v1-dev"],
        ["docker", "push", "reg.example/org/img:v1"],
    ]


def test_push_as_latest_tags_latest_and_latest_dev():
    s = settings(IMAGE="127.0.0.1:5000/img:v1", TARGET="dev,run", PLATFORM="amd64",
                 ENABLE_PUSH_AS_LATEST="true")
    commands = plan_push(s, s.target)
    tag = ["docker", "tag", "127.0.0.1:5000/img:v1-dev", "127.0.0.1:5000/img:latest-dev"]
    assert tag in commands
    assert ["docker", "push", "127.0.0.1:5000/img:latest"] in commands
    assert latest_ref("127.0.0.1:5000/img", "run") == "127.0.0.1:5000/img:latest"


def test_several_platforms_push_arch_images_and_one_manifest_list():
    s = settings(IMAGE="127.0.0.1:5000/img:v1", PLATFORM="amd64,arm64")
    assert plan_push(s, s.target) == [
        ["docker", "push", "127.0.0.1:5000/img:v1-amd64"],
        ["docker", "push", "127.0.0.1:5000/img:v1-arm64"],
        ["docker", "manifest", "create", "--insecure", "--amend", "127.0.0.1:5000/img:v1",
         "127.0.0.1:5000/img:v1-amd64", "127.0.0.1:5000/img:v1-arm64"],
        ["docker", "manifest", "push", "--insecure", "127.0.0.1:5000/img:v1"],
    ]


def test_only_loopback_registries_are_insecure():
    assert insecure("localhost:5000/a:b") == ["--insecure"]
    assert insecure("ghcr.io/org/a:b") == []
    assert insecure("img:latest") == []


def test_singlearch_push_adds_the_arch_postfix_on_arch_specific_runners():
    s = settings(IMAGE="reg.example/img:v1", PLATFORM="arm64", ENABLE_SINGLEARCH_PUSH="true")
    assert plan_push(s, s.target) == [
        ["docker", "push", "reg.example/img:v1"],
        ["docker", "tag", "reg.example/img:v1", "reg.example/img:v1-arm64"],
        ["docker", "push", "reg.example/img:v1-arm64"],
    ]
