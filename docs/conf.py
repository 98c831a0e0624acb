"""Sphinx configuration of the torchrl-dual documentation (docs/README.md: how to build)."""

from __future__ import annotations

import os
import sys
import urllib.request
from pathlib import Path

DOCS = Path(__file__).resolve().parent
REPO = DOCS.parent
sys.path[:0] = [str(REPO), str(DOCS / "_ext")]  # this checkout's package and benchmarks/
# the tutorials' child processes (the recipe, Ray's workers) import benchmarks/ too
os.environ["PYTHONPATH"] = os.pathsep.join(
    p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p
)

import torchrl_dual  # noqa: E402

project = "torchrl-dual"
author = "torchrl-dual contributors"
copyright = "torchrl-dual contributors"  # noqa: A001 - Sphinx's name
release = version = torchrl_dual.__version__

extensions = [
    "api_pages",  # docs/_ext: the API pages from every __all__ (before autosummary reads)
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.intersphinx",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "myst_parser",
    "sphinx_design",  # the landing page's cards
    "sphinxcontrib.mermaid",  # architecture.md's ```mermaid diagram (drawn by mermaid.js)
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = [
    "_build",
    "README.md",
    "tutorials",
    "auto_tutorials/*.ipynb",
    "auto_tutorials/*.py",
]
templates_path = ["_templates"]

# ---- the API reference (docs/_ext/api_pages.py writes api/*.rst at config-inited)
autosummary_generate = True
autosummary_imported_members = True
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_typehints_format = "short"
toc_object_entries_show_parents = "hide"  # "On this page": `forward()`, not `DUALLoss.forward()`
autodoc_preserve_defaults = True  # `CONFIG_DIR / "x"` stays an expression, not a path
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
napoleon_use_ivar = True
napoleon_custom_sections = [("Keyword Args", "params_style")]

# ---- links to torch, tensordict and TorchRL. Their inventories are fetched over the
# network at build time. Offline (this project's CI machine reaches package registries
# only) a failed fetch would be a warning, and -W makes it an error, so each inventory is
# used only if it is reachable (a 5 s probe); TORCHRL_DUAL_DOCS_INTERSPHINX=0 skips the
# probe, =1 uses them all unprobed (a failed fetch then fails a -W build).
_INVENTORIES = {
    "python": ("https://docs.python.org/3", None),
    "torch": ("https://docs.pytorch.org/docs/stable", None),
    "tensordict": ("https://docs.pytorch.org/tensordict/stable", None),
    "torchrl": ("https://docs.pytorch.org/rl/stable", None),
}


def _reachable(url: str) -> bool:
    try:
        with urllib.request.urlopen(f"{url}/objects.inv", timeout=5) as response:
            return response.status == 200
    except Exception:  # noqa: BLE001 - offline, DNS, TLS, HTTP errors: not reachable
        return False


_mode = os.environ.get("TORCHRL_DUAL_DOCS_INTERSPHINX", "auto")
intersphinx_mapping = {
    name: entry
    for name, entry in _INVENTORIES.items()
    if _mode == "1" or (_mode == "auto" and _reachable(entry[0]))
}
intersphinx_timeout = 10
# Not nitpicky: a name Sphinx cannot resolve (a private helper, a type of a project whose
# inventory is offline) renders as plain text instead of failing the -W build.

# ---- the guides (Markdown)
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_fence_as_directive = ["mermaid"]  # GitHub's ```mermaid fences, drawn here too
myst_heading_anchors = 4  # [text](page.md#a-heading) links resolve

# ---- the tutorials (docs/tutorials/*.py, executed at every build)
sphinx_gallery_conf = {
    "examples_dirs": "tutorials",
    "gallery_dirs": "auto_tutorials",
    "filename_pattern": r"/\d+_",  # every numbered script is executed
    "within_subsection_order": "FileNameSortKey",
    "download_all_examples": False,
    "remove_config_comments": True,
    "matplotlib_animations": False,
    "show_memory": False,
    "min_reported_time": 0,
}

# ---- the look
html_theme = "pydata_sphinx_theme"
html_title = f"torchrl-dual {release}"
html_static_path = ["_static"]
html_css_files = ["custom.css"]
html_show_sourcelink = False
html_theme_options = {
    "logo": {"text": "torchrl-dual"},
    "navbar_align": "left",
    "show_toc_level": 2,
    "navigation_with_keys": False,
    "header_links_before_dropdown": 6,
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
html_context = {"default_mode": "light"}
