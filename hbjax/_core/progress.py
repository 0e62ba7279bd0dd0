"""Progress bars for the long-running entry points (``fit``, ``diagnose``,
``monte_carlo``, ``select_structure``), one policy for all of them.

Every such function takes ``progress=True``; pass it here unchanged::

    with progress_bar(progress, total=len(items), desc="select_structure") as bar:
        for item in items:
            ...
            bar.update(1)

- ``progress=False`` (or ``None``): nothing is printed, ever.
- ``progress=True``: a ``tqdm.auto`` bar (a widget in Jupyter when ipywidgets is
  installed, text otherwise) on stderr, shown only once the work has taken more than
  :data:`DELAY` seconds, and only on a terminal or in a Jupyter kernel (logs, pipes and
  CI stay clean).
- ``progress=<dict>``: keyword arguments for ``tqdm`` (e.g. ``{"delay": 0, "file":
  sys.stdout}``); the bar is then shown wherever it is asked to write.

``live=True`` refreshes the bar from a background thread while one long call blocks (a
single jitted computation that cannot report by itself), so it shows the elapsed time.
"""

import contextlib
import sys
import threading
import time
import warnings


#: seconds of work before a bar appears
DELAY = 2.0
#: seconds between refreshes of a live bar
_TICK = 0.5


class NullBar:
    """The bar of ``progress=False``: accepts every call and prints nothing."""

    n = 0

    def update(self, n=1):
        pass

    def set_postfix_str(self, s="", refresh=True):
        pass

    def set_description(self, desc=None, refresh=True):
        pass

    def close(self):
        pass


def _interactive() -> bool:
    """stderr is a terminal, or we run in a Jupyter kernel."""
    ipython = sys.modules.get("IPython")
    if "ipykernel" in sys.modules and ipython is not None:
        shell = ipython.get_ipython()
        if shell is not None and getattr(shell, "kernel", None) is not None:
            return True
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


def _tqdm_class():
    with warnings.catch_warnings():  # no ipywidgets: tqdm.auto warns, then uses text
        warnings.simplefilter("ignore")
        from tqdm.auto import tqdm
    return tqdm


def check_progress(progress, name: str = "progress"):
    """``progress`` is a bool, ``None`` or a dict of tqdm keyword arguments."""
    if progress is None or isinstance(progress, (bool, dict)):
        return progress
    raise TypeError(f"`{name}` must be True, False or a dict of tqdm options, got {progress!r}.")


def make_bar(progress, *, total=None, desc=None, unit="it", live=False):
    """A tqdm bar following the policy of the module docstring, or a :class:`NullBar`.
    Close it with ``.close()`` (or use :func:`progress_bar`)."""
    progress = check_progress(progress)
    if not progress:
        return NullBar()
    options = {"delay": DELAY, "file": sys.stderr, "dynamic_ncols": True, "leave": True,
               "total": total, "desc": desc, "unit": unit}
    if isinstance(progress, dict):
        options.update(progress)  # the user's options override the defaults, `desc` too
    elif not _interactive():
        return NullBar()
    bar = _tqdm_class()(**options)
    if live:
        _start_ticker(bar, float(options.get("delay", DELAY)))
    return bar


def _start_ticker(bar, delay):
    stop = threading.Event()
    start = time.monotonic()

    def tick():
        while not stop.wait(_TICK):
            if time.monotonic() - start >= delay:
                try:
                    bar.refresh()
                except Exception:  # a closed or broken stream must not kill the work
                    return

    thread = threading.Thread(target=tick, name="hbjax-progress", daemon=True)
    close = bar.close

    def close_and_stop():
        stop.set()
        thread.join()
        close()

    bar.close = close_and_stop
    thread.start()


@contextlib.contextmanager
def progress_bar(progress, *, total=None, desc=None, unit="it", live=False):
    """Context manager around :func:`make_bar`: yields the bar, closes it on exit (also
    when the work raises)."""
    bar = make_bar(progress, total=total, desc=desc, unit=unit, live=live)
    try:
        yield bar
    finally:
        bar.close()
