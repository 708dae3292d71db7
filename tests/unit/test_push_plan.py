"""Push planning: docker-ros tag rules, latest tags, manifest lists for several platforms."""

from pathlib import Path

import pytest

from docker_ros.core.errors import BuildError
from docker_ros.core.loading import load_settings
from docker_ros.host import engine
from docker_ros.host.push import (
    also_ref,
    auth_config,
    execute,
    official_only_names,
    plan_manifest,
    plan_outputs,
    plan_push,
    ref_registry,
    registry_warning,
    run_commands,
    slimmed_from,
    write_outputs,
)


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
    assert also_ref("127.0.0.1:5000/img", "latest", "run") == "127.0.0.1:5000/img:latest"
    assert also_ref("127.0.0.1:5000/img:v1", "latest", "slim") == "127.0.0.1:5000/img:latest-slim"
    # `latest<postfix>` (GitHub, another branch) gets the target before the postfix; a git tag
    # that happens to end like a custom IMAGE_POSTFIX stays whole
    assert also_ref("r/img:v1", "latest_b_ci", "dev", "_b_ci") == "r/img:latest-dev_b_ci"
    assert also_ref("r/img:v1", "v1.2.0", "dev", "0") == "r/img:v1.2.0-dev"


def test_several_platforms_push_arch_images_and_one_manifest_list():
    s = settings(IMAGE="127.0.0.1:5000/img:v1", PLATFORM="amd64,arm64")
    assert plan_push(s, s.target) == [
        ["docker", "push", "127.0.0.1:5000/img:v1-amd64"],
        ["docker", "push", "127.0.0.1:5000/img:v1-arm64"],
        ["docker", "buildx", "imagetools", "create", "--tag", "127.0.0.1:5000/img:v1",
         "127.0.0.1:5000/img:v1-amd64", "127.0.0.1:5000/img:v1-arm64"],
    ]


def test_singlearch_push_pushes_only_the_arch_name_on_arch_specific_runners():
    """docker-ros: the runner of one architecture pushes `-<arch>`, never the shared name; the
    image was built under that name (build.target_ref), so it is pushed as it is."""
    s = settings(IMAGE="reg.example/img:v1", PLATFORM="arm64", ENABLE_SINGLEARCH_PUSH="true")
    assert plan_push(s, s.target) == [["docker", "push", "reg.example/img:v1-arm64"]]
    s = settings(IMAGE="reg.example/img:v1", PLATFORM="arm64", ENABLE_SINGLEARCH_PUSH="true",
                 TARGET="dev,run", ENABLE_PUSH_AS_LATEST="true", ENABLE_SLIM="false")
    assert plan_push(s, s.target) == [
        ["docker", "push", "reg.example/img:v1-dev-arm64"],
        ["docker", "tag", "reg.example/img:v1-dev-arm64", "reg.example/img:latest-dev-arm64"],
        ["docker", "push", "reg.example/img:latest-dev-arm64"],
        ["docker", "push", "reg.example/img:v1-arm64"],
        ["docker", "tag", "reg.example/img:v1-arm64", "reg.example/img:latest-arm64"],
        ["docker", "push", "reg.example/img:latest-arm64"],
    ]


def test_singlearch_push_of_several_platforms_pushes_each_arch_name_and_no_list():
    """docker-ros's CI with ENABLE_SINGLEARCH_PUSH builds and pushes each `-<arch>` image and
    writes no manifest list under the shared name (a later `manifest` job does)."""
    s = settings(IMAGE="reg.example/img:v1", PLATFORM="amd64,arm64",
                 ENABLE_SINGLEARCH_PUSH="true")
    assert plan_push(s, s.target) == [["docker", "push", "reg.example/img:v1-amd64"],
                                      ["docker", "push", "reg.example/img:v1-arm64"]]


def test_manifest_joins_the_arch_images_of_every_platform_under_every_name():
    s = settings(IMAGE="127.0.0.1:5000/img:v1", TARGET="dev,run", PLATFORM="amd64,arm64",
                 ENABLE_PUSH_AS_LATEST="true")
    commands = plan_manifest(s, s.target)
    arch = ["127.0.0.1:5000/img:v1-dev-amd64", "127.0.0.1:5000/img:v1-dev-arm64"]
    assert commands[0] == [
        "docker", "buildx", "imagetools", "create", "--tag", "127.0.0.1:5000/img:v1-dev", *arch]
    created = [c[5] for c in commands]
    assert created == ["127.0.0.1:5000/img:v1-dev", "127.0.0.1:5000/img:latest-dev",
                       "127.0.0.1:5000/img:v1", "127.0.0.1:5000/img:latest"]


