"""Pure planning of image builds: argv, tags, build args, secrets, log folding."""

import fcntl
import io
import os
import re
import shlex
import tarfile
from pathlib import Path

import pytest

from docker_ros.core import errors
from docker_ros.core.loading import load_settings
from docker_ros.core.settings import FIELDS, Settings
from docker_ros.host import build, buildcontext, buildlog, buildplan, refs
from docker_ros.host.config import config_table


def settings(**environ):
    return load_settings(environ={"BASE_IMAGE": "base:1", "COMMAND": "run me", **environ},
                         project_dir=Path("/tmp/My_Robot"))


def plan(s, **kw):
    args = {"target": "run", "platform": "amd64", "tools_image": "tools:x", "tag": "img:t",
            "secrets": {}}
    args.update(kw)
    return buildplan.plan_build(s, **args)


def test_every_setting_reaches_the_build_as_its_declaration_says():
    declared = {a.lower() for a in buildplan.dockerfile_args()}
    for name, spec in FIELDS.items():
        if spec.metadata["build"] == "arg":
            assert name in declared, f"{name} is declared build='arg' but is no Dockerfile ARG"
        else:  # tool or none: never an ARG the tool would pass on by the same name
            assert name not in declared, f"{name} is a Dockerfile ARG: declare it build='arg'"
    assert buildplan.SECRETS == ("git_https_password", "git_ssh_private_key")


def test_unset_settings_stay_unset_and_set_ones_are_passed():
    argv = plan(settings(ROS_DISTRO="noetic"))
    assert "ROS_DISTRO=noetic" in argv
    assert not any(a.startswith("GIT_HTTPS_SERVER=") for a in argv)
    assert "BASE_IMAGE=base:1" in argv and "DOCKER_ROS_TOOLS=tools:x" in argv
    assert argv[argv.index("--target") + 1] == "run"
    assert argv[argv.index("--platform") + 1] == "linux/amd64"
    assert argv[-2:] == ["--load", "."]
    pairs = [argv[i + 1] for i, a in enumerate(argv) if a == "--build-arg"]
    assert all(re.fullmatch(r"[A-Z_]+=.*", p) for p in pairs), pairs
    assert [p.split("=")[0] for p in pairs].count("BASE_IMAGE") == 1


def test_secrets_are_never_build_arguments():
    s = settings(GIT_HTTPS_PASSWORD="hunter2", GIT_SSH_PRIVATE_KEY="-----KEY-----",
                 REGISTRY_PASSWORD="regpw")
    argv = plan(s, secrets={"GIT_HTTPS_PASSWORD": "env=DOCKER_ROS_SECRET_GIT_HTTPS_PASSWORD"})
    joined = " ".join(argv)
    for secret in ("hunter2", "-----KEY-----", "regpw"):
        assert secret not in joined
    assert "id=GIT_HTTPS_PASSWORD,env=DOCKER_ROS_SECRET_GIT_HTTPS_PASSWORD" in argv


def test_cache_from_and_attestations():
    argv = plan(settings(CACHE_FROM="127.0.0.1:5000/x:latest"))
    assert argv[argv.index("--cache-from") + 1] == "127.0.0.1:5000/x:latest"
    both = settings(CACHE_FROM="r/x:latest-dev, r/x:latest, r/x:latest-dev_main_ci-arm64")
    for target, sources in (("run", ["r/x:latest"]),
                            ("dev", ["r/x:latest-dev", "r/x:latest-dev_main_ci-arm64"])):
        argv = plan(both, target=target)
        assert [argv[i + 1] for i, a in enumerate(argv) if a == "--cache-from"] == sources
        assert argv.count("--cache-to") == 1
    # one kind only: every target imports it
    assert buildplan.cache_sources(["r/x:latest"], "dev") == ["r/x:latest"]
    argv = plan(settings(CACHE_FROM="127.0.0.1:5000/x:latest"))
    assert "--provenance=false" in argv and "--sbom=true" not in argv
    # BUILDX_ATTESTATIONS=true: provenance and SBOM of the dev and run images (as docker-ros's
    # --provenance=true --sbom=true), none of the results a local output writes (tests, lock)
    attested = settings(BUILDX_ATTESTATIONS="true")
    for target in ("dev", "run"):
        argv = plan(attested, target=target)
        assert "--provenance=mode=min" in argv and "--sbom=true" in argv, target
        assert "--provenance=false" not in argv, target
    for target in ("test-results", "build-state"):
        argv = plan(attested, target=target)
        assert "--provenance=false" in argv and "--sbom=true" not in argv, target


def test_attestations_need_an_engine_that_keeps_them(monkeypatch):
    """The images are loaded into an engine and pushed from it: the classic image store drops
    attestations (its docker driver refuses them), the containerd image store keeps them."""
    from docker_ros.host import builder as builders

    classic = builders.Builder("default", "docker", "default", "unix:///a.sock", False)
    containerd = builders.Builder("e26", "docker", "e26", "unix:///b.sock", True)
    assert builders.attestations_dropped(containerd, {}) == ""
    assert builders.attestations_dropped(classic, {}).startswith(
        "the images are loaded into the engine at unix:///a.sock and pushed from there, and its "
        "classic image store keeps no attestations (SBOM, provenance): turn on its containerd "
        "image store")
    # a BuildKit of its own loads them into the CLI's engine: that one's store decides
    own = builders.Builder("ci", "docker-container", "unix:///c.sock", "", False)
    monkeypatch.setattr(builders, "containerd_store", lambda host, environ: host == "unix:///b.sock")
    assert builders.attestations_dropped(own, {"DOCKER_HOST": "unix:///b.sock"}) == ""
    assert "engine at unix:///a.sock" in builders.attestations_dropped(
        own, {"DOCKER_HOST": "unix:///a.sock"})


