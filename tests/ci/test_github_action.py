"""The GitHub Action run for real as far as this machine allows: github_harness runs
action.yml's steps in order for a push to a feature branch and to the default branch of a copy
of example/, with the inputs of docker-ros's README example, pushing to a local registry that
requires a login (github.actor / github.token, the defaults of registry-user/-password), FROM a
private base image there."""

from __future__ import annotations

import base64
import datetime
import json
import os
import re
import subprocess
from pathlib import Path

import pytest

from tests.ci.cihelp import (
    EXAMPLE_COMMAND,
    REPO,
    assert_pulled_image_runs,
    assert_sources_hold_no_secret,
    docker_recorder,
    example_repository,
    forget_local,
    git,
    push_private_base_image,
    registry_digest,
    registry_tags,
)
from tests.ci.github_harness import Event, run_action
from tests.conftest import AuthRegistry, stable_folder

pytestmark = pytest.mark.docker

IMAGE = "docker-ros-test/ci-github"
FEATURE = "Feature/GitHub--Test-Straße"
# as gacts/github-slug@v1, the Action's slug step, spells it (ß transliterated; docker-ros's
# action takes its tags from the same step)
SLUG = "feature-github-test-strasse"
LABELS = "com.example.team=drives, navigation\ncom.example.tier=1\n"


@pytest.fixture(scope="module")
def runs(ros1_base_image: str, auth_registry: AuthRegistry, engine26: str) -> dict:
    root = stable_folder("github-action")  # (the build cache id: see conftest.stable_folder)
    base = push_private_base_image(ros1_base_image, auth_registry, f"{IMAGE}-base")
    repo = example_repository(root, base)
    git(repo, "push", "-q", "origin", f"main:{FEATURE}")
    # docker-ros's README example "Build development and deployment images" as it is, plus
    # where to push (ghcr.io cannot be reached here)
    example = {"base-image": base, "command": EXAMPLE_COMMAND, "target": "dev,run"}
    inputs = {**example, "image-name": f"{auth_registry.address}/{IMAGE}",
              "registry": auth_registry.address, "enable-push-as-latest": "true"}
    docker_config, argv_log, shim = docker_recorder(root)
    env = {k: v for k, v in os.environ.items()
           if k not in ("TARGET", "COMMAND", "IMAGE") and not k.startswith(("GITHUB_", "CI_"))}
    env.update({"PATH": f"{shim}{os.pathsep}{env['PATH']}", "DOCKER_CONFIG": str(docker_config)})
    results = {}
    # The feature branch's job runs with the defaults: this runner's engine (Engine 20.10)
    # has the classic image store, so the job sets up an engine on the containerd store
    # (docker/setup-docker-action; here Engine 26, which has no outbound NAT: hence
    # build-network host). main keeps the runner's engine (containerd-image-store false), also
    # runs the tests (docker-ros's enable-industrial-ci), into the default folder, and adds
    # labels of its own (one a line, a value with a comma).
    for key, branch, extra in (("feature", FEATURE, {"enable-slim": "false",
                                                     "build-network": "host"}),
                               ("main", "main", {"enable-industrial-ci": "true",
                                                 "labels": LABELS,
                                                 "containerd-image-store": "false"})):
        forget_local(base)  # each run pulls it
        event = Event(origin=root / "origin.git", repository="Org/Example-Repo", ref_name=branch,
                      actor=auth_registry.user, token=auth_registry.password)
        results[key] = run_action(REPO, {**inputs, **extra}, event, root / key, env,
                                  containerd_engine=engine26)
    return {"registry": auth_registry, "root": root, "docker_config": docker_config,
            "argv_log": argv_log, **results}


def test_action_runs_every_step(runs: dict) -> None:
    for key in ("feature", "main"):
        run = runs[key]
        assert run.returncode == 0, run.log[-6000:]
        checkout = run.replaced[0]
        assert checkout == {"uses": "actions/checkout@v4",
                            "with": {"submodules": "recursive", "lfs": "true"}}
        branch = FEATURE if key == "feature" else "main"
        assert run.replaced[-1] == {"uses": "gacts/github-slug@v1", "with": {"to-slug": branch}}
        assert "docker-ros setup: docker-ros " in run.log
    # amd64 on an amd64 runner: no QEMU
    assert runs["feature"].skipped == ["Set up QEMU"]
    assert runs["main"].skipped == ["Set up Docker with the containerd image store",
                                    "Set up QEMU"]


