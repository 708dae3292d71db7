"""docker-ros's CI tag rules, from the variables GitHub Actions and GitLab CI set."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from docker_ros.cli.tasks import write_image_references
from docker_ros.core.ci import (
    REF_SLUG,
    Pipeline,
    build_state_references,
    detect_pipeline,
    digest_references,
    error_annotation,
    github_default_branch,
    github_slug,
    image_references,
    missing_tasks,
    plan_ci_job,
    slim_skipped,
    slugify,
    tag_postfix,
)
from docker_ros.core.display import made_images
from docker_ros.core.loading import load_settings
from docker_ros.host.config import read_settings
from docker_ros.host.push import plan_manifest, plan_outputs, plan_push, push_targets
from tests.rosfixtures import make_package

SRC = Path(__file__).resolve().parents[2] / "src"

GITHUB = {"GITHUB_ACTIONS": "true", "GITHUB_DEFAULT_BRANCH": "main"}
GITLAB = {"GITLAB_CI": "true", "CI_DEFAULT_BRANCH": "main"}
# What the CIs set for a push to the default branch, a feature branch, a tag, a MR/PR.
CASES = {
    "github-default": {**GITHUB, "GITHUB_REF_TYPE": "branch", "GITHUB_REF_NAME": "main"},
    "github-feature": {**GITHUB, "GITHUB_REF_TYPE": "branch",
                       "GITHUB_REF_NAME": "Feature/My_Thing"},
    "github-tag": {**GITHUB, "GITHUB_REF_TYPE": "tag", "GITHUB_REF_NAME": "v1.2.0"},
    "github-pr": {**GITHUB, "GITHUB_EVENT_NAME": "pull_request", "GITHUB_REF_TYPE": "branch",
                  "GITHUB_REF_NAME": "42/merge", "GITHUB_HEAD_REF": "Feature/My_Thing"},
    "gitlab-default": {**GITLAB, "CI_COMMIT_BRANCH": "main", "CI_COMMIT_REF_NAME": "main"},
    "gitlab-feature": {**GITLAB, "CI_COMMIT_BRANCH": "Feature/My_Thing",
                       "CI_COMMIT_REF_NAME": "Feature/My_Thing"},
    "gitlab-tag": {**GITLAB, "CI_COMMIT_TAG": "v1.2.0", "CI_COMMIT_REF_NAME": "v1.2.0"},
    "gitlab-mr": {**GITLAB, "CI_PIPELINE_SOURCE": "merge_request_event",
                  "CI_MERGE_REQUEST_SOURCE_BRANCH_NAME": "Feature/My_Thing",
                  "CI_COMMIT_REF_NAME": "Feature/My_Thing"},
}


def settings(case, **environ):
    return load_settings(environ={"BASE_IMAGE": "b:1", "COMMAND": "c", "IMAGE_NAME": "reg/img",
                                  "TARGET": "dev,run", "PLATFORM": "amd64",
                                  **CASES.get(case, {}), **environ},
                         project_dir=Path("/tmp/repo"))


def refs(s):
    return (s.image_tag, s.dev_image_tag, s.slim_image_tag)


@pytest.mark.parametrize("case", ["github-default", "gitlab-default", "none"])
def test_default_branch_and_outside_ci_get_no_postfix(case):
    s = settings(case)
    assert refs(s) == ("latest", "latest-dev", "latest-slim")
    assert s.image_postfix is None and s.push_also_as == ()


@pytest.mark.parametrize("case", ["github-feature", "gitlab-feature", "github-pr", "gitlab-mr"])
def test_feature_branches_and_merge_requests_get_the_slug_ci_postfix(case):
    s = settings(case)
    assert refs(s) == ("latest_feature-my-thing_ci", "latest-dev_feature-my-thing_ci",
                       "latest-slim_feature-my-thing_ci")


def test_slug_is_gitlabs_ci_commit_ref_slug():
    assert slugify("Feature/My_Thing") == "feature-my-thing"
    assert slugify("-fix--Ü-") == "fix"
    assert slugify("x" * 70 + "/y") == "x" * 63
    assert slugify("a" * 62 + "/b") == "a" * 62  # cut at 63, then no trailing -
    assert slugify("feat--x__y") == "feat--x--y"  # GitLab keeps runs of `-`


def test_github_slug_is_the_one_of_docker_ros_s_action():
    """gacts/github-slug@v1's own test cases, and branch names."""
    assert github_slug(" Foo_bar--_--baz V1.2.3 %_#$ \t\n\r ") == (
        "foo-bar-baz-v1-2-3-percent-dollar")
    assert github_slug("\n\r foo/bar_1.2.3(aaa_bbb)\t") == "foo-bar-1-2-3-aaa-bbb"
    assert github_slug("^*()_=+\\/?~`@;:'\"") == ""
    assert github_slug("Feature/GitHub--Test") == "feature-github-test"
    assert github_slug("fix/Ä@b&c") == "fix-abandc"  # accents lose their mark, @ is dropped


