"""MkDocs hook: Sphinx roles in docstrings become links.

Some hbjax docstrings cross-reference with Sphinx roles (``:func:`simulate` ``,
``:class:`hbjax.Hammerstein` ``). Markdown renders those as ``:func:<code>simulate</code>``;
this hook turns them into optional autorefs to the public name (``hbjax.simulate``,
``hbjax.datasets.brfd``, ...): a link where the name is documented, plain code elsewhere.
"""

import re

_ROLE = re.compile(r":(?:func|class|meth|attr|mod|data|obj|exc):<code>~?([^<]+?)(?:\(\))?</code>")
_SCOPES = ("hbjax.", "hbjax.datasets.", "hbjax.plot.")


def _identifier(name: str) -> str:
    if name.startswith("hbjax."):
        return name
    head = name.split(".")[0]
    for scope in _SCOPES:
        module = _public_module(scope)
        if module is not None and hasattr(module, head):
            return scope + name
    return "hbjax." + name


def _public_module(scope: str):
    import importlib

    try:
        return importlib.import_module(scope.rstrip("."))
    except ImportError:
        return None


def _link(match: re.Match) -> str:
    name = match.group(1)
    return f'<autoref identifier="{_identifier(name)}" optional><code>{name}</code></autoref>'


def on_page_content(html, **kwargs):
    return _ROLE.sub(_link, html)
