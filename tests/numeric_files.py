"""Compare CSV and JSON files written on different machines: the same numbers, not the same bytes.

Why not bytes: OpenBLAS picks its kernels per CPU (``OPENBLAS_CORETYPE=Haswell|SkylakeX|Sandybridge``
reproduce the choice), which changes the summation order inside dot products and factorizations, so
the last bits of anything computed through numpy/scipy linear algebra (the Eq. (2) reflector search,
an identification) differ from one CPU to another. Same machine, same run: compare bytes (the tests
do). Across machines -- a file committed to the repository against one written now -- use this.

Rules, field by field: comment lines, headers, strings, booleans and integers exactly; the number of
rows, columns, list items and the keys exactly; NaN equals NaN; a float (or an integer against a
float) within ``|a - b| <= ABS_TOL + REL_TOL * max(|a|, |b|)``, or within one unit of the finer last
decimal place printed (a value written with fixed decimals may round to the neighbouring digit when
the two unrounded values straddle a rounding boundary; a writer that strips trailing zeros prints
the other one shorter, hence the finer place).
"""

from __future__ import annotations

import json
import math
import re
from decimal import Decimal
from pathlib import Path

# A kernel change perturbs a result by ~1e-16 relative; the solves here amplify that by their
# condition numbers (tens to thousands), i.e. to <= 1e-12. Measured on the shipped paper campaign
# under OPENBLAS_CORETYPE=SkylakeX, Sandybridge, Haswell: truth.json's Eq. (2) search estimates
# differ by <= 2e-13 mm (a few ulp), campaign.csv not at all. 1e-9 (mm, deg: nanometres) keeps a
# margin of 1000 and is still 10 000 times below the interferometer's resolution (lambda/64 ~ 1e-5 mm):
# anything a calibration could notice is caught.
REL_TOL = 1e-9
ABS_TOL = 1e-9

_INT = re.compile(r"^[+-]?\d+$")


def _last_place(token):
    """10**exponent of the last printed digit of a decimal token (0 if it is not a plain decimal)."""
    try:
        exp = Decimal(token).as_tuple().exponent
    except ArithmeticError:
        return 0.0
    return 10.0 ** exp if isinstance(exp, int) else 0.0


def _float_difference(a, b, place=0.0, rel_tol=REL_TOL, abs_tol=ABS_TOL):
    """None if floats a and b agree within the tolerance (or one printed place), else a description."""
    if math.isnan(a) or math.isnan(b):
        return None if math.isnan(a) and math.isnan(b) else "NaN against a number"
    if math.isinf(a) or math.isinf(b):
        return None if a == b else "infinity against another value"
    allowed = max(abs_tol + rel_tol * max(abs(a), abs(b)), place * (1 + 1e-9))
    diff = abs(a - b)
    return None if diff <= allowed else f"differ by {diff:.3g} > allowed {allowed:.3g}"


def _token_difference(ta, tb, **tol):
    """Compare two CSV fields: integers and text exactly, decimals within the tolerance."""
    ta, tb = ta.strip(), tb.strip()
    if ta == tb:
        return None
    if _INT.match(ta) and _INT.match(tb):
        return "integers differ"
    try:
        a, b = float(ta), float(tb)
    except ValueError:
        return "text differs"
    return _float_difference(a, b, min(_last_place(ta), _last_place(tb)), **tol)


def csv_differences(path_a, path_b, **tol):
    """["FILE:LINE: ..."] where two CSV files differ under the rules above (empty: the same numbers)."""
    la = Path(path_a).read_text(encoding="utf-8").splitlines()
    lb = Path(path_b).read_text(encoding="utf-8").splitlines()
    out = []
    if len(la) != len(lb):
        out.append(f"{path_a}: {len(la)} lines against {len(lb)} in {path_b}")
    header = None
    for n, (a, b) in enumerate(zip(la, lb), 1):
        if a.startswith("#") or b.startswith("#") or header is None:
            if a != b:
                out.append(f"{path_a}:{n}: {a!r} against {b!r}")
            if not a.startswith("#"):
                header = a.split(",")
            continue
        fa, fb = a.split(","), b.split(",")
        if len(fa) != len(fb):
            out.append(f"{path_a}:{n}: {len(fa)} fields against {len(fb)}")
            continue
        for col, ta, tb in zip(header + [""] * len(fa), fa, fb):
            why = _token_difference(ta, tb, **tol)
            if why:
                out.append(f"{path_a}:{n}: column '{col}': {ta} against {tb}: {why}")
    return out


def json_differences(a, b, where="", **tol):
    """["KEY PATH: ..."] where two parsed JSON values differ under the rules above."""
    if isinstance(a, dict) and isinstance(b, dict):
        if list(a) != list(b):
            return [f"{where or '/'}: keys {sorted(set(a) ^ set(b)) or 'in another order'}"]
        return [d for k in a for d in json_differences(a[k], b[k], f"{where}/{k}", **tol)]
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{where}: {len(a)} items against {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in json_differences(x, y, f"{where}[{i}]", **tol)]
    numbers = (int, float)
    if (isinstance(a, numbers) and isinstance(b, numbers) and not isinstance(a, bool) and not isinstance(b, bool)
            and (isinstance(a, float) or isinstance(b, float))):
        why = _float_difference(float(a), float(b), **tol)
        return [f"{where}: {a!r} against {b!r}: {why}"] if why else []
    if type(a) is not type(b) or a != b:
        return [f"{where}: {a!r} against {b!r}"]
    return []


def file_differences(path_a, path_b, **tol):
    """Differences of two .csv or .json files (dispatch by suffix)."""
    if str(path_a).endswith(".json"):
        load = lambda p: json.loads(Path(p).read_text(encoding="utf-8"))  # noqa: E731
        return [f"{path_a}: {d}" for d in json_differences(load(path_a), load(path_b), **tol)]
    if str(path_a).endswith(".csv"):
        return csv_differences(path_a, path_b, **tol)
    raise ValueError(f"{path_a}: not a .csv or .json file")


def assert_same_numbers(path_a, path_b, **tol):
    """Fail listing (the first 10) differences of two CSV/JSON files, if any."""
    diffs = file_differences(path_a, path_b, **tol)
    assert not diffs, f"{len(diffs)} differences:\n" + "\n".join(diffs[:10])
