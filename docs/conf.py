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

extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.autosummary", "sphinx.ext.napoleon"]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}  # .rst: the generated API pages
root_doc = "index"
exclude_patterns = ["_build", "_templates"]
# GitHub-style anchors for headings, so that links such as formats.md#cycle-files work the
# same on a forge and in the built site.
myst_heading_anchors = 3
myst_enable_extensions = ["dollarmath"]
# Links to files outside docs/ (the README, the changelog, source files) work on a forge but
# are not pages of the site; tests/test_docs.py checks every relative link and anchor of the
# README and docs/ instead, so Sphinx need not warn about them.
suppress_warnings = ["myst.xref_missing"]

# The API reference (api/index.md): a page per package and module, generated from the
# docstrings at build time into api/generated (not committed), with the templates in
# _templates/autosummary (the command line and python -m cevm are left out: their reference
# is reference/commands.md). Docstrings are numpydoc-style sections read by napoleon.
import cevm  # noqa: E402  (the public names the cevm page lists)

templates_path = ["_templates"]
autosummary_generate = True
autosummary_context = {"public": [n for n in cevm.__all__ if not n.startswith("_")]}
# ignore-module-all: a package re-exports its modules' names in __all__; each is documented once, where defined
autodoc_default_options = {"member-order": "bysource", "ignore-module-all": True}
autodoc_typehints = "description"
napoleon_numpy_docstring = True
napoleon_google_docstring = False

# The README and the changelog live at the top of the repository, where a forge shows
# them; the site has them as pages (readme.md and changelog.md include them), and the
# manual's links to ../README.md and ../CHANGELOG.md point there when the site is built
# (on a forge they keep pointing at the files themselves).
SITE_PAGES = {"../README.md": "readme.md", "../CHANGELOG.md": "changelog.md"}


def _site_links(app, docname, source):
    for repo_path, page in SITE_PAGES.items():
        source[0] = source[0].replace(f"]({repo_path}", f"]({page}")


def _included_links(app, relative_path, parent_docname, content):
    """The README's own link to the changelog, as the site has it (its links into docs/
    are made relative by the include's relative-docs)."""
    if relative_path.name == "README.md":
        content[0] = content[0].replace("](CHANGELOG.md", "](docs/changelog.md")


def setup(app):
    app.connect("source-read", _site_links)
    app.connect("include-read", _included_links)


html_theme = "pydata_sphinx_theme"
html_title = "cevm"
html_theme_options = {"navigation_depth": 2, "show_toc_level": 2}
