"""The one allocation guard: an option or scenario field that sizes an array is refused, in one line, before
any work, when the array would take more than :data:`MAX_ARRAY_BYTES`.

README "Units": "a grid or step that would allocate gigabytes is refused". A grid pitch, a step or a node
count typed a few decades too fine (``--grid-step-deg 0.001``, ``--pitch-mm 0.00001``, a scenario
``grid: [1000, 1000, 1000]``) otherwise ends in a ``MemoryError`` traceback or in the kernel's OOM killer
after the command has taken the whole machine. Every place that turns a user number into an array size
calls :func:`check_allocation` with the option's name, the dimensions and the bytes per element; it raises
:class:`~olti_drake.errors.InputError` naming the option, the value, the size and the limit.

The limit, 2 GiB for one array, is a quarter of an 8 GB laptop: the working sets of the shipped examples
and every documented run stay below 100 MB (a SCARA map of 2001 x 2001 nodes, the largest the SCARA path
takes, is 32 MB of float64), so a request 20x over that is a slip, and a peak of a few such arrays still
fits a small machine. At the package top (open to every layer); it imports only :mod:`olti_drake.errors`.
"""

import math
from typing import Sequence

from olti_drake.errors import InputError

#: Largest single array (bytes) an option or a scenario field may ask for: 2 GiB.
MAX_ARRAY_BYTES = 2 * 1024 ** 3

_GIB = 1024 ** 3


def _fmt_count(x: float) -> str:
    return f"{int(x):,}".replace(",", " ") if x < 1e7 else f"{x:.3g}"


def _fmt_bytes(b: float) -> str:
    if b >= 1024 ** 4:
        return f"{b / 1024 ** 4:.3g} TiB"
    if b >= _GIB:
        return f"{b / _GIB:.3g} GiB"
    return f"{b / 1024 ** 2:.3g} MiB"


def allocation_bytes(dims: Sequence[float], itemsize: int = 8) -> float:
    """Bytes of an array of shape ``dims`` (floats allowed: an estimate before rounding) at ``itemsize``."""
    n = float(itemsize)
    for d in dims:
        n *= max(float(d), 0.0)
    return n


def check_allocation(option: str, value, dims: Sequence[float], itemsize: int = 8, what: str = "elements",
                     hint: str = "use a coarser value", limit: int = MAX_ARRAY_BYTES) -> None:
    """Refuse, in one line, an array of shape ``dims`` x ``itemsize`` bytes sized by ``option`` ``value``.

    ``dims`` may be floats (counts estimated before any array exists) and may be huge (no overflow: the
    product is taken in floating point). A non-finite dimension is refused too.
    """
    nbytes = allocation_bytes(dims, itemsize)
    if math.isfinite(nbytes) and nbytes <= limit:
        return
    shape = " × ".join(_fmt_count(float(d)) for d in dims)
    val = "" if value is None else f" {value}"
    size = _fmt_bytes(nbytes) if math.isfinite(nbytes) else "an unbounded amount"
    raise InputError(f"{option}{val}: would allocate {size} ({shape} {what}, {itemsize} bytes each); "
                     f"at most {_fmt_bytes(limit)} — {hint}")