@pytest.mark.parametrize("case", ["github-feature", "github-pr"])
def test_the_actions_slug_step_names_the_github_ci_tags(case):
    """In the Action, the slug of its gacts/github-slug step (docker-ros's) is the one used:
    it transliterates what github_slug drops (ß, other scripts)."""
    environ = {**CASES[case], "GITHUB_REF_NAME": "Fix/Straße", "GITHUB_HEAD_REF": "Fix/Straße"}
    if case == "github-feature":
        del environ["GITHUB_HEAD_REF"]
    assert tag_postfix(detect_pipeline(environ)) == "_fix-strae_ci"
    assert tag_postfix(detect_pipeline({**environ, REF_SLUG: "fix-strasse"})) == (
        "_fix-strasse_ci")
    gitlab = {**CASES["gitlab-feature"], REF_SLUG: "other"}
    assert tag_postfix(detect_pipeline(gitlab)) == "_feature-my-thing_ci"  # GitHub's only


@pytest.mark.parametrize("ci,environ", [
    ("gitlab", {**GITLAB, "CI_COMMIT_BRANCH": "feat--x", "CI_COMMIT_REF_NAME": "feat--x"}),
    ("github", {**GITHUB, "GITHUB_REF_TYPE": "branch", "GITHUB_REF_NAME": "feat--x"}),
])
def test_each_ci_gets_its_own_docker_ros_slug(ci, environ):
    postfix = tag_postfix(detect_pipeline(environ))
    assert postfix == ("_feat--x_ci" if ci == "gitlab" else "_feat-x_ci")


@pytest.mark.parametrize("case", ["github-tag", "gitlab-tag"])
def test_tag_pipelines_push_target_tag_and_the_git_tag(case):
    """docker-ros's GitLab "Push target tag" (<tag>-<git tag>) and "Push tag" (<git tag>, as
    IMAGE_TAG is latest); no _ci postfix."""
    s = settings(case)
    assert refs(s) == ("latest-v1.2.0", "latest-dev-v1.2.0", "latest-slim-v1.2.0")
    assert plan_push(s, s.target) == [
        ["docker", "push", "reg/img:latest-dev-v1.2.0"],
        ["docker", "tag", "reg/img:latest-dev-v1.2.0", "reg/img:v1.2.0-dev"],
        ["docker", "push", "reg/img:v1.2.0-dev"],
        ["docker", "push", "reg/img:latest-v1.2.0"],
        ["docker", "tag", "reg/img:latest-v1.2.0", "reg/img:v1.2.0"],
        ["docker", "push", "reg/img:v1.2.0"],
    ]


def test_tag_pipeline_with_own_image_tag_pushes_the_git_tag_only_as_latest():
    assert settings("gitlab-tag", IMAGE_TAG="humble").push_also_as == ()
    assert settings("gitlab-tag", IMAGE_TAG="humble",
                    ENABLE_PUSH_AS_LATEST="true").push_also_as == ("v1.2.0",)


@pytest.mark.parametrize("case,expected", [
    ("none", ("latest",)), ("github-default", ("latest",)), ("gitlab-default", ("latest",)),
    ("gitlab-feature", ()), ("gitlab-mr", ()),
])
def test_push_as_latest_from_the_default_branch(case, expected):
    s = settings(case, IMAGE_TAG="v1", ENABLE_PUSH_AS_LATEST="true")
    assert s.push_also_as == expected
    pushed = [c[-1] for c in plan_push(s, s.target) if c[1] == "push"]
    assert ("reg/img:latest" in pushed) == bool(expected)


