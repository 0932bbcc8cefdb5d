"""Sphinx configuration of the chainspace documentation (``make docs``; tests/test_docs.py builds it with -W)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # document the checkout, also when chainspace is not installed

import chainspace  # noqa: E402

project = "chainspace"
author = "the chainspace developers"
copyright = "2026, the chainspace developers"
release = version = chainspace.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "myst_parser",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

# MyST: $...$ maths for the concept pages, ::: fences, heading anchors for cross-page links.
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# The docstrings are numpy-style ("Parameters\n----------").
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
napoleon_use_ivar = True  # attributes as fields of their class, not as separate entries beside autodoc's

autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_typehints_description_target = "documented"  # no type-only lists of undocumented __init__ fields
autodoc_default_options = {"members": True}
# Type hints name numpy's and the standard library's types; they are not part of this site.
nitpicky = False

html_theme = "furo"
html_title = f"chainspace {release}"
html_static_path = ["_static"]


# Some result classes list their attributes as "name : what it is" lines (a description, not a type,
# after the colon). Numpy style would read the description as a type and try to cross-reference
# its words; turn such lines into "name" followed by the indented description before napoleon
# reads them.
_ATTR_LINE = re.compile(r"^(\s*)([A-Za-z_][\w, ]*?) : (.+)$")


def _attributes_as_descriptions(app, what, name, obj, options, lines):
    in_attributes = False
    for i, line in enumerate(lines):
        stripped = line.strip()
        if stripped in ("Attributes", "Parameters", "Returns", "Raises", "Notes", "Examples", "See Also"):
            in_attributes = stripped == "Attributes" and i + 1 < len(lines) and set(lines[i + 1].strip()) == {"-"}
            continue
        if in_attributes:
            m = _ATTR_LINE.match(line)
            if m and not m.group(1):
                names = [n.strip() for n in m.group(2).split(",")]
                lines[i:i + 1] = [x for n in names for x in (n, "    " + m.group(3))]


def setup(app):
    app.connect("autodoc-process-docstring", _attributes_as_descriptions, priority=100)