def test_image_refs_follow_docker_ros():
    s = settings(IMAGE="Reg/Img:v1")
    assert refs.image_ref(s, "run") == "reg/img:v1"
    assert refs.image_ref(s, "dev") == "reg/img:v1-dev"
    assert refs.image_ref(s, "slim") == "reg/img:v1-slim"
    assert refs.platform_ref("reg/img:v1", "arm64", ("amd64", "arm64")) == "reg/img:v1-arm64"
    assert refs.platform_ref("reg/img:v1", "amd64", ("amd64",)) == "reg/img:v1"


def test_jobs_of_two_architectures_on_one_engine_build_under_names_of_their_own():
    """With ENABLE_SINGLEARCH_PUSH (GitLab's build-<arch> jobs) every image is built, tested,
    slimmed and pushed as `<name>-<arch>`, as docker-ros's CI builds it: an amd64 and an arm64
    job on one shell runner never tag each other's image (they did: the amd64 job pushed the
    arm64 image as `-amd64`). Without it, one platform keeps the plain name."""
    for target, name in (("run", "reg/img:v1"), ("dev", "reg/img:v1-dev"),
                         ("slim", "reg/img:v1-slim"), ("build-state", "reg/img:v1-build-state")):
        s = settings(IMAGE="reg/img:v1", PLATFORM="arm64", ENABLE_SINGLEARCH_PUSH="true")
        assert refs.target_ref(s, target, "arm64") == f"{name}-arm64"
        plain = refs.target_ref(settings(IMAGE="reg/img:v1", PLATFORM="arm64"), target, "arm64")
        assert plain == (f"{name}-arm64" if target == "build-state" else name)


def test_log_folding_per_ci():
    lines = ["#5 0.1 Starting >>> rosdep\n", "#5 0.2 something\n",
             "#5 0.3 Finished <<< rosdep [0.2s]\n"]
    for environ, start, end in (
        ({"GITHUB_ACTIONS": "true"}, "::group::rosdep", "::endgroup::"),
        ({"GITLAB_CI": "true"}, "section_start:", "section_end:"),
    ):
        out = io.StringIO()
        buildlog.stream_build(iter(lines), out, environ)
        text = out.getvalue()
        assert start in text and end in text
        assert text.index(start) < text.index("something") < text.index(end)
    plain = io.StringIO()
    buildlog.stream_build(iter(lines), plain, {})
    assert plain.getvalue() == "".join(lines)


def test_colcons_package_lines_are_not_folded():
    """colcon's `Starting >>> <package>` lines look like our steps' ones: folded, they opened a
    group per package inside the colcon step's (GitHub cannot nest groups), and the failed
    package's `Failed <<<` closed them, so the compiler's errors were folded under its name."""
    lines = ["#9 0.1 Starting >>> colcon\n", "#9 0.2 Starting >>> broken_pkg\n",
             "#9 0.3 --- output: broken_pkg\n", "#9 0.4 Failed   <<< broken_pkg [0.2s, exited "
             "with code 2]\n", "#9 0.5 Failed   <<< colcon [0.4s]\n"]
    out = io.StringIO()
    buildlog.stream_build(iter(lines), out, {"GITHUB_ACTIONS": "true"})
    groups = [line for line in out.getvalue().splitlines() if line.startswith("::")]
    assert groups == ["::group::colcon", "::endgroup::"]
    # a package named like one of our steps (`files`) is still colcon's, and the steps of
    # another build step running beside it (bake's other target, `#12`) are folded
    lines = ["#9 0.1 Starting >>> colcon\n", "#12 0.1 Starting >>> rosdep\n",
             "#9 0.2 Starting >>> files\n", "#9 0.3 Finished <<< files [0.1s]\n",
             "#9 0.4 Starting >>> pkg\n", "#12 0.5 Finished <<< rosdep [0.4s]\n",
             "#9 0.6 Finished <<< pkg [0.2s]\n", "#9 0.7 Finished <<< colcon [0.6s]\n"]
    out = io.StringIO()
    buildlog.stream_build(iter(lines), out, {"GITHUB_ACTIONS": "true"})
    folded = [line for line in out.getvalue().splitlines()]
    assert folded.index("::group::colcon") < folded.index("#9 0.2 Starting >>> files")
    assert [line for line in folded if line.startswith("::")] == [
        "::group::colcon", "::group::rosdep", "::endgroup::", "::endgroup::"]
    assert folded[-1] == "::endgroup::" and folded[-2] == "#9 0.7 Finished <<< colcon [0.6s]"


def test_step_errors_are_collected_from_the_log():
    out = io.StringIO()
    errors = buildlog.stream_build(
        iter(["#7 1.0 docker-ros rosdep: no rosdep rule for 'nope' (needed by pkg_a)\n"]),
        out, {},
    )
    assert errors == ["rosdep: no rosdep rule for 'nope' (needed by pkg_a)"]