@pytest.mark.parametrize("case", ["github-feature", "github-pr"])
def test_github_pushes_as_latest_off_the_default_branch_with_the_postfix(case):
    """docker-ros's action: its "Push images (as latest)" step runs on every branch, with the
    branch's `_<slug>_ci` (its GitLab template's "Push latest" only on the default branch)."""
    s = settings(case, IMAGE_TAG="v1", ENABLE_PUSH_AS_LATEST="true", ENABLE_SLIM="true")
    assert s.push_also_as == ("latest_feature-my-thing_ci",)
    pushed = [c[-1] for c in plan_push(s, ["dev", "run", "slim"]) if c[1] == "push"]
    assert pushed == ["reg/img:v1-dev_feature-my-thing_ci",
                      "reg/img:latest-dev_feature-my-thing_ci",
                      "reg/img:v1_feature-my-thing_ci", "reg/img:latest_feature-my-thing_ci",
                      "reg/img:v1-slim_feature-my-thing_ci",
                      "reg/img:latest-slim_feature-my-thing_ci"]
    # IMAGE_POSTFIX=none: no `latest` from another branch (it is the default branch's)
    assert settings(case, IMAGE_TAG="v1", ENABLE_PUSH_AS_LATEST="true",
                    IMAGE_POSTFIX="none").push_also_as == ()
    # IMAGE_TAG latest: those are the configured names, pushed once
    s = settings(case, ENABLE_PUSH_AS_LATEST="true")
    assert [c[-1] for c in plan_push(s, s.target) if c[1] == "push"] == [
        "reg/img:latest-dev_feature-my-thing_ci", "reg/img:latest_feature-my-thing_ci"]


def test_singlearch_push_on_a_feature_branch_pushes_postfix_then_arch():
    s = settings("gitlab-feature", ENABLE_SINGLEARCH_PUSH="true", PLATFORM="arm64")
    pushed = [c[-1] for c in plan_push(s, s.target) if c[1] == "push"]
    assert pushed == ["reg/img:latest-dev_feature-my-thing_ci-arm64",
                      "reg/img:latest_feature-my-thing_ci-arm64"]


def test_image_postfix_overrides_the_rules():
    assert settings("gitlab-feature", IMAGE_POSTFIX="none").image_tag == "latest"
    assert settings("none", IMAGE_POSTFIX="_nightly").dev_image_tag == "latest-dev_nightly"
    assert settings("gitlab-default", IMAGE_TAG="v2", DEV_IMAGE_TAG="d",
                    IMAGE_POSTFIX="-x").dev_image_tag == "d-x"


def test_unknown_default_branch_counts_as_another_branch():
    p = detect_pipeline({"GITHUB_ACTIONS": "true", "GITHUB_REF_NAME": "main"})
    assert p == Pipeline("github", "branch", "main", "")
    assert settings("none", GITHUB_ACTIONS="true", GITHUB_REF_NAME="main").image_tag == (
        "latest_main_ci")


def test_github_default_branch_comes_from_the_event_payload(tmp_path):
    event = tmp_path / "event.json"
    event.write_text(json.dumps({"repository": {"default_branch": "develop"}}))
    environ = {"GITHUB_ACTIONS": "true", "GITHUB_EVENT_PATH": str(event),
               "GITHUB_REF_TYPE": "branch", "GITHUB_REF_NAME": "develop", "BASE_IMAGE": "b:1"}
    assert github_default_branch(environ) == "develop"
    assert read_settings({}, {}, project_dir=tmp_path, environ=environ).image_tag == "latest"
    assert github_default_branch({**environ, "GITHUB_EVENT_PATH": str(tmp_path / "no")}) == ""


