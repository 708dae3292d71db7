"""Settings: declarations, precedence, strict parsing, derived defaults, the generated
configuration reference."""

import re
from pathlib import Path

import pytest
import yaml

from docker_ros.cli import reference
from docker_ros.core.display import (
    as_env,
    display_value,
    missing_required,
    require,
    required_for_build,
)
from docker_ros.core.loading import load_settings, parse_set
from docker_ros.core.settings import FIELDS, SettingsError

DOCS = Path(__file__).resolve().parents[2] / "docs"
ORIGINAL = Path(__file__).resolve().parent / "data" / "docker-ros-readme-defaults.yml"


def load(**layers):
    return load_settings(project_dir=Path("/tmp/my_Repo"), **layers)


@pytest.mark.parametrize(
    "layers, expected, source",
    [
        ({}, "latest", "default"),
        ({"invoke_config": {"image_tag": "yaml"}}, "yaml", "invoke.yaml"),
        ({"invoke_config": {"image_tag": "yaml"}, "dotenv": {"IMAGE_TAG": "dot"}}, "dot", ".env"),
        (
            {"dotenv": {"IMAGE_TAG": "dot"}, "environ": {"IMAGE_TAG": "env"}},
            "env",
            "environment",
        ),
        (
            {
                "invoke_config": {"image_tag": "yaml"},
                "dotenv": {"IMAGE_TAG": "dot"},
                "environ": {"IMAGE_TAG": "env"},
                "flags": {"image_tag": "flag"},
            },
            "flag",
            "flag",
        ),
        ({"environ": {"IMAGE_TAG": "env"}, "flags": {"image_tag": None}}, "env", "environment"),
    ],
)
def test_precedence(layers, expected, source):
    settings = load(**layers)
    assert settings.image_tag == expected
    assert settings.source_of("image_tag") == source


@pytest.mark.parametrize(
    "raw, value",
    [("false", False), ("FALSE", False), ("0", False), ("No", False),
     ("true", True), ("True", True), ("1", True), ("YES", True)],
)
def test_strict_booleans(raw, value):
    assert load(environ={"ENABLE_SLIM": raw}).enable_slim is value


@pytest.mark.parametrize("raw", ["maybe", "", "on", "off", "2"])
def test_bad_boolean_names_variable_and_accepted_values(raw):
    with pytest.raises(SettingsError) as err:
        load(flags={"enable_slim": raw})
    assert "ENABLE_SLIM" in str(err.value)
    assert "true, 1, yes, false, 0, no" in str(err.value)


def test_empty_environment_values_count_as_unset():
    settings = load(environ={"ENABLE_SLIM": "", "ROS_DISTRO": ""}, dotenv={"IMAGE_TAG": ""})
    assert settings.enable_slim is False and settings.ros_distro is None
    assert settings.source_of("enable_slim").startswith("derived: a local build")
    assert settings.image_tag == "latest"


def test_yaml_booleans_are_accepted_as_such():
    assert load(invoke_config={"enable_slim": False}).enable_slim is False


def test_comma_lists_are_checked():
    settings = load(environ={"TARGET": "dev, run", "PLATFORM": "amd64,arm64"})
    assert settings.target == ("dev", "run")
    assert settings.platform == ("amd64", "arm64")
    with pytest.raises(SettingsError, match=r"TARGET='foo'.*allowed values: dev, run"):
        load(environ={"TARGET": "foo"})
    with pytest.raises(SettingsError, match=r"PLATFORM.*s390x.*allowed values: amd64, arm64"):
        load(environ={"PLATFORM": "amd64,s390x"})


def test_all_errors_reported_together():
    with pytest.raises(SettingsError) as err:
        load(environ={"TARGET": "foo", "ENABLE_SLIM": "maybe"}, invoke_config={"imge_tag": "x"})
    text = str(err.value)
    assert "TARGET" in text and "ENABLE_SLIM" in text
    assert "did you mean image_tag?" in text  # as written in invoke.yaml: lower case
    with pytest.raises(SettingsError, match=r"docker_ros.IMGE_TAG \(did you mean IMAGE_TAG\?"):
        load(invoke_config={"IMGE_TAG": "x"})
    with pytest.raises(SettingsError, match=r"--set enable-slm: unknown setting \(did you mean "
                                            r"ENABLE_SLIM\?\)"):
        parse_set(["enable-slm=true"])


