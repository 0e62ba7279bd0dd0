"""The documentation site builds without a warning and documents every public name."""

import importlib
import inspect
import os
import pathlib
import pkgutil
import re
import subprocess
import sys

import hbjax

ROOT = pathlib.Path(__file__).resolve().parents[1]
API = ROOT / "docs" / "api"


def documented_names() -> list[str]:
    """Every ``::: hbjax.X`` line of the API pages."""
    return [
        name
        for page in sorted(API.glob("*.md"))
        for name in re.findall(r"^:::\s+(hbjax[\w.]*)\s*$", page.read_text(), re.M)
    ]


def public_names() -> set[str]:
    """``hbjax.X`` for every public attribute, and the members of every public submodule."""
    top = {name: getattr(hbjax, name) for name in dir(hbjax) if not name.startswith("_")}
    names = {f"hbjax.{name}" for name, value in top.items() if not inspect.ismodule(value)}
    for module_info in pkgutil.iter_modules(hbjax.__path__):
        if module_info.name.startswith("_"):
            continue
        module = importlib.import_module(f"hbjax.{module_info.name}")
        names.add(f"hbjax.{module_info.name}")
        members = getattr(module, "__all__", None) or [
            name
            for name, value in vars(module).items()
            if not name.startswith("_")
            and not inspect.ismodule(value)
            and getattr(value, "__module__", "").startswith("hbjax")
            and not any(value is other for other in top.values())
        ]
        names.update(f"hbjax.{module_info.name}.{name}" for name in members)
    return names


def test_every_public_name_has_one_api_entry():
    documented = documented_names()
    duplicates = sorted({name for name in documented if documented.count(name) > 1})
    assert not duplicates, f"documented twice in docs/api/: {duplicates}"
    missing = sorted(public_names() - set(documented))
    assert not missing, f"add a line `::: NAME` to a page of docs/api/ for each of {missing}"


def test_api_pages_name_only_public_objects():
    public = public_names()
    private = [name for name in documented_names() if name not in public]
    assert not private, f"docs/api/ documents names that are not public: {private}"


def test_site_builds_strict(tmp_path):
    """`mkdocs build --strict` fails on any warning: a broken link, a missing object, an
    unresolved cross-reference, a page missing from the navigation."""
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    site = tmp_path / "site"
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT, env=env, capture_output=True, text=True,
    )
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log[-4000:]
    assert "WARNING" not in log, log[-4000:]
    # The README's quickstarts are included in the home page.
    home = re.sub(r"<[^>]+>", "", (site / "index.html").read_text())
    assert "hbjax.identify_giri(design, y1, y2, y3)" in home
    assert "hbjax montecarlo --config study_config.json" in home
    # Every documented object has its anchor, and Sphinx roles did not leak into the pages.
    pages = "".join(path.read_text() for path in (site / "api").rglob("index.html"))
    for name in documented_names():
        assert f'id="{name}"' in pages, name
    assert ":func:" not in pages and ":class:" not in pages