def test_the_slim_lists_leave_out_the_slim_images_a_foreign_runner_did_not_make():
    s = settings(IMAGE="reg/img:v1", TARGET="run", PLATFORM="amd64,arm64", ENABLE_SLIM="true")
    created = {c[5]: c[6:] for c in plan_manifest(s, ["run", "slim"], ["reg/img:v1-slim-arm64"])}
    assert created == {"reg/img:v1": ["reg/img:v1-amd64", "reg/img:v1-arm64"],
                       "reg/img:v1-slim": ["reg/img:v1-slim-amd64"]}
    # none slimmed: no slim list; an absent run image is left to the command's own failure
    gone = ["reg/img:v1-slim-amd64", "reg/img:v1-slim-arm64", "reg/img:v1-arm64"]
    assert [c[5:] for c in plan_manifest(s, ["run", "slim"], gone)] == [
        ["reg/img:v1", "reg/img:v1-amd64", "reg/img:v1-arm64"]]


def test_a_slim_image_belongs_to_the_run_image_its_label_names():
    """The label holds the run image's local ID: its configuration's digest (classic store),
    or the digest of its manifest or index (containerd store)."""
    label = "org.docker-ros.slim.source"
    run = {"manifest": {"digest": "sha256:m"}}
    raw = {"config": {"digest": "sha256:c"}}

    def slim(source: str) -> dict:
        return {"image": {"config": {"Labels": {label: source}}}}

    assert slimmed_from(slim("sha256:c"), run, raw)
    assert slimmed_from(slim("sha256:m"), run, raw)
    assert not slimmed_from(slim("sha256:other"), run, raw)
    assert not slimmed_from({"image": {"config": {}}}, run, raw)  # made elsewhere: no label
    # a slim image pushed as an index: buildx gives one configuration per platform
    assert slimmed_from({"image": {"linux/amd64": slim("sha256:m")["image"]}}, run, {})
    assert not slimmed_from(slim("sha256:c"), {}, {"manifests": []})


def test_outputs_name_the_pushed_images_per_target():
    s = settings(IMAGE="reg.example/img:v1", TARGET="dev,run", PLATFORM="amd64",
                 ENABLE_SINGLEARCH_PUSH="true")
    pushed = ["reg.example/img:v1-dev-amd64", "reg.example/img:v1-amd64"]
    assert plan_outputs(s, s.target, dict.fromkeys(pushed, "")) == {
        "images": "reg.example/img:v1-dev-amd64,reg.example/img:v1-amd64",
        "dev-image": "reg.example/img:v1-dev-amd64",
        "image": "reg.example/img:v1-amd64",
    }


def test_outputs_are_appended_to_the_github_output_file(tmp_path):
    out = tmp_path / "output"
    out.write_text("earlier=1\n")
    write_outputs({"images": "a:1,b:2", "image": "a:1"}, {"GITHUB_OUTPUT": str(out)})
    write_outputs({"images": "ignored"}, {})
    assert out.read_text() == "earlier=1\nimages=a:1,b:2\nimage=a:1\n"