def test_ci_job_plan_tests_before_pushing_and_names_missing_tasks():
    plan = plan_ci_job(target=("dev", "run"), enable_industrial_ci=True, enable_slim=True)
    assert [argv[0] for argv in plan] == ["build", "test", "slim", "push"]
    assert [argv[0] for argv in plan_ci_job(target=("dev",), enable_industrial_ci=False,
                                             enable_slim=True)] == ["build", "push"]
    assert missing_tasks(plan, {"build", "push", "slim"}) == [
        "ENABLE_INDUSTRIAL_CI=true needs the `test` task, which this docker-ros does not have "
        "yet: set ENABLE_INDUSTRIAL_CI=false"
    ]
    # a slim target is the slim task's; the build before it makes the images without it
    slim = plan_ci_job(target=("run", "slim"), enable_industrial_ci=False, enable_slim=True)
    assert slim[0][-2:] == ["--target", "run"] and [a[0] for a in slim] == ["build", "slim", "push"]


def test_a_ci_job_on_a_runner_of_another_architecture_slims_nothing_and_says_why():
    """docker-ros slims a foreign architecture in a job of its own, on a runner of it; here
    the job's push then leaves the slim image out (and the manifest job its slim list entry)."""
    plan = plan_ci_job(target=("dev", "run"), enable_industrial_ci=False, enable_slim=True,
                       slims_here=False)
    assert plan[1:] == [["push", "--set", "ENABLE_INDUSTRIAL_CI=false",
                         "--set", "ENABLE_SLIM=false"]]
    # a slim target asks for it: slim runs, and fails saying why
    asked = plan_ci_job(target=("run", "slim"), enable_industrial_ci=False, enable_slim=True,
                        slims_here=False)
    assert [a[0] for a in asked] == ["build", "slim", "push"]
    assert "ENABLE_SLIM=false" not in asked[-1]
    assert slim_skipped(("arm64",), "amd64").startswith(
        "slim: arm64 not slimmed on this amd64 runner (slimming runs the image): a slim arm64 "
        "image needs a job on a runner of that architecture")


def test_ci_jobs_reuse_the_pushed_dev_and_run_images_as_cache_by_default() -> None:
    env = {**CASES["gitlab-feature"], "CI_REGISTRY_IMAGE": "reg/g/p", "PLATFORM": "amd64"}
    feature = load_settings(environ=env, project_dir=Path("/tmp/p"))
    assert feature.cache_from[:2] == ("reg/g/p:latest-dev_feature-my-thing_ci",
                                      "reg/g/p:latest-dev_feature-my-thing_ci-amd64")
    # a feature branch also reuses the default branch's images
    assert {"reg/g/p:latest-dev", "reg/g/p:latest"} <= set(feature.cache_from)
    assert feature.source_of("cache_from").startswith("derived from the CI pipeline")
    given = load_settings(environ={**env, "CACHE_FROM": "x/y:z"}, project_dir=Path("/tmp/p"))
    assert given.cache_from == ("x/y:z",)
    assert load_settings(environ={}, project_dir=Path("/tmp/p")).cache_from == ()


def test_ci_jobs_start_from_the_pushed_build_state_then_the_default_branchs() -> None:
    env = {**CASES["gitlab-feature"], "CI_REGISTRY_IMAGE": "reg/g/p", "PLATFORM": "amd64,arm64",
           "TARGET": "dev,run"}
    feature = load_settings(environ=env, project_dir=Path("/tmp/p"))
    assert feature.build_state_from == ("reg/g/p:latest_feature-my-thing_ci-build-state",
                                        "reg/g/p:latest-build-state")
    # pushed once per architecture, under the names the next job pulls
    pushed = [c[-1] for c in plan_push(feature, push_targets(feature)) if "build-state" in c[-1]]
    assert pushed == ["reg/g/p:latest_feature-my-thing_ci-build-state-amd64",
                      "reg/g/p:latest_feature-my-thing_ci-build-state-arm64"]
    outputs = plan_outputs(feature, push_targets(feature), dict.fromkeys(pushed, ""))
    assert outputs["images"] == "" and outputs["build-state-image"] == pushed[0]
    assert load_settings(environ={}, project_dir=Path("/tmp/p")).build_state_from == ()