def test_ca_bundle_accepts_file_or_folder(tmp_path):
    pem = "-----BEGIN CERTIFICATE-----\nabc\n-----END CERTIFICATE-----\n"
    (tmp_path / "certs").mkdir()
    (tmp_path / "certs" / "a.crt").write_text(pem)
    (tmp_path / "certs" / "README").write_text("not a cert")
    bundle = buildcontext.ca_bundle(tmp_path / "certs", tmp_path / "out.pem")
    assert bundle.read_text().count("BEGIN CERTIFICATE") == 1


def test_dockerignore_keeps_env_files_out_and_the_users_rules(tmp_path):
    (tmp_path / ".dockerignore").write_text("build/\n")
    staged = buildcontext.stage_dockerfile(tmp_path, _mk(tmp_path))
    ignore = (staged.parent / "Dockerfile.dockerignore").read_text().splitlines()
    assert ignore[0] == "build/" and ".env" in ignore and "**/.env" in ignore
    assert ".gitlab-ci-local" in ignore
    # what may hold credentials: git's config (a CI job token, a checkout's header)
    for name in (".git", "**/.git", ".gitlab-ci-local-variables.yml"):
        assert name in ignore, name
    assert buildcontext.left_out(".git/config") and buildcontext.left_out("sub/.git")
    left_out = buildcontext.left_out
    assert left_out("docker-ros-test-results/junit/a.xml")  # the CI template's artifact
    assert not left_out("pkg/.github/x.yml") and not left_out("pkg/a.gitignore")
    assert staged.read_text() == buildcontext.DOCKERFILE.read_text()
    assert (tmp_path / ".dockerignore").read_text() == "build/\n"


def _mk(tmp_path):
    out = tmp_path / "staged"
    out.mkdir()
    return out


def test_build_cache_is_per_repository_and_platform():
    a, b = settings(), settings(IMAGE="other/img")
    assert buildplan.cache_id(a, "amd64") == buildplan.cache_id(a, "amd64")
    assert len({buildplan.cache_id(a, "amd64"), buildplan.cache_id(a, "arm64"),
                buildplan.cache_id(b, "amd64")}) == 3


def test_until_tag():
    assert refs.until_ref(settings(IMAGE="r/i:v1"), "rosdep") == "r/i:v1-until-rosdep"


def test_bake_builds_the_targets_in_one_run_from_the_same_definitions():
    s = settings(GIT_HTTPS_PASSWORD="hunter2", BUILD_NETWORK="host", CACHE_FROM="r/x:latest")
    secrets = buildplan.plan_secrets(s, None)
    specs = {t: buildplan.definition(s, target=t, platform="arm64", tools_image="tools:x",
                                 tag=f"img:{t}", secrets=secrets) for t in ("dev", "run")}
    argv = buildplan.plan_bake(specs, "/tmp/d.json")
    assert argv[:3] == ["docker", "buildx", "bake"] and argv[-2:] == ["dev", "run"]
    text = buildplan.bake_file(specs)
    assert "hunter2" not in text and "DOCKER_ROS_SECRET_GIT_HTTPS_PASSWORD" in text
    run = specs["run"]
    assert (run["target"], run["tags"], run["platforms"]) == ("run", ["img:run"], ["linux/arm64"])
    assert run["network"] == "host" and run["cache-from"] == ["r/x:latest"]
    # the single-target argv says the same as the bake target
    one = buildplan.build_argv(run)
    assert one[one.index("--network") + 1] == "host" and "--load" in one
    assert [one[i + 1] for i, a in enumerate(one) if a == "--build-arg"] == [
        f"{k}={v}" for k, v in run["args"].items()]
    # BUILD_NETWORK needs a bake that knows `network` (0.17 and later, not Debian's 0.13);
    # with registry cache each image is the first build of its stages: one build per target
    net = settings(BUILD_NETWORK="host")
    assert buildplan.can_bake(net, True) and not buildplan.can_bake(net, False)
    assert buildplan.can_bake(settings(), False) and not buildplan.can_bake(s, True)
    assert not buildplan.can_bake(settings(CACHE_FROM="r/x:latest"), True)


def test_bake_is_granted_our_folders_and_the_host_network_when_it_checks_entitlements(tmp_path):
    context = tmp_path / "ws"
    context.mkdir()
    specs = {"run": {}}
    # a buildx whose `bake --help` lists --allow (echo prints its arguments), and one without
    checks, old = ("echo", "--allow"), ("true",)
    host = settings(BUILD_NETWORK="host", BUILD_CONTEXT=str(context))
    allow = buildplan.bake_allow(checks, host, "/tmp/t")
    assert allow == ["fs.read=/tmp/t", f"fs.read={context.resolve()}", "network.host"]
    assert buildplan.plan_bake(specs, "/tmp/t/d.json", ["docker", "buildx"], allow)[2:6] == [
        "bake", "--allow=fs.read=/tmp/t", f"--allow=fs.read={context.resolve()}",
        "--allow=network.host"]
    assert "network.host" not in buildplan.bake_allow(checks, settings(BUILD_CONTEXT=str(context)),
                                                  "/tmp/t")
    assert buildplan.bake_allow(old, host, "/tmp/t") == []


def test_a_failed_step_is_found_in_a_bake_log_too():
    lines = ["#7 [dev source 2/2] RUN --mount=... clone\n", "#9 [run build 1/1] RUN colcon\n",
             "#9 3.1 docker-ros colcon: package a failed to build\n"]
    assert buildlog.failed_step(lines) == ("build", "colcon")