def test_by_default_the_job_builds_on_an_engine_with_the_containerd_image_store(
    runs: dict, engine26: str
) -> None:
    """The runner's engine has the classic image store: with the defaults the job sets one up
    on the containerd store, and the build exports a registry cache of every stage (docker-ros's
    container builder gave that too); with containerd-image-store false it keeps the runner's
    engine and says why its cache is the inline one."""
    setup = {"uses": "docker/setup-docker-action@v4",
             "with": {"daemon-config": '{"features": {"containerd-snapshotter": true}}',
                      "set-host": "true"}}
    assert runs["feature"].replaced[1] == setup
    feature, main = runs["feature"].log, runs["main"].log
    assert f"(docker driver of the local engine at {engine26}, containerd image store)" in (
        feature)
    assert "CACHE_TO: registry cache of every stage (mode=max)" in feature
    assert "exporting cache to registry" in feature
    assert setup not in runs["main"].replaced
    assert ("CACHE_TO: inline cache only (the docker driver of an engine on the classic image "
            "store cannot export a registry cache") in main


def test_feature_branch_gets_the_ci_postfix_and_main_also_latest(runs: dict) -> None:
    """The branch slug as docker-ros's action makes it (gacts/github-slug: `--` collapses, ß
    becomes ss)."""
    auth = runs["registry"]
    assert registry_tags(auth.address, IMAGE, auth.auth) == [
        "latest", "latest-build-state-amd64", "latest-dev", f"latest-dev_{SLUG}_ci",
        "latest-slim", f"latest_{SLUG}_ci",
        f"latest_{SLUG}_ci-build-state-amd64",
        # the registry cache of every stage, beside the dev image the job pushes (the
        # feature job's engine has the containerd image store; main's keeps the inline cache)
        f"latest_{SLUG}_ci-cache-dev-amd64", f"latest_{SLUG}_ci-cache-run-amd64",
    ]


def test_outputs_name_the_pushed_images_and_their_digests(runs: dict) -> None:
    auth = runs["registry"]
    name = f"{auth.address}/{IMAGE}"
    outputs = runs["feature"].outputs["docker-ros"]
    digests = json.loads(outputs.pop("digests"))
    assert outputs == {
        "images": f"{name}:latest-dev_{SLUG}_ci,{name}:latest_{SLUG}_ci",
        "dev-image": f"{name}:latest-dev_{SLUG}_ci",
        "image": f"{name}:latest_{SLUG}_ci",
        "build-state-image": f"{name}:latest_{SLUG}_ci-build-state-amd64",
        "dev-digest": digests[f"{name}:latest-dev_{SLUG}_ci"],
        "digest": digests[f"{name}:latest_{SLUG}_ci"],
        "build-state-digest": registry_digest(auth.address, IMAGE,
                                              f"latest_{SLUG}_ci-build-state-amd64", auth.auth),
    }
    # IMAGE_TAG is latest already: ENABLE_PUSH_AS_LATEST adds no second push of it
    main = runs["main"].outputs["docker-ros"]
    assert main["images"] == f"{name}:latest-dev,{name}:latest,{name}:latest-slim"
    assert set(json.loads(main["digests"])) == set(main["images"].split(","))
    # each the digest the registry serves the name under (what signing by digest needs)
    for pushed, digest in [*digests.items(), *json.loads(main["digests"]).items()]:
        assert re.fullmatch(r"sha256:[0-9a-f]{64}", digest), (pushed, digest)
        assert registry_digest(auth.address, IMAGE, pushed.rpartition(":")[2],
                               auth.auth) == digest, pushed
    assert main["slim-digest"] == json.loads(main["digests"])[f"{name}:latest-slim"]
    # the build state's, an output of its own (not in `images`, `digests`)
    assert main["build-state-image"] == f"{name}:latest-build-state-amd64"
    assert re.fullmatch(r"sha256:[0-9a-f]{64}", main["build-state-digest"])
    assert main["build-state-digest"] == registry_digest(
        auth.address, IMAGE, "latest-build-state-amd64", auth.auth)


