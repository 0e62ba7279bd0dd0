"""MkDocs hook: the API pages import hbjax without running its command line.

mkdocstrings inspects the imported package, submodules included; ``hbjax/__main__.py`` runs the
CLI when imported. A placeholder in ``sys.modules`` stands in for it while the site is built.
"""

import sys
import types


def on_startup(**kwargs):
    sys.modules.setdefault("hbjax.__main__", types.ModuleType("hbjax.__main__"))
