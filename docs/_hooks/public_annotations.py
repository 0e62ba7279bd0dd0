"""Griffe extension: signatures on the API pages use the public spellings of types.

Inspected annotations carry the modules objects are defined in (``hbjax._core.model.Hammerstein``,
``jax.jaxlib._jax.Array``, ``jaxtyping.Float[...]``); the reader imports ``hbjax.Hammerstein``
and ``jax.Array``. Each annotation is rewritten to those names.
"""

import importlib
import re

import griffe

_JAX_ARRAY = re.compile(r"\b(?:jax\.)?jaxlib\.(?:_jax|xla_extension)\.(?:ArrayImpl|Array)\b")
_PRIVATE = re.compile(r"\bhbjax(?:\._\w+)+\.([A-Za-z]\w*)")


def _public(text: str) -> str:
    hbjax = importlib.import_module("hbjax")
    text = _JAX_ARRAY.sub("Array", text)
    text = re.sub(r"\bjaxtyping\.", "", text)
    return _PRIVATE.sub(lambda m: f"hbjax.{m.group(1)}" if hasattr(hbjax, m.group(1)) else m.group(0), text)


def _rewrite(annotation):
    if annotation is None:
        return None
    text = str(annotation)
    public = _public(text)
    return annotation if public == text else public


class PublicAnnotations(griffe.Extension):
    def on_function(self, *, func: griffe.Function, **kwargs) -> None:
        for parameter in func.parameters:
            parameter.annotation = _rewrite(parameter.annotation)
        func.returns = _rewrite(func.returns)

    def on_attribute(self, *, attr: griffe.Attribute, **kwargs) -> None:
        attr.annotation = _rewrite(attr.annotation)
