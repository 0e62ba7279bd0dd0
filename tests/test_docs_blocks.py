"""Every ```python block of the guides (docs/*.md) runs as a user would copy it.

A page's blocks run in order in one fresh namespace (the module ``__main__``), like cells
pasted into one new notebook, in an empty temporary working directory, with matplotlib's
Agg backend, and with JAX's 64-bit mode off as in a new interpreter (the suite's conftest
switches it on; a page that needs it must switch it on itself, as a user must). A block
written as an interactive session (``>>>`` prompts) runs as a doctest in the same
namespace: its shown output must match (``...`` stands for elided text). A block whose
first line is a comment naming a script (``# study.py - ...``) is what a user saves to
that file and starts with ``python study.py``: it is written there and run in an
interpreter of its own.

No block is skipped: a failing block fails its page's test with the page, the block's
index and line, and the error. Where a page states a value its blocks compute, CHECKS
holds that statement as an expression evaluated in the page's namespace after the block.
"""

import doctest
import pathlib
import re
import socket
import subprocess
import sys
import time
import traceback
import types

import jax
import matplotlib
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PAGES = sorted(
    page for page in (ROOT / "docs").glob("*.md") if re.search(r"^```python\n", page.read_text(), re.M)
)
SCRIPT = re.compile(r"#\s*([\w-]+\.py)\b")

# What a page states about the values its blocks compute: {page: {block index: [expression]}},
# each evaluated in the page's namespace right after that block.
CHECKS = {
    "io_and_cli.md": {
        1: ["rec.dt == 0.001 and (rec.source, rec.name) == ('bench.csv', 'bench')",
            "rec.v.dtype == rec.y.dtype == 'float64' and len(rec.v) == len(rec.y)",
            "not (rec.v.flags.writeable or rec.y.flags.writeable)"],
        3: ["coarse.dt == 16.0"],
        7: ["(len(est), len(val), est.dt) == (1024, 1024, 4.0)",
            "hbjax.datasets.brfd_names() == ['0.25Hz36lbtension1amplitude', "
            "'0.5Hz30lbtension1amplitude', '1Hz30lbtension1amplitude', '1Hz36lbtension1.5amplitude']",
            "len(rec) == 7169 and rec.dt == 1 / 1024"],
    },
    "refinement.md": {0: ["0.5 < float(params[1]) < 2.0"]},  # "about ... (1 / 0.9)"
    "training.md": {
        0: ["plants.backlash.c1.dtype == jnp.float32"],  # "float32: jax_enable_x64 is left off"
        1: ["any(bool(jnp.any(g != 0)) for g in jax.tree_util.tree_leaves(grads))"],
    },
}


def python_blocks(text: str) -> list[tuple[int, str]]:
    """The ```python blocks of a Markdown text: ``(line of the fence, code)``."""
    return [
        (text[: m.start()].count("\n") + 1, m.group(1))
        for m in re.finditer(r"^```python\n(.*?)^```[ \t]*$", text, re.S | re.M)
    ]


def _blank_lines_shown(session: str) -> str:
    """A session's blank lines inside printed output as doctest's ``<BLANKLINE>`` (doctest
    otherwise ends the expected output there and checks nothing after it)."""
    lines = session.rstrip("\n").split("\n")
    return "\n".join(
        "<BLANKLINE>" if not line.strip() and not lines[i + 1].lstrip().startswith(">>>") else line
        for i, line in enumerate(lines[:-1])
    ) + "\n" + lines[-1] + "\n"


def _run_block(page: pathlib.Path, index: int, line: int, code: str, namespace: dict) -> None:
    where = f"{page.name}, block {index} (line {line})"
    script = SCRIPT.match(code.lstrip())
    if script:
        pathlib.Path(script.group(1)).write_text(code)
        proc = subprocess.run([sys.executable, script.group(1)], capture_output=True, text=True,
                              timeout=600)
        assert proc.returncode == 0, f"{where}: `python {script.group(1)}` failed\n{proc.stderr[-4000:]}"
    elif code.lstrip().startswith(">>>"):
        test = doctest.DocTestParser().get_doctest(_blank_lines_shown(code), namespace, where,
                                                   str(page), line)
        report = []
        runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
        runner.run(test, out=report.append, clear_globs=False)
        assert not runner.failures, f"{where}: the session's output differs\n" + "".join(report)
    else:
        try:
            exec(compile(code, f"{page.name}[{index}]", "exec", dont_inherit=True), namespace)
        except Exception:
            raise AssertionError(f"{where} failed:\n{traceback.format_exc()}") from None
    false = [check for check in CHECKS.get(page.name, {}).get(index, []) if not eval(check, namespace)]
    assert not false, f"{where} ran, but what the page states is false: {false}"


@pytest.fixture
def fresh_session(tmp_path, monkeypatch):
    """An empty working directory, JAX's 64-bit mode off (a new interpreter's default), a new
    module ``__main__`` whose namespace the blocks share, the Agg backend; all restored after."""
    monkeypatch.chdir(tmp_path)
    # docs/monte_carlo.md's multi-host script reads its coordinator from COORDINATOR: a free
    # port here, not its default 1234, which another run on this machine may hold
    with socket.socket() as probe:
        probe.bind(("localhost", 0))
        monkeypatch.setenv("COORDINATOR", f"localhost:{probe.getsockname()[1]}")
    main = types.ModuleType("__main__")
    monkeypatch.setitem(sys.modules, "__main__", main)
    matplotlib.use("Agg")
    x64 = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", False)
    try:
        yield main.__dict__
    finally:
        jax.config.update("jax_enable_x64", x64)
        import matplotlib.pyplot as plt

        plt.close("all")


@pytest.mark.parametrize("page", PAGES, ids=[p.stem for p in PAGES])
def test_page_blocks_run(page, fresh_session):
    blocks = python_blocks(page.read_text())
    assert blocks
    for index, (line, code) in enumerate(blocks):
        start = time.perf_counter()
        _run_block(page, index, line, code, fresh_session)
        print(f"{page.name}, block {index} (line {line}): {time.perf_counter() - start:.1f} s")


def test_every_python_fence_is_collected():
    # a fence spelled otherwise (```py, ```pycon, indented, with attributes) would be skipped
    for page in sorted((ROOT / "docs").glob("*.md")):
        text = page.read_text()
        fences = re.findall(r"^[ \t]*```[ \t]*\{?\.?py", text, re.M | re.I)
        assert len(fences) == len(python_blocks(text)), f"{page.name}: write python fences as ```python"


def test_checks_name_blocks_that_exist():
    blocks = {page.name: len(python_blocks(page.read_text())) for page in PAGES}
    for name, checks in CHECKS.items():
        assert all(0 <= index < blocks.get(name, 0) for index in checks), name
