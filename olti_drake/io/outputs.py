"""Every file a verb writes goes through here: checked before the work, written atomically.

One rule for all verbs (README, "never overwrite"):

- **Measurements are never replaced** -- a campaign (``campaign.csv``, or any
  CSV with a ``displacement_mm`` column), its ``truth.json``, a run log
  (``events.jsonl``, ``run.json``) -- by any verb, ``--force`` or not.
- **Inputs are never replaced**: an output that is the same file as an input
  (``os.path.samefile``: symbolic and hard links included) is refused.
- **Results** (result/uncertainty/design JSON, predictions, commands, tables,
  figures, reports, diagrams) replace an existing file only with ``--force``.

:func:`preflight` checks all of that, and that every output can be created
(its directory exists or can be made, is a directory, is writable; the path
is not a directory), *before* any long work, raising one-line
:class:`OutputError`. :func:`writing` / :func:`write_text` then write to a
temporary file in the same directory and rename it into place, so a failed
write never leaves half a file nor destroys the old one; an ``OSError`` while
writing becomes one :class:`OutputError` line naming the path and the cause.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from typing import Iterable, Sequence

from olti_drake.errors import InputError

#: File names that hold measured data (a campaign and its log), whatever the verb.
MEASUREMENT_NAMES = ("campaign.csv", "truth.json", "events.jsonl", "run.json")


class OutputError(InputError):
    """An output that must not or cannot be written; one line naming the path."""


def is_measurement(path) -> bool:
    """Whether an existing ``path`` holds measured data (by name, or a CSV with readings)."""
    name = os.fspath(path)
    if os.path.basename(name) in MEASUREMENT_NAMES:
        return True
    if not name.lower().endswith(".csv") or not os.path.isfile(name):
        return False
    try:
        with open(name, encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.strip() and not line.lstrip().startswith("#"):
                    return "displacement_mm" in [c.strip() for c in line.split(",")]
    except OSError:
        return False
    return False


def _same_file(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _first_existing(path: str) -> str:
    """``path`` or its nearest existing ancestor."""
    p = os.path.abspath(path)
    while not os.path.exists(p):
        p = os.path.dirname(p)
    return p


def check_directory(out_dir, create: bool = True, for_file: str = "") -> None:
    """``out_dir`` is (or, with ``create``, can be made as) a writable directory; ``for_file``: the
    output whose directory it is (named first in the message)."""
    d = os.fspath(out_dir) or "."
    who = f"{for_file}: " if for_file else ""
    if os.path.exists(d):
        if not os.path.isdir(d):
            raise OutputError(f"{who}{d} is a file, not a directory")
        if not os.access(d, os.W_OK | os.X_OK):
            raise OutputError(f"{who}directory {d} is not writable")
        return
    if not create:
        raise OutputError(f"{who}directory {d} does not exist")
    base = _first_existing(d)
    if not os.path.isdir(base):
        raise OutputError(f"{who}cannot create directory {d}: {base} is a file")
    if not os.access(base, os.W_OK | os.X_OK):
        raise OutputError(f"{who}cannot create directory {d}: {base} is not writable")


def preflight(files: Sequence, inputs: Iterable = (), force: bool = False, measurements: Sequence = (),
              dirs: Sequence = (), create_dirs: bool = False) -> None:
    """Check every output before any work; raise one-line :class:`OutputError`.

    ``files``: result files (replaced only with ``force``); ``measurements``:
    measured-data files (never replaced); ``inputs``: files that must not be
    written (None entries ignored); ``dirs``: output directories, made on
    writing when ``create_dirs`` (else each file's directory must exist).
    """
    for d in dirs:
        check_directory(d, create=create_dirs)
    ins = [os.fspath(p) for p in inputs if p]
    seen = {}
    for path, measured in [(os.fspath(p), False) for p in files if p] + \
                          [(os.fspath(p), True) for p in measurements if p]:
        key = os.path.abspath(path)
        if key in seen:
            raise OutputError(f"{path}: named twice as an output ({seen[key]} and {path})")
        seen[key] = path
        parent = os.path.dirname(path)
        if not any(os.path.abspath(os.fspath(d)) == os.path.dirname(key) for d in dirs):
            check_directory(parent, create=False, for_file=path)
        if os.path.isdir(path):
            raise OutputError(f"{path}: is a directory, expected a file name")
        if not os.path.lexists(path):
            continue
        for i in ins:
            if _same_file(path, i):
                raise OutputError(f"{path}: output would overwrite an input file ({i})")
        _check_regular(path)
        if measured or is_measurement(path):
            raise OutputError(f"{path} exists and holds measured data, which olti never replaces "
                              f"(not even with --force); choose another --out")
        if not force:
            raise OutputError(f"{path} exists; pass --force to replace it (or choose another --out)")


def _check_regular(path: str) -> None:
    """An existing output must be a regular file: a device (``/dev/null``), a FIFO, a socket or a symbolic link
    is never replaced by the rename, not even with ``--force`` (as root, ``--out /dev/null --force`` would
    otherwise replace the machine's device node with a file)."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if stat.S_ISREG(mode):
        return
    what = ("a symbolic link" if stat.S_ISLNK(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a FIFO" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
    raise OutputError(f"{path}: exists and is {what}, not a regular file; olti replaces only regular files (not "
                      f"even with --force): choose another --out")


@contextlib.contextmanager
def writing(path, mode: str = "w", measurement: bool = False, fsync: bool = False, **open_kw):
    """Open a temporary file next to ``path``; on success move it to ``path`` (atomic).

    ``measurement``: never replace an existing file (the rename refuses it).
    Yields the open file (``mode`` as :func:`open`); with ``mode=None`` yields
    the temporary *path* for a library that writes files itself (matplotlib).
    """
    name = os.fspath(path)
    d = os.path.dirname(os.path.abspath(name))
    if "b" not in (mode or "b"):
        open_kw.setdefault("encoding", "utf-8")
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(dir=d, prefix=f".{os.path.basename(name)}.", suffix=".tmp")
        if mode is None:
            os.close(fd)
            yield tmp
        else:
            with os.fdopen(fd, mode, **open_kw) as f:
                yield f
                f.flush()
                if fsync:
                    os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        _check_regular(name)  # (again at the rename: it may have appeared since the preflight)
        if measurement:
            _link_new(tmp, name)
        else:
            os.replace(tmp, name)
        tmp = None
    except FileExistsError:
        raise OutputError(f"{name} exists and holds measured data, which olti never replaces") from None
    except OSError as e:
        raise OutputError(f"{name}: cannot write ({e.strerror or e})") from None
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def _link_new(tmp: str, name: str) -> None:
    """Move ``tmp`` to ``name`` only if ``name`` does not exist (a hard link fails if it does)."""
    try:
        os.link(tmp, name)
    except FileExistsError:
        raise
    except OSError:                   # a file system without hard links: check, then rename
        if os.path.lexists(name):
            raise FileExistsError(name) from None
        os.replace(tmp, name)
        return
    os.unlink(tmp)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text(path, text: str, measurement: bool = False) -> str:
    """Write ``text`` to ``path`` atomically (:func:`writing`); returns the path."""
    with writing(path, measurement=measurement, newline="") as f:
        f.write(text)
    return os.fspath(path)


def write_json(path, obj, measurement: bool = False) -> str:
    """``obj`` as indented JSON (one space) with a final newline, atomically."""
    import json

    return write_text(path, json.dumps(obj, indent=1) + "\n", measurement=measurement)


def save_figure(fig, path, dpi: int = 120, **kw) -> str:
    """A matplotlib figure as PNG at exactly ``path`` (no extension added), atomically."""
    with writing(path, mode=None) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png", **kw)
    return os.fspath(path)


def make_dir(out_dir) -> str:
    """Create an output directory (and parents); one line on failure."""
    d = os.fspath(out_dir)
    try:
        os.makedirs(d, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{d}: cannot create the directory ({e.strerror or e})") from None
    return d