def test_a_run_only_pipeline_pushes_its_build_state_and_cache_only_where_named() -> None:
    """The build state (the colcon build folder) and a registry cache of every stage hold the
    sources: docker-ros's run-only pipeline pushed neither. By default they go only next to a
    dev image the pipeline pushes; BUILD_STATE_REPOSITORY names a repository for both."""
    env = {**CASES["gitlab-feature"], "CI_REGISTRY_IMAGE": "reg/g/p", "TARGET": "run"}
    run_only = load_settings(environ=env, project_dir=Path("/tmp/p"))
    assert (run_only.build_state_from, run_only.cache_to) == ((), None)
    assert "build-state" not in push_targets(run_only)
    named = load_settings(environ={**env, "BUILD_STATE_REPOSITORY": "reg/private/p"},
                          project_dir=Path("/tmp/p"))
    assert named.build_state_from == ("reg/private/p:latest_feature-my-thing_ci-build-state",
                                      "reg/private/p:latest-build-state")
    assert named.cache_to == "reg/private/p:latest_feature-my-thing_ci-cache"
    assert named.source_of("cache_to") == (
        "derived from the CI pipeline (to BUILD_STATE_REPOSITORY)")
    pushed = [c[-1] for c in plan_push(named, push_targets(named)) if "build-state" in c[-1]]
    assert pushed == ["reg/private/p:latest_feature-my-thing_ci-build-state-amd64"]


def test_a_failed_task_is_a_github_error_annotation(tmp_path) -> None:
    """On GitHub a failed task's message is also an error annotation, which the run's summary
    page shows (otherwise it shows `Process completed with exit code 1` only); escaped as the
    runner reads workflow commands. Elsewhere nothing."""
    assert error_annotation({"GITHUB_ACTIONS": "true"}, "docker-ros build",
                            "failed: 100% of it\n  a: b") == (
        "::error title=docker-ros build::failed: 100%25 of it%0A  a: b")
    assert error_annotation({"GITHUB_ACTIONS": "true"}, "a:b,c", "x") == (
        "::error title=a%3Ab%2Cc::x")
    assert error_annotation({"GITLAB_CI": "true"}, "docker-ros build", "failed") == ""
    env = {**os.environ, "GITHUB_ACTIONS": "true", "PYTHONPATH": str(SRC)}
    env.pop("TARGET", None)
    env.pop("COMMAND", None)
    task = subprocess.run([sys.executable, "-m", "docker_ros", "build", "--set", "TARGET="],
                          cwd=tmp_path, env=env, capture_output=True, text=True)
    assert task.returncode == 1
    assert task.stdout.startswith("::error title=docker-ros build::invalid configuration:%0A  "
                                  "TARGET='' is empty"), task.stdout
    # `docker-ros ci`: one annotation, its failed task's (not also `build failed` from ci)
    make_package(tmp_path / "pkg", "pkg")  # (COMMAND is all that is missing)
    job = subprocess.run([sys.executable, "-m", "docker_ros", "ci", "--set", "BASE_IMAGE=b:1",
                          "--set", "IMAGE=docker-ros-test/none:1"],
                         cwd=tmp_path, env=env, capture_output=True, text=True)
    assert job.returncode == 1
    assert [line for line in job.stdout.splitlines() if line.startswith("::error")] == [
        "::error title=docker-ros build::missing required configuration: COMMAND (set it in "
        ".env, the environment, invoke.yaml under docker_ros: or as flags)"], job.stdout


def test_docker_ros_image_variables_name_this_pipelines_images() -> None:
    """docker-ros's 21 `_IMAGE_*` variables (its template's global variables, used by jobs of a
    .gitlab-ci.yml) for the images our pipeline pushes: a feature branch's, a tag pipeline's."""
    feature = dict(image_references(
        {"RUN": ("reg/g/p", "latest_feat_ci"), "DEV": ("reg/g/p", "latest-dev_feat_ci"),
         "SLIM": ("reg/g/p", "latest-slim_feat_ci")}, "_feat_ci", ""))
    assert len(feature) == 21
    assert feature["_RUN_IMAGE"] == "reg/g/p:latest"
    assert feature["_DEV_IMAGE"] == "reg/g/p:latest-dev"
    assert feature["_IMAGE_RUN_CI"] == "reg/g/p:latest_feat_ci"
    assert feature["_IMAGE_DEV_CI_ARM64"] == "reg/g/p:latest-dev_feat_ci-arm64"
    assert feature["_IMAGE_SLIM_LATEST"] == "reg/g/p:latest-slim"
    assert feature["_IMAGE_RUN_TAG"] == feature["_IMAGE_RUN_TARGET_TAG"] == ""
    tag = dict(image_references(
        {"RUN": ("reg/g/p", "1.0-v2"), "DEV": ("reg/g/p", "1.0-dev-v2"),
         "SLIM": ("reg/g/p", "1.0-slim-v2")}, "-v2", "v2"))
    assert tag["_IMAGE_RUN_TARGET_TAG"] == tag["_IMAGE_RUN_CI"] == "reg/g/p:1.0-v2"
    assert tag["_IMAGE_DEV_TARGET_TAG"] == "reg/g/p:1.0-dev-v2"
    assert (tag["_IMAGE_RUN_TAG"], tag["_IMAGE_DEV_TAG"]) == ("reg/g/p:v2", "reg/g/p:v2-dev")


