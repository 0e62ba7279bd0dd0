"""Paths in and out: the checks every reader makes before opening a file, and the atomic,
no-clobber writer every hbjax writer (Python API and command line) goes through.

Writing rules (``docs/robustness.md``):

- a regular file is written to a short-named temporary file in the same folder, flushed to
  disk and then published: with ``os.link`` (fails if the name appeared meanwhile: no
  clobbering, even in a race), or ``os.replace`` when ``overwrite``. On file systems without
  hard links (vfat, SMB) a new file is created with ``O_EXCL`` instead, which also never
  replaces a file that appeared during the write;
- character devices and FIFOs (``/dev/null``, ``/dev/stdout``, a named pipe) are written
  into, never replaced: nothing is destroyed, so no ``overwrite`` is needed. So is a regular
  file named by an open file descriptor (``/dev/stdout`` redirected to a file, ``/dev/fd/N``,
  ``/proc/<pid>/fd/N``), appended to; any other name of a regular file, under ``/proc`` or
  not, follows the rules above. Block devices and sockets are refused, and so is ``-``
  (write to ``/dev/stdout`` instead);
- several outputs of one command are checked together before any work
  (:func:`check_outputs`) and published together (:func:`atomic_write_many`): if one cannot
  be published, the new files already published are removed again.
"""

from __future__ import annotations

import errno
import os
import pathlib
import re
import stat
import tempfile

# link() errors that mean "this file system has no hard links", not "the name is taken".
_NO_HARD_LINKS = {errno.EPERM, errno.EACCES, errno.EXDEV, errno.EMLINK, errno.ENOSYS,
                  errno.EOPNOTSUPP, errno.ENOTSUP}


HINT = "overwrite=True (--force on the command line)"


def as_path(path) -> pathlib.Path:
    """``path`` as a Path; anything but a ``str`` or ``os.PathLike`` (``None``, a number,
    an open file) is a ``TypeError`` naming `path`."""
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"`path` must be a file name (a str or os.PathLike), got "
                        f"{type(path).__name__}.")
    return pathlib.Path(path)


def check_readable(path, what: str) -> pathlib.Path:
    """``path`` as a Path, if it names something readable as a file: a regular file or a
    FIFO (``<(...)`` process substitution). ``FileNotFoundError`` / ``IsADirectoryError`` /
    ``ValueError`` (devices, sockets) otherwise, naming ``what`` and the path."""
    p = as_path(path)
    try:
        mode = os.stat(p).st_mode
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} {str(p)!r} does not exist.") from None
    except NotADirectoryError:
        raise FileNotFoundError(
            f"{what} {str(p)!r} does not exist (a folder in its path is a file)."
        ) from None
    if stat.S_ISDIR(mode):
        raise IsADirectoryError(f"{what} {str(p)!r} is a directory, not a file.")
    if not (stat.S_ISREG(mode) or stat.S_ISFIFO(mode)):
        raise ValueError(f"{what} {str(p)!r} is not a regular file (a device or socket).")
    return p


# An entry of a file-descriptor folder: /proc/<pid>/fd/N (also per thread), /dev/fd/N.
_FD_ENTRY = re.compile(r"/proc/[^/]+(/task/[^/]+)?/fd/[^/]+|/dev/fd/[^/]+")


def _names_open_file(p: pathlib.Path) -> bool:
    """True if ``p`` is, or links through, an entry of a file-descriptor folder
    (``/dev/stdout`` is a link to ``/proc/self/fd/1``): such a name stands for a file this
    process holds open, e.g. a redirected standard output, which is written into. Other
    names under ``/proc`` (``/proc/self/cwd/...``, ``/proc/<pid>/root/...``) reach ordinary
    files, which are not: they get the no-clobber rules of any other name."""
    path, hops = os.path.abspath(p), 0
    while hops < 40:
        # The folder resolved too: /dev/fd and /proc/self are themselves links.
        resolved = os.path.join(os.path.realpath(os.path.dirname(path)), os.path.basename(path))
        if _FD_ENTRY.fullmatch(path) or _FD_ENTRY.fullmatch(resolved):
            return True
        if not os.path.islink(path):
            return False
        path = os.path.join(os.path.dirname(path), os.readlink(path))
        hops += 1
    return False


def _is_special(p: pathlib.Path) -> bool:
    """True for what is written into rather than replaced: an existing character device or
    FIFO (followed through symbolic links), or an open file named by its file descriptor."""
    try:
        mode = os.stat(p).st_mode
    except OSError:
        return False
    return stat.S_ISCHR(mode) or stat.S_ISFIFO(mode) or (
        stat.S_ISREG(mode) and _names_open_file(p))


def check_writable(path, *, overwrite: bool, hint: str = HINT) -> pathlib.Path:
    """Everything about the output ``path`` that can be checked before writing: not ``-``,
    not a directory, block device or socket, folder exists, and no existing file unless
    ``overwrite`` (devices and FIFOs are written into). Returns the path."""
    as_path(path)
    if str(path) == "-":
        raise ValueError(
            "'-' is not a file name hbjax writes to; to write to standard output give "
            "/dev/stdout."
        )
    p = pathlib.Path(path)
    if _is_special(p):
        return p
    if os.path.lexists(p):
        try:
            mode = os.stat(p).st_mode
        except OSError:  # a dangling symbolic link
            raise FileExistsError(
                f"{str(p)!r} is a symbolic link to a missing file; remove it or choose "
                "another name."
            ) from None
        if stat.S_ISDIR(mode):
            raise IsADirectoryError(f"{str(p)!r} is a directory, not a file.")
        if not stat.S_ISREG(mode):
            raise ValueError(f"{str(p)!r} is a block device or socket; hbjax does not write to it.")
        if not overwrite:
            raise FileExistsError(f"{str(p)!r} already exists; pass {hint} to replace it.")
    parent = p.parent if str(p.parent) else pathlib.Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"folder {str(parent)!r} of {str(p)!r} does not exist.")
    return p


