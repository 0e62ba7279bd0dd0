"""Generate docs/api.md from the docstrings of every public name of hbjax.

    .venv/bin/python docs/gen_api.py           # rewrite docs/api.md
    .venv/bin/python docs/gen_api.py --check   # exit 1 if docs/api.md is out of date

Public names are those re-exported by ``hbjax/__init__.py`` (grouped by its ``# --- area ---``
section comments), plus the functions of the public submodules ``hbjax.datasets`` and
``hbjax.plot``. Docstrings are the source: Sphinx roles such as ``:func:`x` `` become plain
code spans, everything else is copied as Markdown.
"""

import argparse
import dataclasses
import importlib
import inspect
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "api.md"
SUBMODULES = ("datasets", "plot")
TITLES = {
    "refinement": "Refinement: prediction-error fit of the whole model",
    "monte carlo": "Monte Carlo studies",
    "diagnosis": "Diagnosis: does the model fit the recording?",
    "io, datasets, cli": "Recordings, model files and bundled data sets",
}


def sections():
    """``[(title, [name, ...]), ...]`` in the order of ``hbjax/__init__.py``."""
    text = (ROOT / "hbjax" / "__init__.py").read_text()
    out = [("Core: model, simulation, paper signals, closed-form identification", [])]
    for line in text.splitlines():
        marker = re.match(r"#\s*---\s*(.+?)\s*---", line)
        if marker:
            key = re.sub(r"\s*\(issue \d+\)", "", marker.group(1)).strip()
            out.append((TITLES.get(key, key[:1].upper() + key[1:]), []))
            continue
        for name in re.findall(r"\bas\s+([A-Za-z_][A-Za-z0-9_]*)", line.split("#")[0]):
            if not name.startswith("_") and name not in out[-1][1]:
                out[-1][1].append(name)
    return [(title, names) for title, names in out if names]


def clean(doc: str | None) -> str:
    if not doc:
        return "*(no docstring)*"
    doc = inspect.cleandoc(doc)
    doc = re.sub(r":(?:func|class|meth|attr|mod|data|obj):`~?([^`]+)`", r"`\1`", doc)
    doc = doc.replace("``", "`")
    return doc


def signature(obj) -> str:
    target = getattr(obj, "__wrapped__", obj)
    try:
        sig = inspect.signature(target, eval_str=True)
    except (TypeError, ValueError, NameError):
        try:
            sig = inspect.signature(target)
        except (TypeError, ValueError):
            return ""
    if inspect.isclass(obj):
        sig = sig.replace(return_annotation=inspect.Signature.empty)
    text = str(sig)
    # Default values that print as memory addresses would make the file change every run.
    text = re.sub(r" at 0x[0-9a-f]+", "", text)
    # Public spellings of types: hbjax._core.model.Hammerstein -> hbjax.Hammerstein, etc.
    public = importlib.import_module("hbjax")
    text = re.sub(
        r"\bhbjax\._[a-z_]+\.([A-Z]\w*)",
        lambda m: f"hbjax.{m.group(1)}" if hasattr(public, m.group(1)) else m.group(0),
        text,
    )
    text = re.sub(r"\b(?:jax\.)?jaxlib\._jax\.(?:Array|ArrayImpl)", "Array", text)
    text = re.sub(r"\bjaxtyping\.", "", text)
    return text


def members(cls):
    """Public methods and properties defined on ``cls`` itself (not inherited)."""
    out = []
    for name, value in cls.__dict__.items():
        if name.startswith("_"):
            continue
        if isinstance(value, property):
            out.append((name, "property", value.fget.__doc__, ""))
        elif inspect.isfunction(value) or isinstance(value, (staticmethod, classmethod)):
            fn = value.__func__ if isinstance(value, (staticmethod, classmethod)) else value
            sig = signature(fn).replace("(self, ", "(").replace("(self)", "()")
            out.append((name, "method", fn.__doc__, sig))
        elif callable(value) and hasattr(value, "__wrapped__"):
            fn = value.__wrapped__
            sig = signature(fn).replace("(self, ", "(").replace("(self)", "()")
            out.append((name, "method", fn.__doc__, sig))
    return out


def fields(cls):
    if not dataclasses.is_dataclass(cls):
        return []
    return [f.name for f in dataclasses.fields(cls) if not f.name.startswith("_")]