def test_with_cache_from_the_run_image_installs_on_a_copy_of_base():
    assert buildplan.run_base(settings()) == "base"
    assert buildplan.run_base(settings(CACHE_FROM="r/img:1-dev,r/img:1")) == "base-run"
    spec = buildplan.definition(settings(CACHE_FROM="r/img:1"), target="run", platform="amd64",
                            tools_image="t", tag="x", secrets={})
    assert spec["args"]["DOCKER_ROS_RUN_BASE"] == "base-run"


def test_base_run_is_base_with_one_env_first():
    """The Dockerfile defines base-run as base again after one ENV (the run image's own chain
    with CACHE_FROM): kept a copy of base here, as no tool writes it."""
    text = buildcontext.DOCKERFILE.read_text()

    def stage(name):
        start = text.index(f"FROM ${{BASE_IMAGE}} AS {name}\n")
        return text[start:text.index("\n# ----", start)]

    copy = stage("base-run")
    assert copy == stage("base").replace(" AS base\n", " AS base-run\nENV DOCKER_ROS_RUN_CHAIN=1\n")
    assert "prepare --dependency-types exec" in copy


def test_skeleton_holds_what_the_source_stage_reads_and_no_source_file(tmp_path):
    from docker_ros.host.buildcontext import additional_files_pattern, skeleton_files, source_stages

    (tmp_path / "pkg" / "src").mkdir(parents=True)
    (tmp_path / "pkg" / "package.xml").write_text("<package/>")
    (tmp_path / "pkg" / "src" / "main.cpp").write_text("int main() {}")
    (tmp_path / "docker" / "additional-files").mkdir(parents=True)
    (tmp_path / "docker" / "additional-debs.txt").write_text("jq\n")
    (tmp_path / "docker" / "additional-files" / "a.conf").write_text("a")
    (tmp_path / ".repos").write_text("repositories: {}\n")
    # a requirement file's nested -r/-c files (relative to it), not a missing one
    (tmp_path / "common").mkdir()
    (tmp_path / "docker" / "additional-pip-requirements.txt").write_text(
        "-r ../common/req.txt\n-r gone.txt\n")
    (tmp_path / "common" / "req.txt").write_text("-c pins.txt\n")
    (tmp_path / "common" / "pins.txt").write_text("a<2\n")
    settings = load_settings(environ={"BASE_IMAGE": "b:1", "COMMAND": "c",
                                      "BUILD_CONTEXT": str(tmp_path)}, project_dir=tmp_path)
    assert skeleton_files(settings, tmp_path) == [
        ".repos", "common/pins.txt", "common/req.txt", "docker/additional-debs.txt",
        "docker/additional-files/a.conf", "docker/additional-pip-requirements.txt",
        "pkg/package.xml"]
    assert source_stages(settings)["DOCKER_ROS_SOURCE_START"] == "skeleton"
    # the dev image's sources lose docker/additional-files: the build context leaves it out
    # (its files come with the skeleton), so no step removes it on each source edit
    assert source_stages(settings)["DOCKER_ROS_DEV_TREE"] == "tree-marked"
    assert additional_files_pattern(settings) == "/docker/additional-files"

    def other(files_dir: str) -> Settings:
        return load_settings(environ={"BASE_IMAGE": "b:1", "COMMAND": "c", "BUILD_CONTEXT":
                                      str(tmp_path), "ADDITIONAL_FILES_DIR": files_dir},
                             project_dir=tmp_path)

    assert source_stages(other("docker/none"))["DOCKER_ROS_DEV_TREE"] == "tree-marked"
    assert additional_files_pattern(other("docker/none")) is None
    assert additional_files_pattern(other("./docker/additional-files/")) == (
        "/docker/additional-files")
    # the repository itself stays; a path a .dockerignore line would read as a pattern is
    # removed by a step of its own instead
    assert additional_files_pattern(other(".")) is None
    (tmp_path / "maps[1]").mkdir()
    assert additional_files_pattern(other("maps[1]")) is None
    assert source_stages(other("maps[1]"))["DOCKER_ROS_DEV_TREE"] == "tree-pruned"
    # what the build context leaves out (credentials in .env files) stays out of it too
    (tmp_path / "docker" / "additional-files" / ".env").write_text("GIT_HTTPS_PASSWORD=x")
    assert "docker/additional-files/.env" not in skeleton_files(settings, tmp_path)
    # a hook may change any file, and .dockerignore patterns are BuildKit's to apply: the
    # source stage then reads the whole build context
    for name in ("docker/before_dependency_identification.sh", ".dockerignore"):
        (tmp_path / name).write_text("true\n")
        assert skeleton_files(settings, tmp_path) is None
        assert additional_files_pattern(settings) is None  # (the source stage reads it)
        assert source_stages(settings) == {"DOCKER_ROS_SOURCE_START": "checkout",
                                           "DOCKER_ROS_TREE": "source",
                                           "DOCKER_ROS_DEV_TREE": "tree-pruned"}
        (tmp_path / name).unlink()