def test_ci_dry_run_writes_the_image_variables_as_a_dotenv_file(tmp_path) -> None:
    """`docker-ros manifest --dotenv FILE` (the template's Push jobs; `ci` alike) writes them as
    GitLab's dotenv report reads them, also with --dry-run."""
    env = {**os.environ, **CASES["gitlab-feature"], "PYTHONPATH": str(SRC),
           "IMAGE_NAME": "reg.example/g/p", "TARGET": "dev,run", "PLATFORM": "amd64"}
    dotenv = tmp_path / "images.env"
    task = subprocess.run([sys.executable, "-m", "docker_ros", "manifest", "--dry-run",
                           "--dotenv", str(dotenv)], cwd=tmp_path, env=env,
                          capture_output=True, text=True)
    assert task.returncode == 0, task.stdout + task.stderr
    lines = dotenv.read_text().splitlines()
    assert len(lines) == 21
    assert "_IMAGE_RUN_CI=reg.example/g/p:latest_feature-my-thing_ci" in lines
    assert "_IMAGE_RUN_CI_AMD64=reg.example/g/p:latest_feature-my-thing_ci-amd64" in lines


def test_pushed_names_get_a_digest_variable_of_their_own() -> None:
    """`<variable>_DIGEST` for each reference the job pushed, also two variables of one name
    (`_RUN_IMAGE` and `_IMAGE_RUN_CI` on the default branch); none for a name not pushed or of
    unknown digest (an empty one would blank another job's in a job that needs both)."""
    references = [("_RUN_IMAGE", "r/p:latest"), ("_IMAGE_RUN_CI", "r/p:latest"),
                  ("_IMAGE_RUN_CI_AMD64", "r/p:latest-amd64"), ("_IMAGE_DEV_CI", "r/p:latest-dev"),
                  ("_IMAGE_RUN_TAG", "")]
    pushed = {"r/p:latest": "sha256:1", "r/p:latest-dev": "", "r/p:other": "sha256:2"}
    assert digest_references(references, pushed) == [
        ("_RUN_IMAGE_DIGEST", "sha256:1"), ("_IMAGE_RUN_CI_DIGEST", "sha256:1")]
    assert digest_references(references, {}) == []
    states = {"amd64": "r/p:latest-build-state-amd64", "arm64": "r/p:latest-build-state-arm64"}
    assert build_state_references(states, ["r/p:latest-build-state-arm64"]) == [
        ("_IMAGE_BUILD_STATE_CI_ARM64", "r/p:latest-build-state-arm64")]
    assert build_state_references(states, []) == []


def main_pipeline_job(monkeypatch: pytest.MonkeyPatch, **environ: str):
    env = {**CASES["gitlab-default"], "IMAGE_NAME": "reg.example/g/p", "TARGET": "dev,run",
           "PLATFORM": "amd64", "BASE_IMAGE": "b:1", "COMMAND": "c", **environ}
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    return load_settings(environ=env, project_dir=Path("/tmp/p"))