def test_a_local_build_slims_only_when_asked():
    """docker-ros's ENABLE_SLIM=true stays the default in CI and for push/ci/manifest; a local
    build slims when ENABLE_SLIM is given (any source), or with a `slim` target."""
    local = load(environ={"TARGET": "run"}, command="build")
    assert local.enable_slim is False
    assert "slims only when asked" in local.source_of("enable_slim")
    for command in ("push", "ci", "manifest"):
        pushed = load(command=command)
        assert pushed.enable_slim is True
        assert pushed.source_of("enable_slim") == (f"derived from the command: `{command}` "
                                                   "slims as CI does")
    github = load(environ={"GITHUB_ACTIONS": "true"}, command="build")
    assert github.enable_slim is True and "CI pipeline (github)" in github.source_of("enable_slim")
    assert load(environ={"GITLAB_CI": "true"}).enable_slim is True
    for given in ({"dotenv": {"ENABLE_SLIM": "true"}}, {"environ": {"ENABLE_SLIM": "yes"}},
                  {"invoke_config": {"enable_slim": True}}, {"flags": {"enable_slim": True}}):
        assert load(**given, command="build").enable_slim is True, given
    off = load(environ={"ENABLE_SLIM": "false"}, command="push")
    assert off.enable_slim is False and off.source_of("enable_slim") == "environment"


def test_a_slim_target_is_the_run_image_slimmed():
    only = load(flags={"target": "slim"}, command="build")
    assert only.target == ("run", "slim") and only.source_of("target") == "flag"
    assert only.enable_slim is True
    assert only.source_of("enable_slim") == "derived from TARGET (flag)"
    both = load(dotenv={"TARGET": "dev,run,slim"})
    assert both.target == ("dev", "run", "slim") and both.enable_slim is True
    with pytest.raises(SettingsError, match=r"TARGET \(flag\) names slim but ENABLE_SLIM=false "
                                            r"\(.env\): drop one of them"):
        load(dotenv={"ENABLE_SLIM": "false"}, flags={"target": "dev,slim"})


def test_missing_required_all_at_once():
    settings = load(environ={"TARGET": "dev,run"})
    with pytest.raises(SettingsError) as err:
        require(settings, required_for_build(settings))
    assert "BASE_IMAGE" in str(err.value) and "COMMAND" in str(err.value)
    dev_only = load(environ={"TARGET": "dev", "BASE_IMAGE": "b"})
    require(dev_only, required_for_build(dev_only))


def test_docker_ros_derived_names_and_tags():
    s = load(environ={"IMAGE": "Registry:5000/My/Img:v1"})
    assert (s.image_name, s.image_tag) == ("registry:5000/my/img", "v1")
    assert (s.dev_image_name, s.dev_image_tag) == ("registry:5000/my/img", "v1-dev")
    assert (s.slim_image_name, s.slim_image_tag) == ("registry:5000/my/img", "v1-slim")
    assert load().image_name == "my_repo"
    assert load(environ={"GITHUB_REPOSITORY": "Org/Repo"}).image_name == "ghcr.io/org/repo"
    assert load(environ={"CI_REGISTRY_IMAGE": "reg/x/y"}).image_name == "reg/x/y"
    assert load(environ={"IMAGE": "localhost:5000/img"}).image_tag == "latest"


@pytest.mark.parametrize(
    "layers, name, tag, tag_source",
    [
        ({"dotenv": {"IMAGE": "a/b:v1"}}, "a/b", "v1", "derived from IMAGE (.env)"),
        ({"dotenv": {"IMAGE": "a/b:v1"}, "flags": {"image_tag": "fromflag"}},
         "a/b", "fromflag", "flag"),
        ({"dotenv": {"IMAGE": "a/b:v1"}, "environ": {"IMAGE_TAG": "env"}},
         "a/b", "env", "environment"),
        ({"dotenv": {"IMAGE": "a/b:v1", "IMAGE_TAG": "own"}}, "a/b", "own", ".env"),
        ({"dotenv": {"IMAGE_TAG": "dot"}, "environ": {"IMAGE": "c/d:v2"}},
         "c/d", "v2", "derived from IMAGE (environment)"),
        ({"invoke_config": {"image_name": "y/z"}, "dotenv": {"IMAGE": "a/b"}},
         "a/b", "latest", "derived from IMAGE (.env)"),
    ],
)
def test_image_splits_at_its_own_precedence_with_provenance(layers, name, tag, tag_source):
    s = load(**layers)
    assert (s.image_name, s.image_tag) == (name, tag)
    assert s.source_of("image_tag") == tag_source
    assert s.dev_image_tag == f"{tag}-dev"
    assert s.source_of("dev_image_tag") == f"derived from IMAGE_TAG ({tag_source})"