# The endings of real buildx runs (docker driver, buildx 0.13, Engine 20.10).
DAEMON_RESTARTED = [
    "#19 [source 1/1] RUN python3 -m docker_ros.in_image.steps clone\n",
    "#19 1.399 Starting >>> clone\n",
    "ERROR: failed to receive status: rpc error: code = Unavailable desc = error reading from "
    "server: EOF\n",
]
INTERRUPTED = [
    "#19 1.399 started-f90bde4cdac0487189b584bc5467c781\n",
    "#19 CANCELED\n",
    "ERROR: failed to solve: Canceled: context canceled\n",
]


def test_a_lost_engine_is_named_and_a_rerun_called_safe():
    assert buildlog.engine_lost(DAEMON_RESTARTED).endswith("error reading from server: EOF")
    refused = ["#3 DONE 0.1s\n", "ERROR: Cannot connect to the Docker daemon at "
               "unix:///var/run/docker.sock. Is the docker daemon running?\n"]
    assert buildlog.engine_lost(refused).startswith("ERROR: Cannot connect to the Docker daemon")
    dial = ["error: dial unix /var/run/docker.sock: connect: connection refused\n"]
    assert buildlog.engine_lost(dial)
    # a build step's own output never counts (a refused git server inside a RUN)
    step = ["#9 0.5 fatal: unable to access: Failed to connect: connection refused\n",
            "#9 0.6 rpc error: code = Unavailable desc = transport is closing\n",
            "ERROR: failed to solve: process \"/bin/sh -c x\" did not complete successfully\n"]
    assert buildlog.engine_lost(step) == "" and buildlog.engine_lost(INTERRUPTED) == ""
    reason = buildlog.failure_reason(DAEMON_RESTARTED, [])
    assert reason.startswith("failed: the connection to the Docker engine was lost (ERROR: "
                             "failed to receive status: rpc error: code = Unavailable")
    assert reason.endswith("nothing was tagged, so rerunning is safe once `docker info` answers")
    assert buildlog.failure_reason(step, ["clone: x"]) == "failed in step clone: x"
    assert buildlog.failure_reason(step, []) == "failed (see the BuildKit error above)"


def test_an_interrupted_buildx_is_told_from_a_failed_one():
    assert buildlog.cancelled(INTERRUPTED)
    assert not buildlog.cancelled(DAEMON_RESTARTED)
    # bake: one target failed, the other cancelled; buildx names the failure last
    failed = ["#12 CANCELED\n", "ERROR: target dev: failed to solve: Canceled: context canceled\n",
              "ERROR: target run: failed to solve: process \"/bin/sh -c x\" did not complete "
              "successfully: exit code: 1\n"]
    assert not buildlog.cancelled(failed)
    assert not buildlog.cancelled(["#5 0.1 ERROR: context canceled\n"])


def test_each_platform_builds_from_its_own_base_image():
    amd64, arm64 = refs.LocalBase("amd64", False), refs.LocalBase("arm64", False)
    both = {"b:1": amd64, "b:1-arm64": arm64}
    assert refs.choose_base("b:1", "amd64", both) == ("b:1", "")
    base, why = refs.choose_base("b:1", "arm64", both)
    assert base == "b:1-arm64" and why.startswith("base image (arm64): b:1-arm64")
    # a name only a registry holds, or holds as a multi-arch list: BuildKit picks the platform
    assert refs.choose_base("reg/b:1", "arm64", {}) == ("reg/b:1", "")
    pulled = {"reg/b:1": refs.LocalBase("amd64", True)}
    base, why = refs.choose_base("reg/b:1", "arm64", pulled)
    assert base == "reg/b:1" and "pulls its arm64 image from its registry" in why


def test_a_local_base_of_another_architecture_is_never_used_for_a_platform():
    local = {"b:1": refs.LocalBase("amd64", False), "b:1-arm64": refs.LocalBase("amd64", False)}
    with pytest.raises(errors.BuildError) as error:
        refs.choose_base("b:1", "arm64", local)
    message = str(error.value)
    assert "BASE_IMAGE b:1 is a local amd64 image from no registry" in message
    assert "inv bootstrap-base-image --platform arm64" in message and "b:1-arm64" in message


def test_a_misspelt_base_image_names_the_local_image_it_misspells():
    tags = ["ros:noetic", "ros:humble", "docker-ros/ros1:bookworm",
            "docker-ros/ros1:bookworm-arm64", "docker-ros-tools:0123456789abcdef-amd64"]
    assert refs.closest_image("ros:notic", tags) == "ros:noetic"
    assert refs.closest_image("docker-ros/ros1:bookwrom", tags) == "docker-ros/ros1:bookworm"
    # another image of the same repository, or of another name, is not a typo of it
    assert refs.closest_image("ros:jazzy", tags) == ""
    assert refs.closest_image("rwthika/ros2:jazzy", tags) == ""
    # close, but in digits: another version or image, not a typo
    assert refs.closest_image("docker-ros/ros2:bookworm", tags) == ""
    assert refs.closest_image("ros:noetic-1", ["ros:noetic-2"]) == ""
    # the closest that is no other version
    assert refs.closest_image("docker-ros/ros1:bookwrm-arm64", tags) == (
        "docker-ros/ros1:bookworm-arm64")
    assert refs.closest_image("ros:noetic", []) == ""


