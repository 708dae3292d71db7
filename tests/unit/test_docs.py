"""The README and the docs: every command they show works as written (task and flags as the
command line parses them), the README's two commands are what CI runs, the settings and CI
examples they show are the declared ones, and the generated parts cover what they generate
from. `nox -s docs` builds the site strictly (broken links and references fail)."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
from pathlib import Path
from typing import Iterator, List, Tuple

import pytest
from invoke import Program
from invoke.parser import ParseError, Parser, ParserContext

from docker_ros.cli import reference
from docker_ros.cli.settingstask import setting_help
from docker_ros.cli.tasks import COMPOSITE_HELP, ns
from docker_ros.core.display import default_doc
from docker_ros.core.settings import FIELDS, env_name, is_secret
from docker_ros.in_image.steps import STEPS

REPO = Path(__file__).resolve().parents[2]
README = REPO / "README.md"
DOCS = REPO / "docs"
PAGES = [README, REPO / "CONTRIBUTING.md", *sorted(DOCS.rglob("*.md"))]
ENV = re.compile(r"^(?:[A-Z_][A-Z0-9_]*=\S*\s+)+")


def code_blocks(path: Path, languages: Tuple[str, ...] = ("bash",)) -> Iterator[str]:
    for match in re.finditer(r"^```(\w+)\n(.*?)^```", path.read_text(), re.S | re.M):
        if match.group(1) in languages:
            yield match.group(2)


def shown_commands(program: str) -> Iterator[Tuple[str, List[str]]]:
    """(page, argv after the program) of each `inv ...`/`docker-ros ...` line of a bash block
    and each such inline code span, without a leading `NAME=value` environment or a trailing
    comment. Spans with a placeholder (`inv <step> --in-container`) and quoted output
    (`docker-ros test (amd64): 41 passed...`) are no commands."""
    for path in PAGES:
        lines = [line for block in code_blocks(path) for line in block.splitlines()]
        prose = re.sub(r"^```.*?^```", "", path.read_text(), flags=re.S | re.M)
        spans = re.findall(r"`([^`\n]+)`", prose)
        for line in [*lines, *spans]:
            line = ENV.sub("", line.strip())
            if not line.startswith(program + " "):
                continue
            words = shlex.split(line, comments=True)
            if any("<" in word or "..." in word for word in words):
                continue
            if len(words) > 1 and (words[1].endswith(":") or words[1].startswith("(")):
                continue
            yield path.relative_to(REPO).as_posix(), words[1:]


def parse(argv: List[str]) -> None:
    core = ParserContext(args=Program().core_args())
    Parser(initial=core, contexts=ns.to_contexts()).parse_argv(argv)


COMMANDS = list(shown_commands("inv")) + list(shown_commands("docker-ros"))


def test_the_docs_show_commands() -> None:
    pages = {page for page, _ in COMMANDS}
    assert {"README.md", "docs/guide/steps.md", "docs/guide/lock.md",
            "docs/guide/daily-work.md"} <= pages
    assert len(COMMANDS) > 100


@pytest.mark.parametrize("page,argv", COMMANDS, ids=[f"{p}: {' '.join(a)}" for p, a in COMMANDS])
def test_every_shown_command_parses(page: str, argv: List[str]) -> None:
    """Each task exists and takes each flag shown (invoke's own parser, as `inv` runs it)."""
    try:
        parse(argv)
    except ParseError as exc:
        pytest.fail(f"{page}: `inv {' '.join(argv)}` does not parse: {exc}")


def test_an_unknown_flag_does_not_parse() -> None:
    with pytest.raises(ParseError):
        parse(["build", "--no-such-flag"])
    with pytest.raises(ParseError):
        parse(["no-such-task"])


def test_readme_shows_the_example_and_the_test_command_ci_runs(tmp_path: Path) -> None:
    """The README's two commands on the example: the main job, and the test suite, which is
    what `.ci/run` runs after setup.sh (run here with both stubbed: nox gets no argument)."""
    blocks = [block.strip() for block in code_blocks(README)]
    assert "bash scripts/setup.sh && inv example" in blocks
    assert "nox" in blocks
    assert "example" in ns.task_names
    (tmp_path / ".ci").mkdir()
    (tmp_path / "scripts").mkdir()
    (tmp_path / "bin").mkdir()
    run = tmp_path / ".ci" / "run"
    run.write_text((REPO / ".ci" / "run").read_text())
    (tmp_path / "scripts" / "setup.sh").write_text("echo setup >> \"$CALLS\"\n")
    fake_nox = tmp_path / "bin" / "nox"
    fake_nox.write_text('#!/bin/sh\necho "nox $*" >> "$CALLS"\n')
    fake_nox.chmod(0o755)
    calls = tmp_path / "calls"
    env = {**os.environ, "CALLS": str(calls), "PATH": f"{tmp_path / 'bin'}:{os.environ['PATH']}"}
    result = subprocess.run(["bash", str(run)], env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert calls.read_text().split("\n") == ["setup", "nox ", ""]


def test_readme_is_short() -> None:
    lines = README.read_text().splitlines()
    assert len(lines) <= 300, f"README.md has {len(lines)} lines: move the details to docs/"


def test_readme_settings_are_declared_with_their_defaults() -> None:
    text = README.read_text()
    begin, end = "<!-- readme-settings:begin -->", "<!-- readme-settings:end -->"
    table = text.split(begin, 1)[1].split(end, 1)[0]
    rows = [row for row in table.strip().splitlines()[2:]]
    assert len(rows) >= 8
    for row in rows:
        name, default = [cell.strip() for cell in row.strip("|").split("|")][:2]
        name = name.strip("`")
        assert name.lower() in FIELDS, f"README names {name}, which is not a setting"
        assert default == default_doc(name.lower()), f"README's default of {name}"


def test_relative_links_lead_to_files() -> None:
    """GitHub renders the README and CONTRIBUTING links; Sphinx checks the docs' own."""
    for path in (README, REPO / "CONTRIBUTING.md"):
        for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", path.read_text()):
            if "://" not in target:
                assert (path.parent / target).exists(), f"{path.name} links to {target}"


def test_every_page_is_in_a_toctree() -> None:
    """(Sphinx warns about a page in no toctree too; this says which.)"""
    listed = set()
    for page in DOCS.rglob("*.md"):
        for block in re.findall(r"```\{toctree\}\n(.*?)```", page.read_text(), re.S):
            for entry in block.splitlines():
                if entry and not entry.startswith(":"):
                    listed.add((page.parent / entry.strip()).relative_to(DOCS).as_posix())
    pages = {p.relative_to(DOCS).with_suffix("").as_posix() for p in DOCS.rglob("*.md")}
    assert pages - listed == {"index"}


def test_the_steps_table_lists_every_setting_flag_of_each_step_task() -> None:
    """The steps page renders the generated table: each step with every setting its task
    takes beyond those all step tasks share (the hand-kept table lacked the recursive flags
    and --ros-distro)."""
    assert "```{steps-table}\n```" in (DOCS / "guide" / "steps.md").read_text()
    table = reference.steps_table()
    common = reference.common_step_flags()
    for step in STEPS:
        row = next(r for r in table.splitlines() if f"| {step} | `inv {step}` |" in r)
        for flag in reference.task_flags(step):
            own = "--" + flag.replace("_", "-") not in common
            if flag in FIELDS and own and not is_secret(flag):
                assert f"`{env_name(flag)}`" in row, (step, flag)
    assert "`--ros-distro`" in table
    assert "`--enable-recursive-blacklisted-packages`" in table
    assert "--dry-run" in common and "--in-container" in common


def test_the_stage_graph_names_every_stage() -> None:
    dockerfile = (REPO / "docker" / "Dockerfile").read_text()
    stages = re.findall(r"^FROM\s+\S+\s+AS\s+(\S+)", dockerfile, re.M | re.I)
    graph = reference.stage_graph(dockerfile)
    shown = {re.sub(r"^[│├└─\s]+", "", line).split()[0] for line in graph.splitlines()}
    assert set(stages) <= shown
    assert "```{stage-graph}\n```" in (DOCS / "architecture.md").read_text()


def test_the_stage_graph_hangs_stages_under_their_parents() -> None:
    dockerfile = "ARG A\nARG PICK=one\nFROM ${A} AS one\nFROM ${PICK} AS two\n" \
                 "FROM scratch AS three\nCOPY --from=two /x /x\n"
    assert reference.stage_graph(dockerfile) == "\n".join([
        "${A} (build argument)",
        "└── one",
        "    └── two   [FROM ${PICK}, by default]",
        "scratch (empty)",
        "└── three   [uses two]",
    ])


def test_help_says_required_not_default_required() -> None:
    assert setting_help("base_image") == "Base image `name:tag` (required)"
    assert "(default: required" not in setting_help("command")
    assert setting_help("image_tag").endswith("(default: latest)")


def test_run_help_counts_command_among_the_ten_steps() -> None:
    """COMMAND is run by the tenth step, not after the ten."""
    assert "ten steps and COMMAND" not in COMPOSITE_HELP["run"]
    assert "the tenth, command, runs COMMAND" in " ".join(COMPOSITE_HELP["run"].split())


def test_secrets_are_never_flags_in_the_docs() -> None:
    """The docs say secrets are never flags and that one given as a flag is refused (which
    tests/unit/test_bad_input.py and the host tests check)."""
    pages = [README, DOCS / "guide" / "configuration.md", DOCS / "reference" / "configuration.md"]
    for path in pages:
        text = " ".join(path.read_text().split())
        assert "are never flags" in text and "refused" in text, path.name
    assert "have no flags" not in " ".join(p.read_text() for p in PAGES)


def test_the_architecture_page_names_modules_that_exist() -> None:
    """The layers table names each layer's modules, and the build's path names files: all of
    them exist (a module moved or split must be moved in the page too)."""
    package = REPO / "src" / "docker_ros"
    text = (DOCS / "architecture.md").read_text()
    for row in re.findall(r"^\| `(\w+)/` \|.*$", text, re.M):
        line = next(r for r in text.splitlines() if r.startswith(f"| `{row}/` |"))
        modules = line.split("|")[4]
        for name in re.findall(r"`(\w+)/?`", modules):
            found = [package / row / f"{name}.py", package / row / name]
            assert any(path.exists() for path in found), f"{row}/{name} is named, not found"
    for path in re.findall(r"`((?:cli|host|in_image)/[\w/]+\.py)`", text):
        assert (package / path).exists(), path


def test_a_parser_leaves_the_tasks_help_texts() -> None:
    """invoke pops a task's help texts as it makes its flags: after one parser (this module's
    commands, the docs' reference), --help and every reader of Task.help still find them."""
    before = {name: dict(ns[name].help) for name in ns.task_names}
    ns.to_contexts()
    assert {name: dict(ns[name].help) for name in ns.task_names} == before
    assert any(before.values())