def test_derived_names_say_where_they_come_from():
    s = load(dotenv={"IMAGE": "a/b:v1"})
    assert s.source_of("image_name") == "derived from IMAGE (.env)"
    assert s.source_of("slim_image_name") == "derived from IMAGE_NAME (derived from IMAGE (.env))"
    gh = load(environ={"GITHUB_REPOSITORY": "Org/Repo"})
    assert gh.source_of("image_name") == "derived from GITHUB_REPOSITORY (environment)"


def test_secrets_are_masked_and_not_exported_by_default():
    s = load(environ={"GIT_HTTPS_PASSWORD": "hunter2", "REGISTRY_PASSWORD": "pw"})
    assert display_value(s, "git_https_password") == "****"
    assert "GIT_HTTPS_PASSWORD" not in as_env(s)
    assert as_env(s, include_secrets=True)["GIT_HTTPS_PASSWORD"] == "hunter2"


def test_unset_values_stay_unset():
    env = as_env(load())
    assert "ROS_DISTRO" not in env and "BASE_IMAGE" not in env
    assert env["ENABLE_RECURSIVE_VCS_IMPORT"] == "true"


def reference_defaults():
    """Variable -> default text from the original docker-ros README (recorded in
    tests/unit/data)."""
    return yaml.safe_load(ORIGINAL.read_text())


def test_every_docker_ros_variable_is_declared_with_its_default():
    ref = reference_defaults()
    assert len(ref) > 40
    declared = {n.upper() for n in FIELDS}
    assert set(ref) - declared == set()
    plain = {  # defaults that are plain values in the original (not CI expressions)
        name: default.split("|")[-1].strip().strip("`\"")
        for name, default in ref.items()
        if default and "<" not in default and "$" not in default and "runner" not in default
    }
    # docker-ros's README documents an older SLIM_BUILD_ARGS than its action.yml and GitLab
    # template run (--continue-after=30, env, include, preserve, exclude): we take what its
    # pipelines run (tests/ci/test_ci_files.py compares those).
    assert plain.pop("SLIM_BUILD_ARGS").startswith("--sensor-ipc-mode proxy --continue-after=10")
    for name, default in plain.items():
        value = FIELDS[name.lower()].default
        shown = ",".join(value) if isinstance(value, tuple) else value
        if isinstance(value, bool):
            shown = "true" if value else "false"
        assert str(shown) == default, name


def test_the_reference_has_one_row_per_declared_setting():
    """The reference is generated from the declarations when the docs are built: every
    setting has its row, in declaration order, with its variable name first."""
    rows = reference.table().splitlines()[2:]
    names = [re.match(r"\| `([A-Z0-9_]+)` \|", row).group(1) for row in rows]
    assert names == [name.upper() for name in FIELDS]


def test_the_docs_render_the_generated_reference_and_link_to_it():
    """The configuration reference page renders the generated table (no table kept by hand),
    and the README, the docs' landing page and the configuration guide link to it."""
    page = (DOCS / "reference" / "configuration.md").read_text()
    assert "```{settings-reference}\n```" in page
    assert "| variable |" not in page, "a table kept by hand: the reference is generated"
    extension = (DOCS / "_ext" / "docker_ros_docs.py").read_text()
    assert "reference.table()" in extension
    links = {
        DOCS.parent / "README.md": "(docs/reference/configuration.md)",
        DOCS / "index.md": "(reference/configuration.md)",
        DOCS / "guide" / "configuration.md": "(../reference/configuration.md)",
    }
    for path, link in links.items():
        assert link in path.read_text(), f"{path.name} does not link to the reference"


def test_reference_table_rows_have_four_cells():
    """A `|` inside a cell is escaped: GitHub would cut the row at it."""
    for row in reference.table().splitlines():
        cells = re.split(r"(?<!\\)\|", row.strip())[1:-1]
        assert len(cells) == 4, row