def test_a_base_is_in_a_registry_only_under_a_name_it_was_pulled_or_pushed_as():
    digests = ["127.0.0.1:5000/other@sha256:1", "ros@sha256:2"]
    assert refs.from_registry("ros:noetic", digests)
    assert refs.from_registry("127.0.0.1:5000/other:tag", digests)
    assert not refs.from_registry("docker-ros/ros1:bookworm", digests)
    assert not refs.from_registry("127.0.0.1:5000/ros:noetic", digests)


def layer_bytes(folder: Path) -> bytes:
    """folder as an image layer holds it: a tar with each entry's time and mode."""
    data = io.BytesIO()
    with tarfile.open(fileobj=data, mode="w") as tar:
        tar.add(str(folder), arcname="docker-ros")
    return data.getvalue()


def test_the_tools_tree_makes_the_same_layer_whenever_and_however_it_was_installed(tmp_path):
    """Two CI runners install docker-ros at other times (pip gives files the install's time)
    and perhaps with another umask: the tools image's layer must not differ, or no step that
    mounts it comes from a registry cache on an empty runner."""
    trees = []
    for name, umask in (("one", 0o022), ("two", 0o002)):
        old = os.umask(umask)
        try:
            buildcontext.tools_tree(tmp_path / name)
        finally:
            os.umask(old)
        folder = tmp_path / name / "docker-ros"
        os.utime(next(folder.rglob("*.py")), (len(trees) * 1000, len(trees) * 1000))
        trees.append(folder)
    assert layer_bytes(trees[0]) != layer_bytes(trees[1])  # the copies differ as installed
    for folder in trees:
        buildcontext.reproducible(folder)
    assert layer_bytes(trees[0]) == layer_bytes(trees[1])
    scripts = list(trees[0].rglob("*.sh"))
    assert scripts and all(p.stat().st_mode & 0o777 == 0o755 for p in scripts)


def test_a_new_imports_image_replaces_the_repository_s_others_of_its_platform():
    current = f"{buildcontext.IMPORTS_REPOSITORY}:bbbb-amd64"
    tags = [current, f"{buildcontext.IMPORTS_REPOSITORY}:aaaa-amd64",
            f"{buildcontext.IMPORTS_REPOSITORY}:aaaa-arm64", "my/own:aaaa-amd64"]
    assert buildcontext.superseded_imports(tags, current) == [
        f"{buildcontext.IMPORTS_REPOSITORY}:aaaa-amd64"]
    assert buildcontext.imports_owner(Path("a")) == buildcontext.imports_owner(Path("a").resolve())
    assert buildcontext.imports_owner(Path("a")) != buildcontext.imports_owner(Path("b"))



def test_tagged_in_log_reads_buildkits_names() -> None:
    lines = ["#41 naming to docker.io/library/robot:1-dev done",
             "#42 naming to 127.0.0.1:5000/team/robot:1 done",
             "#43 naming to docker.io/team/arm:1 0.0s"]
    assert buildlog.tagged_in_log(lines, "robot:1-dev")
    assert buildlog.tagged_in_log(lines, "127.0.0.1:5000/team/robot:1")
    assert not buildlog.tagged_in_log(lines, "robot:1")  # not `robot:1-dev`
    assert not buildlog.tagged_in_log(lines, "team/arm:1")  # started, not done


def test_a_target_failing_after_another_was_built_alone_names_the_built_one(
        monkeypatch, tmp_path):
    """With one buildx run per target (BUILD_NETWORK on a bake that knows no `network`, as
    Debian's 0.13), run failing after dev was built and tagged names dev as built, as a failing
    bake run does."""
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "package.xml").write_text("<package/>")
    s = load_settings(environ={"BASE_IMAGE": "base:1", "COMMAND": "run me",
                               "BUILD_NETWORK": "host"}, project_dir=tmp_path)
    monkeypatch.setattr(build, "selected_builder", lambda settings: None)
    monkeypatch.setattr(build.builder, "cache_export", lambda chosen: "inline")
    monkeypatch.setattr(build.builder, "buildx_command", lambda chosen, name: ["buildx"])
    monkeypatch.setattr(build.builder, "own_buildkit", lambda chosen: False)
    monkeypatch.setattr(buildplan, "bake_allows", lambda buildx: False)
    monkeypatch.setattr(build, "ensure_tools_image", lambda platform, buildx, **k: "tools:x")
    monkeypatch.setattr(build, "ensure_imports_image", lambda settings, platform, buildx, **k: "")
    monkeypatch.setattr(build, "tag_local_base", lambda settings, platform: None)
    monkeypatch.setattr(build, "platform_base", lambda settings, platform: ("base:1", ""))

    def run_buildx(argv, targets, platform, **kw):
        if "run" in targets:
            raise errors.BuildError("building target 'run' (amd64) failed in step colcon: x",
                                   2, stage="build", step="colcon")
        return 1.0

    monkeypatch.setattr(build, "run_buildx", run_buildx)
    with pytest.raises(errors.BuildError) as failed:
        build.build_images(s, targets={"dev": "img:t-dev", "run": "img:t"}, platform="amd64",
                           out=io.StringIO(), environ={})
    assert str(failed.value) == ("building target 'run' (amd64) failed in step colcon: x; "
                                 "'dev' was built: img:t-dev")
    assert (failed.value.returncode, failed.value.stage, failed.value.step) == (
        2, "build", "colcon")

    class Terminated(KeyboardInterrupt):  # (as settingstask.Terminated: SIGTERM keeps its type)
        pass

    def ctrl_c(argv, targets, platform, **kw):
        if "run" in targets:
            raise Terminated
        return 1.0

    monkeypatch.setattr(build, "run_buildx", ctrl_c)
    with pytest.raises(Terminated) as stopped:
        build.build_images(s, targets={"dev": "img:t-dev", "run": "img:t"}, platform="amd64",
                           out=io.StringIO(), environ={})
    assert str(stopped.value) == "'dev' was built: img:t-dev"


