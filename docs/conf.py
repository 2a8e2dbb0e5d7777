"""Sphinx configuration of lidarpkt's documentation site.

Build it with ``python -m sphinx -W --keep-going -b html docs docs/_build/html`` (the ``docs`` extra);
``tests/docs/test_docs.py`` runs the same build in the test suite. Why Sphinx (and not MkDocs): see
``docs/design.md``, "How this site is built".
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

import lidarpkt  # noqa: E402

project = "lidarpkt"
author = "the lidarpkt developers"
copyright = "the lidarpkt developers, BSD-3-Clause"  # noqa: A001
release = lidarpkt.__version__
version = release

extensions = [
    "myst_parser",            # the pages are Markdown (MyST)
    "sphinx.ext.autodoc",     # the API reference, from the docstrings
    "sphinx.ext.napoleon",    # the docstrings' Args: / Returns: / Raises: sections
    "sphinx.ext.viewcode",    # the source beside each documented name
    "sphinxarg.ext",          # the CLI reference, from lidarpkt.cli.build_parser("*")
    "lidarpkt_docs",          # cross-references resolved by identity; see docs/_ext/lidarpkt_docs.py
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

# Every warning fails the build (-W); nitpicky makes an unresolved cross-reference one. References the
# docstrings make to internal modules and to other libraries are settled in lidarpkt_docs.
nitpicky = True

myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3
# "more than one target found": a short name in a docstring's field list (``lost_packets``) that several
# classes define; the link goes to one of them. An unresolved reference still fails the build.
suppress_warnings = ["ref.python"]

autodoc_default_options = {"members": True, "undoc-members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_typehints_format = "short"
autodoc_preserve_defaults = False  # True fails on some signatures (a **options: Unpack[...])
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
napoleon_use_ivar = True  # "Attributes:" as a field list: the attributes themselves are documented by autodoc

html_theme = "furo"
html_title = f"lidarpkt {release}"
html_static_path: list[str] = []
html_show_sourcelink = False
