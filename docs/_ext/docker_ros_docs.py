"""Sphinx directives that write parts of the docs from the code at build time, so that they
cannot drift from it:

- ``settings-reference``: the configuration reference, one row per setting declaration
  (docker_ros.cli.reference.table);
- ``steps-table``: the ten steps, each with the settings its task takes
  (docker_ros.cli.reference.steps_table), and the flags every step task shares;
- ``stage-graph``: the Dockerfile's stages as a text tree (docker_ros.cli.reference.stage_graph).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, List

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective

ROOT = Path(__file__).resolve().parents[2]


class MarkdownDirective(SphinxDirective):
    """Renders the Markdown text() returns, in the page's own parser (MyST)."""

    def text(self) -> str:
        raise NotImplementedError

    def run(self) -> List[nodes.Node]:
        from docker_ros.cli import reference

        self.env.note_dependency(reference.__file__)
        container = nodes.container()
        self.state.nested_parse(StringList(self.text().splitlines(), source="(generated)"),
                                self.content_offset, container)
        return container.children


class SettingsReference(MarkdownDirective):
    def text(self) -> str:
        from docker_ros.cli import reference
        from docker_ros.core import settings

        self.env.note_dependency(settings.__file__)
        return reference.table()


class StepsTable(MarkdownDirective):
    def text(self) -> str:
        from docker_ros.cli import reference

        flags = ", ".join(f"`{flag}`" for flag in reference.common_step_flags())
        return reference.steps_table() + f"\n\nEvery step task also takes {flags}."


class StageGraph(SphinxDirective):
    def run(self) -> List[nodes.Node]:
        from docker_ros.cli import reference

        dockerfile = ROOT / "docker" / "Dockerfile"
        self.env.note_dependency(str(dockerfile))
        graph = reference.stage_graph(dockerfile.read_text())
        return [nodes.literal_block(graph, graph, language="text")]


def setup(app: Sphinx) -> Dict[str, Any]:
    app.add_directive("settings-reference", SettingsReference)
    app.add_directive("steps-table", StepsTable)
    app.add_directive("stage-graph", StageGraph)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
