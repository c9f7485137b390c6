"""Sphinx configuration: the pages are Markdown (MyST), readable as they are on any forge.

Build (offline, no CI): pip install -e ".[docs]" && python -m sphinx -W --keep-going -b html docs docs/_build/html
"""

from importlib import metadata

project = "cevm"
author = "the cevm developers"
try:
    release = metadata.version("cevm")
except metadata.PackageNotFoundError:  # building from a checkout without installing it
    release = ""
version = release

extensions = ["myst_parser"]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build"]
# GitHub-style anchors for headings, so that links such as formats.md#cycle-files work the
# same on a forge and in the built site.
myst_heading_anchors = 3
myst_enable_extensions = ["dollarmath"]
# Links to files outside docs/ (the README, the changelog, source files) work on a forge but
# are not pages of the site; tests/test_docs.py checks every relative link and anchor of the
# README and docs/ instead, so Sphinx need not warn about them.
suppress_warnings = ["myst.xref_missing"]

html_theme = "pydata_sphinx_theme"
html_title = "cevm"
html_theme_options = {"navigation_depth": 2, "show_toc_level": 2}