def render_object(qualname: str, obj, level: str = "###") -> list[str]:
    lines = []
    if inspect.isclass(obj):
        lines.append(f"{level} `{qualname}`\n")
        lines.append(f"```python\nclass {qualname}{signature(obj)}\n```\n")
        lines.append(clean(obj.__doc__) + "\n")
        names = fields(obj)
        if names and "**Fields:**" not in (obj.__doc__ or ""):
            lines.append("Fields: " + ", ".join(f"`{n}`" for n in names) + ".\n")
        for name, kind, doc, sig in members(obj):
            head = f"`.{name}`" if kind == "property" else f"`.{name}{sig}`"
            body = clean(doc) if doc else ""
            lines.append(f"- {head}" + (": " + body.replace("\n", "\n  ") if body else ""))
        if members(obj):
            lines.append("")
    elif inspect.ismodule(obj):
        lines.append(f"{level} `{qualname}` (module)\n")
        first = clean(obj.__doc__).split("\n\n")[0]
        lines.append(f"{first} See [`{qualname}` functions](#{anchor(qualname)}-functions).\n")
    elif callable(obj):
        lines.append(f"{level} `{qualname}`\n")
        lines.append(f"```python\n{qualname}{signature(obj)}\n```\n")
        lines.append(clean(obj.__doc__) + "\n")
    else:
        lines.append(f"{level} `{qualname}` ({type(obj).__name__})\n")
        lines.append(data_comment(qualname.rsplit(".", 1)[-1]) + "\n")
        if isinstance(obj, dict):
            lines.append("Keys: " + ", ".join(f"`{k}`" for k in obj) + ".\n")
    return lines


def data_comment(name: str) -> str:
    """The ``#:`` comment lines above ``NAME = ...`` in the hbjax sources (Sphinx style)."""
    for path in sorted((ROOT / "hbjax").glob("*.py")):
        match = re.search(rf"((?:^#:.*\n)+)^{re.escape(name)}\b.*=", path.read_text(), re.M)
        if match:
            return clean(" ".join(line[2:].strip() for line in match.group(1).splitlines()))
    return "*(no description)*"


def anchor(text: str) -> str:
    return re.sub(r"[^a-z0-9 -]", "", text.lower()).replace(" ", "-")


def module_functions(module):
    names = getattr(module, "__all__", None) or [
        n for n, v in vars(module).items()
        if not n.startswith("_") and (inspect.isfunction(v) or inspect.isclass(v))
        and getattr(v, "__module__", "").startswith("hbjax")
    ]
    return sorted(names)


def generate() -> str:
    sys.path.insert(0, str(ROOT))
    hbjax = importlib.import_module("hbjax")
    out = [
        "# API reference\n",
        "Generated from the docstrings by `docs/gen_api.py`; do not edit by hand. Conventions "
        "(equations, normalisation, signals): [conventions.md](conventions.md).\n",
        f"hbjax {hbjax.__version__}. `import hbjax` enables JAX's float64 mode.\n",
    ]
    toc = []
    body = []
    for title, names in sections():
        toc.append(f"- [{title}](#{anchor(title)}): " + ", ".join(f"`{n}`" for n in names))
        body.append(f"## {title}\n")
        for name in names:
            obj = getattr(hbjax, name)
            body.extend(render_object(f"hbjax.{name}", obj))
    for sub in SUBMODULES:
        try:
            module = importlib.import_module(f"hbjax.{sub}")
        except ImportError:
            continue
        title = f"hbjax.{sub} functions"
        names = module_functions(module)
        if not names:
            continue
        toc.append(f"- [`hbjax.{sub}`](#{anchor(title)}): " + ", ".join(f"`{n}`" for n in names))
        body.append(f"## {title}\n")
        body.append(clean(module.__doc__) + "\n")
        for name in names:
            body.extend(render_object(f"hbjax.{sub}.{name}", getattr(module, name)))
    toc.append("- Command line: see [io_and_cli.md](io_and_cli.md) (`hbjax --help`).")
    return "\n".join(out + ["## Contents\n"] + toc + [""] + body).rstrip() + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="fail if docs/api.md is stale")
    args = parser.parse_args()
    text = generate()
    if args.check:
        if not OUT.exists() or OUT.read_text() != text:
            print("docs/api.md is out of date: run .venv/bin/python docs/gen_api.py", file=sys.stderr)
            return 1
        return 0
    OUT.write_text(text)
    print(f"wrote {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