def test_images_carry_the_oci_labels_and_the_action_s_labels(runs: dict) -> None:
    """source and revision from the repository (GitHub's name of it, the checked-out commit),
    created the commit's time, version IMAGE_TAG, title, licenses of the example's package.xml,
    then the `labels` input's; the slim image keeps them under a title of its own."""
    name = f"{runs['registry'].address}/{IMAGE}"
    origin = runs["root"] / "origin.git"
    revision = git(origin, "rev-parse", "main").strip()
    committed = int(git(origin, "log", "-1", "--format=%ct", "main"))
    created = datetime.datetime.fromtimestamp(committed, tz=datetime.timezone.utc)
    expected = {
        "org.opencontainers.image.source": "https://github.com/Org/Example-Repo",
        "org.opencontainers.image.revision": revision,
        "org.opencontainers.image.created": created.strftime("%Y-%m-%dT%H:%M:%SZ"),
        "org.opencontainers.image.version": "latest",
        "org.opencontainers.image.licenses": "MIT",
        "com.example.team": "drives, navigation",
        "com.example.tier": "1",
    }
    titles = {"latest": "ci-github", "latest-dev": "ci-github (dev)",
              "latest-slim": "ci-github (slim)"}
    for tag, title in titles.items():
        labels = json.loads(subprocess.run(
            ["docker", "image", "inspect", "--format", "{{json .Config.Labels}}",
             f"{name}:{tag}"], capture_output=True, text=True, check=True).stdout)
        print(f"\nLABELS {name}:{tag} {json.dumps(labels, sort_keys=True)}")
        oci = {k: v for k, v in labels.items() if not k.startswith("org.docker-ros.")}
        assert oci == {**expected, "org.opencontainers.image.title": title}, tag
        assert all(not k.startswith(("io.", "docker-ros.")) for k in labels), labels


def test_the_job_summary_lists_the_images_and_the_digests(runs: dict) -> None:
    name = f"{runs['registry'].address}/{IMAGE}"
    summary = runs["main"].summary
    assert summary.startswith("### docker-ros\n"), summary
    assert "| image | platform | size | build time | cached steps | slim ratio |" in summary
    for tag in ("latest-dev", "latest"):
        assert re.search(rf"\| `{re.escape(name)}:{tag}` \| amd64 \| \d+ MB \| [\d.]+ s \| "
                         r"\d+/\d+ \|  \|", summary), summary
    assert re.search(rf"\| `{re.escape(name)}:latest-slim` \| amd64 \| \d+ MB \| [\d.]+ s "
                     r"\((traced, checked|up to date)\) \|  \| [\d.]+x \|", summary), summary
    for pushed, digest in json.loads(runs["main"].outputs["docker-ros"]["digests"]).items():
        assert f"| `{pushed}` | `{digest}` |" in summary
    assert runs["registry"].password not in summary + runs["feature"].summary
    assert "| pushed | digest |" in runs["feature"].summary


def test_test_results_are_in_the_folder_the_output_names(runs: dict) -> None:
    """With enable-industrial-ci the results go to `<runner.temp>/docker-ros-test-results`,
    which the output `test-results` names (for actions/upload-artifact)."""
    folder = runs["main"].outputs["setup"]["test-results"]
    assert folder == str(runs["root"] / "main" / "runner-temp" / "docker-ros-test-results")
    assert (Path(folder) / "outcome.json").is_file()
    assert "docker-ros test (amd64): " in runs["main"].log
    assert f"(JUnit XML and logs in {folder})" in runs["main"].log
    assert not Path(runs["feature"].outputs["setup"]["test-results"]).exists()  # no tests


def test_token_never_reaches_the_log(runs: dict) -> None:
    """github.token is the registry password and the git password by default: logged in with
    it on standard input, it is in no log, docker command line or image history, and no
    login is left in the runner's DOCKER_CONFIG or its temporary folder."""
    auth = runs["registry"]
    for key in ("feature", "main"):
        assert auth.password not in runs[key].log
        assert f"docker-ros ci: logged in to {auth.address} as {auth.user}" in runs[key].log
        assert list((runs["root"] / key / "runner-temp").glob("docker-ros-login-*")) == []
    argvs = runs["argv_log"].read_text()
    assert f"login --username {auth.user} --password-stdin {auth.address}" in argvs
    assert auth.password not in argvs
    config = runs["docker_config"] / "config.json"
    assert auth.address not in (config.read_text() if config.exists() else "")
    history = subprocess.run(["docker", "history", "--no-trunc",
                              f"{auth.address}/{IMAGE}:latest"],
                             capture_output=True, text=True, check=True).stdout
    assert auth.password not in history


def test_pushed_dev_image_holds_no_token(runs: dict) -> None:
    """actions/checkout keeps github.token in the checkout's .git/config (an authorization
    header): git's folder stays out of the dev image's sources."""
    auth = runs["registry"]
    token = base64.b64encode(f"x-access-token:{auth.password}".encode()).decode()
    assert_sources_hold_no_secret(f"{auth.address}/{IMAGE}:latest-dev", [auth.password, token],
                                  auth.auth)


def test_pushed_run_image_runs(runs: dict) -> None:
    ref = f"{runs['registry'].address}/{IMAGE}:latest_{SLUG}_ci"
    assert_pulled_image_runs(ref, runs["registry"].auth)
