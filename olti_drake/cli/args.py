"""Checked numeric command-line options: argparse ``type=`` factories.

Every numeric option of ``olti`` is parsed by one of these, so a value that cannot be right
(``--huber-k 0``, ``--outlier-threshold nan``, ``--meshcat-port 70000``, ``--error-scale -1``) is
refused while the command line is parsed, before any file is read or written, with one line that
argparse prefixes with the option's name (``argument --huber-k: must be > 0, got '0'``). Units are
those of the option (mm, degrees). Only the standard library is imported: ``olti --help`` stays fast.
"""

import argparse
import math

#: Largest plausible magnitude of a length given on the command line, mm (+-100 m, as units.UNIT_BOUNDS).
MAX_MM = 1e5


def real(lo=None, hi=None, lo_open=False, hi_open=False):
    """A finite float in [lo, hi] (``lo_open``/``hi_open``: that end excluded; None: unbounded)."""
    want = _range_text(lo, hi, lo_open, hi_open)

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number {want}, got {text!r}") from None
        if not math.isfinite(v) or not _inside(v, lo, hi, lo_open, hi_open):
            raise argparse.ArgumentTypeError(f"must be a finite number {want}, got {text!r}")
        return v

    parse.__name__ = "number"
    return parse


def smoothing(text: str):
    """``--smoothing``: ``auto``, ``off`` or a weight >= 0 (the roughness prior's, estimation.smoothing)."""
    if text in ("auto", "off"):
        return text
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected auto, off or a weight >= 0, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"must be auto, off or a finite weight >= 0, got {text!r}")
    return v


smoothing.__name__ = "smoothing"


def integer(lo=None, hi=None):
    """A whole number in [lo, hi] (None: unbounded)."""
    want = _range_text(lo, hi, False, False)

    def parse(text: str) -> int:
        try:
            v = int(text, 10)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number {want}, got {text!r}") from None
        if not _inside(v, lo, hi, False, False):
            raise argparse.ArgumentTypeError(f"must be a whole number {want}, got {text!r}")
        return v

    parse.__name__ = "integer"
    return parse


def pairs_mm(size: int, positive: bool = False):
    """``x,y;x,y;...`` (size 2 per group) or ``a,b`` in mm -> list of lists; finite, within +-MAX_MM,
    and > 0 if ``positive`` (link lengths)."""
    form = "x,y;x,y;..." if size == 2 else ",".join("v" * size)

    def parse(text: str):
        try:
            rows = [[float(v) for v in part.split(",")] for part in text.replace(";", " ").split()]
        except ValueError:
            rows = []
        if not rows or any(len(r) != size for r in rows):
            raise argparse.ArgumentTypeError(f"expected {form} in mm, got {text!r}")
        for v in (v for r in rows for v in r):
            if not (math.isfinite(v) and abs(v) <= MAX_MM) or (positive and v <= 0):
                raise argparse.ArgumentTypeError(f"{v:g} is not a plausible length (finite, "
                                                 f"{'> 0 and ' if positive else ''}within +-{MAX_MM:g} mm)")
        return rows

    parse.__name__ = "mm values"
    return parse


def points_mm():
    """``x,y;x,y;...`` or ``x,y,z;x,y,z;...`` in mm (2D or 3D points, all of one width) -> list of lists,
    checked as :func:`pairs_mm`; the caller checks the width against its campaign."""
    two, three = pairs_mm(2), pairs_mm(3)

    def parse(text: str):
        try:
            return two(text)
        except argparse.ArgumentTypeError:
            try:
                return three(text)
            except argparse.ArgumentTypeError as e:
                if "plausible" in str(e):
                    raise
                raise argparse.ArgumentTypeError(f"expected x,y;x,y;... or x,y,z;x,y,z;... in mm, "
                                                 f"got {text!r}") from None

    parse.__name__ = "mm points"
    return parse


def _inside(v, lo, hi, lo_open, hi_open) -> bool:
    above = lo is None or (v > lo if lo_open else v >= lo)
    below = hi is None or (v < hi if hi_open else v <= hi)
    return above and below


def _range_text(lo, hi, lo_open, hi_open) -> str:
    def num(v):
        return str(v) if isinstance(v, int) else f"{v:g}"

    if lo is not None and hi is not None:
        return f"in {'(' if lo_open else '['}{num(lo)}, {num(hi)}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {num(lo)}"
    if hi is not None:
        return f"{'<' if hi_open else '<='} {num(hi)}"
    return ""


positive = real(0, lo_open=True)
nonnegative = real(0)
probability = real(0, 1, lo_open=True, hi_open=True)
seed = integer(0, 2 ** 32 - 1)   # numpy and Drake seeds; larger ones would be silently reduced
count = integer(1)
port = integer(1, 65535)
coverage_factor = real(0, 10, lo_open=True)       # k of an expanded uncertainty (in use: 1..3)
workers = integer(1, 256)                            # worker processes
length_mm = real(0, MAX_MM, lo_open=True)            # a positive length or step, mm
distance_mm = real(0, MAX_MM)                        # a clearance or separation, mm (0: off)


def tolerances(text: str) -> dict:
    """``--tolerance NAME=VALUE[,NAME=VALUE]``: ISO 9283 tolerances (mm for AP_P, RP_l; deg for AP_abc, RP_abc)."""
    out = {}
    for item in text.split(","):
        name, sep, value = item.partition("=")
        try:
            v = float(value)
        except ValueError:
            v = float("nan")
        if not sep or not name.strip() or not (v > 0 and v < float("inf")):
            raise argparse.ArgumentTypeError(f"{item!r}: NAME=VALUE with a value > 0 (e.g. AP_P=0.1,RP_l=0.05)")
        out[name.strip()] = v
    return out