def test_the_flag_column_names_the_tasks_in_the_fewest_words():
    every, steps = ["a", "b", "c", "d", "e", "s1", "s2", "s3"], ["s1", "s2", "s3"]
    assert reference.tasks_phrase(every, every, steps) == "every task"
    assert reference.tasks_phrase(["a", "b"], every, steps) == "a, b"
    assert reference.tasks_phrase(["a", "b", "c", "d", "e", "s1"], every, steps) == (
        "every task but s2, s3")
    assert reference.tasks_phrase(["a", "s1", "s2", "s3"], every, steps) == "the step tasks, a"
    assert reference.tasks_phrase(["a", "b", "c", "d"], every, steps) == "a, b, c, d"
    tie = ["a", "b", "c", "d", "e", "f", "s1"]  # 4 names, or "every task but" 3 names
    assert reference.tasks_phrase(["a", "b", "c", "d"], tie, ["s1"]) == "a, b, c, d"


def test_the_flag_column_s_tasks_are_those_whose_help_has_the_flag():
    """WORKSPACE's flag is every step task's, dev's, run's and test's, not build's (the
    column said only `--workspace` while 13 of the 23 tasks had it)."""
    row = next(r for r in reference.table().splitlines() if r.startswith("| `WORKSPACE` |"))
    assert "| `--workspace` (the step tasks, dev, run, test) |" in row
    assert "workspace" not in reference.task_flags("build")
    assert "workspace" in reference.task_flags("dev")


def test_a_later_source_s_valid_value_clears_an_earlier_invalid_one():
    settings = load(invoke_config={"target": "foo"}, dotenv={"TARGET": "dev"}, lenient=True)
    assert settings.target == ("dev",) and settings.source_of("target") == ".env"
    assert "target" not in settings.problems
    with pytest.raises(SettingsError, match="TARGET='bar'.*from .env"):
        load(invoke_config={"target": "dev"}, dotenv={"TARGET": "bar"})


def test_an_invoke_yaml_key_given_twice_is_refused():
    """image-tag and image_tag are one setting: the last one won without a word."""
    with pytest.raises(SettingsError, match=r"invoke.yaml: docker_ros.image_tag and "
                       r"docker_ros.image-tag are one setting: keep one"):
        load(invoke_config={"image-tag": "a", "image_tag": "b"})


def test_a_secret_in_invoke_yaml_is_refused_without_showing_it():
    """invoke.yaml is a committed file of the repository (and copied into the dev image)."""
    with pytest.raises(SettingsError) as err:
        load_settings(invoke_config={"git_https_password": "s3cr3t-yaml"}, environ={})
    assert ("invoke.yaml: docker_ros.git_https_password: a secret is never read from invoke's "
            "configuration (a committed or shared file); set it in the environment or .env"
            ) in str(err.value)
    assert "s3cr3t-yaml" not in str(err.value)
    shown = load_settings(invoke_config={"REGISTRY_PASSWORD": "s3cr3t-yaml"}, environ={},
                          lenient=True)
    assert shown.registry_password is None and "s3cr3t-yaml" not in repr(shown.problems)


def test_the_settings_repr_holds_no_secret():
    settings = load_settings(environ={"GIT_HTTPS_PASSWORD": "s3cr3t-a", "REGISTRY_PASSWORD":
                                      "s3cr3t-b", "GIT_SSH_PRIVATE_KEY": "s3cr3t-c"})
    assert settings.registry_password == "s3cr3t-b"
    assert "s3cr3t" not in repr(settings) and "git_https_server" in repr(settings)


def test_a_yaml_number_for_a_text_setting_and_a_list_item_twice_are_refused():
    # `image_tag: 1.10` in invoke.yaml is the float 1.1 to YAML: the images were tagged 1.1
    with pytest.raises(SettingsError, match=r"image_tag: YAML reads it as the number 1.1 .*quote"):
        load(invoke_config=yaml.safe_load("image_tag: 1.10\nbase_image: b:1"))
    assert load(invoke_config=yaml.safe_load("image_tag: '1.10'")).image_tag == "1.10"
    assert load(invoke_config={"image_tag": 2}).image_tag == "2"  # (no digit lost)
    # a list, a mapping or a YAML boolean (`yes`) became Python's text of it: '[-DA=1, ...]'
    refused = "cmake_args: [-DA=1, -DB=2]\nimage_tag: yes\nimage_name: {a: 1}\nbase_image: b:1"
    with pytest.raises(SettingsError) as raised:
        load(invoke_config=yaml.safe_load(refused))
    assert str(raised.value).splitlines()[1:] == [
        "  invoke.yaml: docker_ros.cmake_args: YAML reads it as a list, but CMAKE_ARGS is one "
        "text value: write it as text, quoted, e.g. cmake_args: '...'",
        "  invoke.yaml: docker_ros.image_tag: YAML reads it as the boolean true (yes/no/on/off "
        "are booleans to YAML), but IMAGE_TAG is one text value: write it as text, quoted, e.g. "
        "image_tag: '...'",
        "  invoke.yaml: docker_ros.image_name: YAML reads it as a mapping, but IMAGE_NAME is one "
        "text value: write it as text, quoted, e.g. image_name: '...'"]
    # (a YAML list for a list setting and a boolean for a boolean one are what they mean)
    assert load(invoke_config={"target": ["dev", "run"], "enable_slim": True}).target == (
        "dev", "run")
    # PLATFORM=amd64,amd64 built amd64 twice, tagged -amd64 as for two platforms
    with pytest.raises(SettingsError, match=r"PLATFORM='amd64,amd64': amd64 given twice"):
        load(environ={"PLATFORM": "amd64,amd64"})
    with pytest.raises(SettingsError, match=r"TARGET='dev,run,dev': dev given twice"):
        load(environ={"TARGET": "dev,run,dev"})
    # (a list without fixed values may name one image twice: CI's defaults on the default branch)
    assert load(environ={"CACHE_FROM": "r/i:1,r/i:1"}).cache_from == ("r/i:1", "r/i:1")


