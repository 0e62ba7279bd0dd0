"""Griffe extension: the API pages show what the reader can use.

- Signatures use the public spellings of types. Inspected annotations carry the modules objects
  are defined in (``hbjax._core.model.Hammerstein``, ``jax.jaxlib._jax.Array``,
  ``jaxtyping.Float[...]``); the reader imports ``hbjax.Hammerstein`` and ``jax.Array``.
- Class attributes whose only "docstring" is that of their value's builtin type (a field
  defaulting to ``""`` would show the documentation of ``str``) are left out: the class
  docstring describes its fields.
"""

import builtins
import importlib
import inspect
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


_BUILTIN_DOCS = {
    inspect.cleandoc(value.__doc__)
    for value in vars(builtins).values()
    if isinstance(value, type) and value.__doc__
} | {inspect.cleandoc(type(None).__doc__ or "")} - {""}


class PublicAnnotations(griffe.Extension):
    def on_class(self, *, cls: griffe.Class, **kwargs) -> None:
        for name, member in list(cls.members.items()):
            if member.is_alias or not member.is_attribute or member.docstring is None:
                continue
            if inspect.cleandoc(member.docstring.value) in _BUILTIN_DOCS:
                cls.del_member(name)

    def on_function(self, *, func: griffe.Function, **kwargs) -> None:
        for parameter in func.parameters:
            parameter.annotation = _rewrite(parameter.annotation)
            if str(parameter.default) == "<factory>":  # a dataclass default_factory
                parameter.default = "..."  # valid Python, so the signature can be formatted
        func.returns = _rewrite(func.returns)

    def on_attribute(self, *, attr: griffe.Attribute, **kwargs) -> None:
        attr.annotation = _rewrite(attr.annotation)
