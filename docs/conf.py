"""Sphinx configuration of the docker-ros docs (MyST Markdown; built by `nox -s docs`)."""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(HERE.parent / "src"))  # the reference is generated from this checkout

project = "docker-ros (Python)"
author = "the docker-ros (Python) authors"
extensions = ["myst_parser", "docker_ros_docs"]
source_suffix = {".md": "markdown"}
exclude_patterns = ["_build"]
myst_heading_anchors = 4
myst_enable_extensions = ["colon_fence"]
html_theme = "alabaster"  # Sphinx's own: nothing to download
html_title = project
# The build must not reach the internet (no intersphinx, no remote images); nitpicky mode
# with -W turns every unresolved link into an error (see noxfile.py's docs session).
nitpicky = True
