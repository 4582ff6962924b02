"""Sphinx configuration of the stealth-ns docs site (`make docs`, warnings are errors)."""

from __future__ import annotations

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS / "_ext"))

project = "stealth-ns"
author = "stealth-ns developers"
extensions = ["myst_parser", "cli_reference"]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build"]
html_theme = "furo"
html_title = "stealth-ns"
# links such as [the scan guide](../guides/scan.md#limits) are checked, headings included
myst_heading_anchors = 4
myst_enable_extensions = ["colon_fence"]
# a fenced block in a language Pygments does not know is shown as plain text, not a warning
highlight_language = "text"
suppress_warnings: list[str] = []
nitpicky = False
