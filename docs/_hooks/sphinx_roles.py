"""MkDocs hook: Sphinx roles in docstrings become links.

Some hbjax docstrings cross-reference with Sphinx roles (``:func:`simulate` ``,
``:class:`hbjax.Hammerstein` ``). Markdown renders those as ``:func:<code>simulate</code>``;
this hook turns them into optional autorefs to the public name (``hbjax.simulate``,
``hbjax.datasets.brfd``, ...): a link where the name is documented, plain code elsewhere.
"""

import functools
import importlib
import pkgutil
import re

_ROLE = re.compile(r":(?:func|class|meth|attr|mod|data|obj|exc):<code>~?([^<]+?)(?:\(\))?</code>")


@functools.cache
def _scopes() -> tuple:
    """``hbjax`` and its public submodules (``hbjax.datasets``, ``hbjax.plot``, ...)."""
    hbjax = importlib.import_module("hbjax")
    names = [m.name for m in pkgutil.iter_modules(hbjax.__path__) if not m.name.startswith("_")]
    return (hbjax,) + tuple(importlib.import_module(f"hbjax.{name}") for name in names)


def _identifier(name: str) -> str:
    if name.startswith("hbjax."):
        return name
    head = name.split(".")[0]
    for module in _scopes():
        if hasattr(module, head) and not isinstance(getattr(module, head), type(module)):
            return f"{module.__name__}.{name}"
    return f"hbjax.{name}"


def _link(match: re.Match) -> str:
    name = match.group(1)
    return f'<autoref identifier="{_identifier(name)}" optional><code>{name}</code></autoref>'


def on_page_content(html, **kwargs):
    return _ROLE.sub(_link, html)