def test_the_repository_s_other_imports_images_go_only_after_the_build(monkeypatch, tmp_path):
    # Two builds of one repository at once, the second after a package.xml edit: the second
    # removed the first's imports image before the first's BuildKit had read it, and the
    # first failed looking for docker-ros-imports:... on Docker Hub.
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "package.xml").write_text("<package/>")
    s = settings(BUILD_CONTEXT=str(tmp_path))
    owner = buildcontext.imports_owner(tmp_path)[:8]
    other = f"{buildcontext.IMPORTS_REPOSITORY}:0000000000000000-{owner}-amd64"
    images = {other}
    seen_in_build = []
    monkeypatch.setattr(build, "selected_builder", lambda settings: None)
    monkeypatch.setattr(build.builder, "cache_export", lambda chosen: "inline")
    monkeypatch.setattr(build.builder, "buildx_command", lambda chosen, name: ["docker", "buildx"])
    monkeypatch.setattr(build.builder, "own_buildkit", lambda chosen: False)
    monkeypatch.setattr(build, "ensure_tools_image", lambda platform, buildx, **k: "tools:1")
    monkeypatch.setattr(build, "image_exists", lambda ref: ref in images)
    monkeypatch.setattr(buildcontext, "scratch_image",
                        lambda ctx, folder, ref, *a, **k: images.add(ref))
    monkeypatch.setattr(build, "tag_local_base", lambda settings, platform: None)
    monkeypatch.setattr(build, "prepare_pin_secrets", lambda *a: ({}, {}))
    monkeypatch.setattr(build, "platform_base", lambda settings, platform: ("base:1", ""))
    monkeypatch.setattr(build, "seed_builds", lambda *a: None)
    monkeypatch.setattr(build, "run_buildx",
                        lambda *a, **k: seen_in_build.append(set(images)) or 1.0)
    monkeypatch.setattr(build.engine, "tags_labelled", lambda labels: sorted(images))
    monkeypatch.setattr(build.engine, "remove_quietly", images.difference_update)
    build.build_images(s, targets={"run": "r:1"}, platform="amd64", out=io.StringIO())
    assert other in seen_in_build[0]  # still there while the build ran
    assert other not in images and len(images) == 1  # then only the new one stays
    # another build of the repository running (its shared lock on the folder): its imports
    # image stays; the last build to end removes the superseded ones
    images.add(other)
    running = os.open(str(tmp_path), os.O_RDONLY)
    try:
        fcntl.flock(running, fcntl.LOCK_SH)
        build.build_images(s, targets={"run": "r:1"}, platform="amd64", out=io.StringIO())
        assert other in images
    finally:
        os.close(running)
    build.build_images(s, targets={"run": "r:1"}, platform="amd64", out=io.StringIO())
    assert other not in images


def test_a_ctrl_c_after_buildkit_tagged_an_image_says_so():
    """buildx cancelled by Ctrl-C after it had named one target: the interruption names it
    (it stays tagged; README: 'interrupted' otherwise tags nothing)."""
    log = ("#20 naming to docker.io/library/img:t-dev done\n"
           "ERROR: failed to solve: Canceled: context canceled\n")
    argv = ["bash", "-c", f"printf '%s' {shlex.quote(log)}; exit 1"]
    with pytest.raises(KeyboardInterrupt) as stopped:
        build.run_buildx(argv, {"dev": "img:t-dev", "run": "img:t"}, "amd64", env=os.environ,
                         out=io.StringIO(), environ={})
    assert str(stopped.value) == "'dev' was built: img:t-dev"
    argv = ["bash", "-c", "echo 'ERROR: failed to solve: Canceled: context canceled'; exit 1"]
    with pytest.raises(KeyboardInterrupt) as plain:
        build.run_buildx(argv, {"run": "img:t"}, "amd64", env=os.environ, out=io.StringIO(),
                         environ={})
    assert str(plain.value) == ""


def test_rmw_implementation_is_passed_when_chosen():
    """Unchosen, the base image's RMW_IMPLEMENTATION stays (docker-ros's build.sh passed it only
    when set); the default written in .env or a flag is a choice too; the CI integrations'
    default in the environment is not."""
    def passed(s):
        return [a for a in plan(s) if a.startswith("RMW_IMPLEMENTATION=")]

    assert passed(settings()) == []
    assert passed(settings(RMW_IMPLEMENTATION="rmw_fastrtps_cpp")) == []  # (CI's default)
    assert passed(settings(RMW_IMPLEMENTATION="rmw_zenoh_cpp")) == [
        "RMW_IMPLEMENTATION=rmw_zenoh_cpp"]
    chosen = load_settings(environ={"BASE_IMAGE": "base:1", "COMMAND": "run me"},
                           dotenv={"RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"},
                           project_dir=Path("/tmp/My_Robot"))
    assert passed(chosen) == ["RMW_IMPLEMENTATION=rmw_fastrtps_cpp"]
    # `inv config` says which: an unchosen value is not what the image gets on every base
    def shown(s):
        return next(line for line in config_table(s).splitlines()
                    if line.startswith("RMW_IMPLEMENTATION"))

    assert shown(settings()).endswith(
        "default (not chosen: a base image's own RMW_IMPLEMENTATION stays)")
    assert shown(chosen).endswith(".env")