def test_a_push_the_registry_refuses_for_want_of_a_login_names_the_login_settings(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A CI job without (valid) REGISTRY_USER/REGISTRY_PASSWORD fails at the push after the
    whole build: the line names the settings to check, not only the engine's answer; other
    failures keep their own reason only."""
    def refused(ref: str, auth: object) -> None:
        raise engine.EngineError(f"docker push {ref} failed: no basic auth credentials")

    monkeypatch.setattr(engine, "push", refused)
    with pytest.raises(BuildError) as raised:
        execute(["docker", "push", "reg:5000/x:1"], settings())
    assert str(raised.value) == (
        "docker push reg:5000/x:1 failed: no basic auth credentials; the registry wants a "
        "login: check REGISTRY, REGISTRY_USER and REGISTRY_PASSWORD (and that the user may "
        "push there)")

    def unreachable(ref: str, auth: object) -> None:
        raise engine.EngineError(f"docker push {ref} failed: connection refused")

    monkeypatch.setattr(engine, "push", unreachable)
    with pytest.raises(BuildError) as raised:
        execute(["docker", "push", "reg:5000/x:1"], settings())
    assert str(raised.value) == "docker push reg:5000/x:1 failed: connection refused"


def test_a_registry_the_images_do_not_go_to_is_a_warning():
    """REGISTRY is only the login: an image name without a host is pushed to Docker Hub."""
    hub = settings(IMAGE="team/app:v1", TARGET="dev,run", REGISTRY="reg.example:5000")
    assert registry_warning(hub, hub.target) == (
        "warning: REGISTRY is reg.example:5000 (the login), but team/app:v1-dev, team/app:v1 go "
        "to Docker Hub: put reg.example:5000/ in front of IMAGE/IMAGE_NAME to push there")
    assert registry_warning(settings(IMAGE="reg.example:5000/team/app:v1", TARGET="run",
                                     REGISTRY="https://reg.example:5000"), ["run"]) == ""
    assert registry_warning(settings(IMAGE="team/app:v1", REGISTRY="docker.io"), ["run"]) == ""
    assert registry_warning(settings(IMAGE="team/app:v1"), ["run"]) == ""
    other = settings(IMAGE="ghcr.io/team/app:v1", REGISTRY="reg.example")
    assert "ghcr.io/team/app:v1 goes to ghcr.io" in registry_warning(other, ["run"])
    # with credentials, the warning says that they do not go there; REGISTRY unset is Docker Hub
    unset = settings(IMAGE="ghcr.io/team/app:v1", REGISTRY_USER="u", REGISTRY_PASSWORD="p")
    assert registry_warning(unset, ["run"]) == (
        "warning: REGISTRY is unset (the login goes to Docker Hub), but ghcr.io/team/app:v1 goes "
        "to ghcr.io, without REGISTRY_USER/REGISTRY_PASSWORD (only your docker configuration's "
        "own login there counts): set REGISTRY=ghcr.io to log in there")
    assert registry_warning(settings(IMAGE="team/app:v1", REGISTRY_USER="u",
                                     REGISTRY_PASSWORD="p"), ["run"]) == ""
    assert ref_registry("localhost/app") == "localhost"
    assert ref_registry("docker.io/team/app") == "docker.io"


def test_a_name_without_registry_or_namespace_is_refused_before_the_build():
    """`docker push my-image` goes to docker.io/library/my-image, which takes Docker's official
    images only: `inv push` failed so after the build and the slimming."""
    said = official_only_names(settings(IMAGE="my-image:v1", ENABLE_SLIM="true"),
                               ["dev", "run", "slim"])
    assert said == ["IMAGE_NAME 'my-image' names no registry and no namespace: docker would "
                    "push it to docker.io/library/my-image, which takes Docker's official "
                    "images only; name your registry (IMAGE=registry.example.com/my-image:tag) "
                    "or Docker Hub user (IMAGE=<user>/my-image:tag)"]
    assert [line.split(" names")[0] for line in official_only_names(
        settings(IMAGE="me/img:v1", DEV_IMAGE_NAME="dev-img"), ["dev", "run"])] == [
        "DEV_IMAGE_NAME 'dev-img'"]
    # the build state is pushed under IMAGE_NAME; a slim image by its own name
    assert [line.split(" names")[0] for line in official_only_names(
        settings(IMAGE="img:v1", SLIM_IMAGE_NAME="me/slim"), ["run", "build-state", "slim"])] == [
        "IMAGE_NAME 'img'"]
    for pushable in ("user/img:1", "reg.example/img:1", "localhost:5000/img:1"):
        assert official_only_names(settings(IMAGE=pushable), ["dev", "run"]) == [], pushable


def test_the_registry_password_goes_only_to_pushes_to_registry(monkeypatch):
    """The engine offers a push's credentials to whatever registry the name goes to: a dev
    image on another registry than REGISTRY (or a Docker Hub name) must get none of them."""
    s = settings(IMAGE="reg.example:5000/team/app:v1", DEV_IMAGE_NAME="other.example/team/dev",
                 TARGET="dev,run", REGISTRY="https://reg.example:5000", REGISTRY_USER="u",
                 REGISTRY_PASSWORD="secret")
    login = {"username": "u", "password": "secret", "serveraddress": "https://reg.example:5000"}
    assert auth_config(s, "reg.example:5000/team/app:v1") == login
    assert auth_config(s, "other.example/team/dev:v1-dev") is None
    assert auth_config(s, "team/app:v1") is None
    hub = settings(IMAGE="team/app:v1", REGISTRY_USER="u", REGISTRY_PASSWORD="secret")
    assert auth_config(hub, "team/app:v1") == {"username": "u", "password": "secret"}
    assert auth_config(hub, "docker.io/team/app:v1") is not None
    assert auth_config(hub, "ghcr.io/team/app:v1") is None
    assert auth_config(settings(REGISTRY="reg.example:5000"), "reg.example:5000/a:1") is None
    sent = []
    monkeypatch.setattr(engine, "push", lambda ref, auth: sent.append((ref, auth)))
    run_commands(s, plan_push(s, s.target), dry_run=False, label="push")
    assert sent == [("other.example/team/dev:v1-dev", None),
                    ("reg.example:5000/team/app:v1", login)]