def test_the_dotenv_report_gives_the_digests_of_what_the_job_pushed(tmp_path,
                                                                     monkeypatch) -> None:
    """A single-arch pipeline on the default branch: build-amd64 (`docker-ros ci`, as the
    template runs it) pushes the `-amd64` images and the build state, Push (`docker-ros
    manifest`) the lists; each report gives the digests of its own job's pushes."""
    build = main_pipeline_job(monkeypatch, ENABLE_SINGLEARCH_PUSH="true")
    names = [argv[-1] for argv in plan_push(build, push_targets(build)) if argv[1] == "push"]
    assert names == ["reg.example/g/p:latest-dev-amd64", "reg.example/g/p:latest-amd64",
                     "reg.example/g/p:latest-build-state-amd64",
                     "reg.example/g/p:latest-slim-amd64"]
    digests = {name: f"sha256:{n}" for n, name in enumerate(names)}
    write_image_references(build, str(tmp_path / "build.env"), digests)
    lines = (tmp_path / "build.env").read_text().splitlines()
    assert lines[:21] == [f"{k}={v}" for k, v in image_references(
        {"RUN": ("reg.example/g/p", "latest"), "DEV": ("reg.example/g/p", "latest-dev"),
         "SLIM": ("reg.example/g/p", "latest-slim")}, "", "")]
    assert lines[21:] == [
        "_IMAGE_BUILD_STATE_CI_AMD64=reg.example/g/p:latest-build-state-amd64",
        "_IMAGE_RUN_CI_AMD64_DIGEST=sha256:1",
        "_IMAGE_DEV_CI_AMD64_DIGEST=sha256:0",
        "_IMAGE_SLIM_CI_AMD64_DIGEST=sha256:3",
        "_IMAGE_BUILD_STATE_CI_AMD64_DIGEST=sha256:2",
    ]
    push = main_pipeline_job(monkeypatch)
    lists = {argv[argv.index("--tag") + 1]: "sha256:" + argv[argv.index("--tag") + 1][-6:]
             for argv in plan_manifest(push, made_images(push))}
    assert list(lists) == ["reg.example/g/p:latest-dev", "reg.example/g/p:latest",
                           "reg.example/g/p:latest-slim"]
    write_image_references(push, str(tmp_path / "push.env"), lists)
    assert (tmp_path / "push.env").read_text().splitlines()[21:] == [
        "_RUN_IMAGE_DIGEST=sha256:latest", "_DEV_IMAGE_DIGEST=sha256:st-dev",
        "_SLIM_IMAGE_DIGEST=sha256:t-slim",
        "_IMAGE_RUN_CI_DIGEST=sha256:latest", "_IMAGE_RUN_LATEST_DIGEST=sha256:latest",
        "_IMAGE_DEV_CI_DIGEST=sha256:st-dev", "_IMAGE_DEV_LATEST_DIGEST=sha256:st-dev",
        "_IMAGE_SLIM_CI_DIGEST=sha256:t-slim", "_IMAGE_SLIM_LATEST_DIGEST=sha256:t-slim",
    ]


def test_the_manifest_task_reads_its_pushes_digests_back_into_the_report(
        tmp_path, monkeypatch) -> None:
    """`docker-ros manifest --dotenv` (the Push jobs): the names push_and_report pushed, with
    their digests, go through the job's record into the report (`ci` reads it the same way
    after its tasks' processes)."""
    from docker_ros.cli.program import main
    from docker_ros.host import push

    def manifest(settings, targets, *, dry_run):
        return {push.image_ref(settings, t): f"sha256:{t}" for t in targets}

    monkeypatch.setattr(push, "manifest", manifest)
    for key in ("REGISTRY_USER", "REGISTRY_PASSWORD", "GITHUB_OUTPUT", "GITHUB_STEP_SUMMARY",
                "DOCKER_ROS_JOB_RECORD"):
        monkeypatch.delenv(key, raising=False)
    main_pipeline_job(monkeypatch, ENABLE_SLIM="false")
    monkeypatch.chdir(tmp_path)
    main(["manifest", "--dotenv", str(tmp_path / "images.env")])
    lines = (tmp_path / "images.env").read_text().splitlines()
    assert lines[21:] == [
        "_RUN_IMAGE_DIGEST=sha256:run", "_DEV_IMAGE_DIGEST=sha256:dev",
        "_IMAGE_RUN_CI_DIGEST=sha256:run", "_IMAGE_RUN_LATEST_DIGEST=sha256:run",
        "_IMAGE_DEV_CI_DIGEST=sha256:dev", "_IMAGE_DEV_LATEST_DIGEST=sha256:dev",
    ]