def _target(p: pathlib.Path) -> pathlib.Path:
    """Where a regular file behind ``p`` lives: symbolic links are followed, so replacing
    the file keeps the link."""
    if os.path.islink(p):
        return pathlib.Path(os.path.realpath(p))
    return p


def _write_into(p: pathlib.Path, payload: bytes) -> None:
    """Write into an existing device, FIFO or open file named by its file descriptor."""
    # Append: a FIFO or device does not care, and a redirected standard output keeps what
    # was printed before.
    with open(p, "ab") as fh:
        fh.write(payload)
        fh.flush()


def _default_mode() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def _fill_temporary(folder: pathlib.Path, payload: bytes, target: pathlib.Path) -> str:
    # A short name: a 255-character target name must still leave room for the temporary one.
    try:
        fd, tmp = tempfile.mkstemp(prefix=".hbjax-", suffix=".tmp", dir=folder)
    except OSError as exc:  # named by the user's file, not by the hidden temporary one
        raise type(exc)(f"cannot write {str(target)!r}: its folder {str(folder)!r} takes no "
                        f"new file ({exc.strerror}).") from None
    try:
        os.chmod(tmp, _default_mode())  # mkstemp makes it private (0600)
        with os.fdopen(fd, "wb") as fh:
            fh.write(payload)
            fh.flush()
            os.fsync(fh.fileno())
    except BaseException:
        os.unlink(tmp)
        raise
    return tmp


def _create_exclusive(p: pathlib.Path, payload: bytes, hint: str) -> None:
    """Create ``p`` with O_EXCL and write ``payload``: never replaces a file, even one that
    appeared a moment ago. A failed write removes the file it created."""
    try:
        fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except FileExistsError:
        raise FileExistsError(f"{str(p)!r} already exists; pass {hint} to replace it.") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(payload)
            fh.flush()
            os.fsync(fh.fileno())
    except BaseException:
        os.unlink(p)
        raise


def _publish(tmp: str, p: pathlib.Path, payload: bytes, overwrite: bool, hint: str) -> None:
    if overwrite:
        # The replaced file's permissions carry over (a private 0600 model file stays
        # private; the temporary file has the umask's default mode).
        try:
            os.chmod(tmp, stat.S_IMODE(os.stat(p).st_mode))
        except FileNotFoundError:
            pass
        os.replace(tmp, p)
        return
    try:
        os.link(tmp, p)  # fails if the target appeared meanwhile: no clobbering in a race
    except FileExistsError:
        raise FileExistsError(f"{str(p)!r} already exists; pass {hint} to replace it.") from None
    except OSError as exc:
        if exc.errno not in _NO_HARD_LINKS:
            raise
        _create_exclusive(p, payload, hint)  # file systems without hard links
    os.unlink(tmp)


def _encode(data) -> bytes:
    if isinstance(data, str):
        return data.encode("utf-8")
    if isinstance(data, (bytes, bytearray)):
        return bytes(data)
    raise TypeError(f"data to write must be str or bytes, got {type(data).__name__}.")


def atomic_write_many(items, *, overwrite: bool = False, hint: str = HINT):
    """Write every ``(path, data)`` of ``items``, all or nothing.

    All paths are checked first (:func:`check_writable`; two items naming the same file are
    refused), then every regular file is filled as a temporary file, and only then are they
    published. If publishing one fails, the files this call created are removed again (a file
    it replaced under ``overwrite`` stays replaced). Devices and FIFOs are written into last.

    **Returns:** the list of paths written.
    """
    items = [(check_writable(path, overwrite=overwrite, hint=hint), _encode(data))
             for path, data in items]
    seen = {}
    for p, _ in items:
        key = os.path.realpath(p)
        if key in seen and not _is_special(p):
            raise ValueError(f"{str(seen[key])!r} and {str(p)!r} name the same file.")
        seen[key] = p
    regular = [(p, d) for p, d in items if not _is_special(p)]
    special = [(p, d) for p, d in items if _is_special(p)]
    temps: list[tuple[pathlib.Path, str, bytes]] = []
    created: list[pathlib.Path] = []
    try:
        for p, data in regular:
            target = _target(p)
            folder = target.parent if str(target.parent) else pathlib.Path(".")
            temps.append((target, _fill_temporary(folder, data, target), data))
        for target, tmp, data in temps:
            existed = os.path.lexists(target)
            _publish(tmp, target, data, overwrite, hint)
            if not existed:
                created.append(target)
    except BaseException:
        for _, tmp, _ in temps:
            if os.path.exists(tmp):
                os.unlink(tmp)
        for target in created:
            if os.path.exists(target):
                os.unlink(target)
        raise
    for p, data in special:
        _write_into(p, data)
    return [p for p, _ in items]


def atomic_write(path, data: str | bytes, *, overwrite: bool = False) -> pathlib.Path:
    """Write ``data`` to ``path`` all at once: a temporary file in the same directory is
    filled, flushed to disk and renamed over ``path``, so an interrupted run never leaves a
    truncated file. An existing ``path`` is kept unless ``overwrite`` is true; devices and
    FIFOs are written into, never replaced (see the module docstring)."""
    return atomic_write_many([(path, data)], overwrite=overwrite)[0]