def test_a_required_value_emptied_by_a_higher_source_says_where_from():
    """`--base-image ""` over a .env that sets it: the message names the flag, not only the
    variable (the user sees BASE_IMAGE in .env)."""
    emptied = load_settings(dotenv={"BASE_IMAGE": "ros:noetic"}, flags={"base_image": ""},
                            project_dir=Path("/tmp/p"))
    with pytest.raises(SettingsError, match=r"BASE_IMAGE \(empty, from flag\)"):
        require(emptied, ["base_image"])
    with pytest.raises(SettingsError, match=r"configuration: BASE_IMAGE \(set it"):
        require(load_settings(project_dir=Path("/tmp/p")), ["base_image"])


def test_missing_required_names_every_missing_value_in_one_line():
    """Nothing missing is '' (no message); one value is "set it", two are "set them"."""
    settings = load_settings(dotenv={"BASE_IMAGE": "ros:noetic"}, project_dir=Path("/tmp/p"))
    assert missing_required(settings, ["base_image"]) == ""
    assert missing_required(settings, ["base_image", "command"]).startswith(
        "missing required configuration: COMMAND (set it in .env")
    none = load_settings(project_dir=Path("/tmp/p"))
    assert missing_required(none, ["base_image", "command"]).startswith(
        "missing required configuration: BASE_IMAGE, COMMAND (set them in .env")


def test_a_host_path_from_a_file_starting_with_a_tilde_is_in_the_home_folder(monkeypatch):
    """`BUILD_CONTEXT=~/repo` in .env (no shell expands it) was used as the folder `~`."""
    monkeypatch.setenv("HOME", "/home/robot")
    settings = load(dotenv={"BUILD_CONTEXT": "~/repo", "WORKSPACE": "~/ws",
                            "EXTRA_CA_CERTS": "~/ca.pem", "TEST_RESULTS_DIR": "~/results",
                            "ADDITIONAL_DEBS_FILE": "~/debs.txt"})
    assert (settings.build_context, settings.workspace, settings.extra_ca_certs,
            settings.test_results_dir) == ("/home/robot/repo", "/home/robot/ws",
                                           "/home/robot/ca.pem", "/home/robot/results")
    assert settings.additional_debs_file == "~/debs.txt"  # (in the repository: refused later)


def test_none_turns_the_ci_caches_and_the_build_state_off():
    """They are pushed next to the images, as public as they are, and hold sources: a public
    image of private sources needs a way out of the CI defaults."""
    ci = {"GITLAB_CI": "true", "CI_REGISTRY_IMAGE": "reg.example/g/p", "CI_COMMIT_BRANCH": "main",
          "CI_DEFAULT_BRANCH": "main", "TARGET": "dev,run"}
    default = load(environ=ci)
    assert default.cache_to and default.build_state_from and default.cache_from
    off = load(environ={**ci, "CACHE_TO": "none", "BUILD_STATE_FROM": "none",
                        "CACHE_FROM": "none"})
    assert (off.cache_to, off.build_state_from, off.cache_from) == (None, (), ())
    assert off.source_of("cache_to") == "environment: none, turned off"
    assert load(dotenv={"CACHE_TO": "none"}).cache_to is None  # (outside CI too)