def test_a_platform_failing_after_another_names_what_that_one_built(monkeypatch, tmp_path):
    """PLATFORM=amd64,arm64: arm64 failing (or Ctrl-C) names amd64's tagged images."""
    from docker_ros.host import pipeline
    from docker_ros.host.pipeline import TaskError

    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "package.xml").write_text("<package/>")
    s = load_settings(environ={"BASE_IMAGE": "base:1", "COMMAND": "run me", "IMAGE": "img:t",
                               "PLATFORM": "amd64,arm64"}, project_dir=tmp_path)
    monkeypatch.setattr(pipeline, "check_inputs", lambda settings, targets, required: None)
    monkeypatch.setattr(build, "check_engine", lambda settings: None)
    monkeypatch.setattr(refs, "platform_base", lambda settings, platform: ("base:1", ""))
    monkeypatch.setattr(build, "summary_table", lambda built: "")
    failure: BaseException = errors.BuildError("building target 'run' (arm64) failed in step "
                                              "colcon: x", 2, stage="build", step="colcon")

    def build_images(settings, *, targets, platform, **kw):
        if platform == "arm64":
            raise failure
        return [build.BuiltImage(t, ref, platform, 1.0) for t, ref in targets.items()]

    monkeypatch.setattr(build, "build_images", build_images)
    with pytest.raises(TaskError) as failed:
        pipeline.build_targets(s, ("dev", "run"), dry_run=False)
    assert str(failed.value).endswith("colcon: x; 'dev' was built: img:t-dev-amd64; 'run' was "
                                      "built: img:t-amd64")
    failure = KeyboardInterrupt()
    with pytest.raises(KeyboardInterrupt) as stopped:
        pipeline.build_targets(s, ("dev", "run"), dry_run=False)
    assert str(stopped.value) == "'dev' was built: img:t-dev-amd64; 'run' was built: img:t-amd64"


# A rosdep step on an engine whose containers have no outbound NAT (Engine 26 of setup.sh):
# apt-get update only warns, then apt finds no package (real lines, shortened).
NO_NAT = [
    "#14 [dev dependencies-dev 2/3] RUN python3 -m docker_ros.in_image.steps rosdep\n",
    "#14 0.9 Err:1 http://deb.debian.org/debian trixie InRelease\n",
    "#14 0.9   Temporary failure resolving 'deb.debian.org'\n",
    "#14 1.0 W: Failed to fetch http://deb.debian.org/debian/dists/trixie/InRelease  "
    "Temporary failure resolving 'deb.debian.org'\n",
    "#14 1.2 E: Unable to locate package libyaml-cpp-dev\n",
    "#14 1.3 docker-ros rosdep: apt-get install failed with exit code 100\n",
    "#14 ERROR: process \"/bin/sh -c python3 -m docker_ros.in_image.steps rosdep\" did not "
    "complete successfully: exit code: 100\n",
]


def test_a_step_without_network_points_at_build_network_host():
    reason = buildlog.failure_reason(NO_NAT, ["rosdep: apt-get install failed"], "")
    assert reason.startswith("failed in step rosdep: apt-get install failed; the step could not "
                             "reach the network (Temporary failure resolving 'deb.debian.org')")
    assert reason.endswith("set BUILD_NETWORK=host")
    assert "BUILD_NETWORK is none" in buildlog.failure_reason(NO_NAT, ["rosdep: x"], "none")
    assert buildlog.failure_reason(NO_NAT, ["rosdep: x"], "host") == "failed in step rosdep: x"
    # only the failed step's output counts (an earlier step's warning is no cause)
    earlier = ["#9 0.5 W: Failed to fetch x  Temporary failure resolving 'deb.debian.org'\n",
               "#9 DONE 0.6s\n", *NO_NAT[4:]]
    assert buildlog.network_hint(earlier, "") == ""
    pip = ["#8 3.0 WARNING: Retrying ... NewConnectionError('<pip._vendor.urllib3.connection."
           "HTTPSConnection object>: Failed to establish a new connection: [Errno -3] Temporary "
           "failure in name resolution')\n", "#8 ERROR: process did not complete\n"]
    assert "(Failed to establish a new connection)" in buildlog.network_hint(pip, "default")


def test_a_layout_context_names_its_image_by_tag_and_digest(tmp_path: Path) -> None:
    """The digest chooses the image; the tag keeps buildx 0.33.0 from making `<store>:@<digest>`
    of a digest alone (docker/buildx#3793)."""
    ref = "docker-ros-tools:0123abcd-amd64"
    folder = buildcontext.layout_folder(tmp_path, ref)
    folder.mkdir()
    (folder / "index.json").write_text(
        '{"schemaVersion": 2, "manifests": [{"digest": "sha256:' + "a" * 64 + '"}]}')
    assert buildcontext.scratch_layout(tmp_path, ref) == (
        f"oci-layout://{tmp_path}/docker-ros-tools_0123abcd-amd64:0123abcd-amd64@sha256:"
        + "a" * 64)
