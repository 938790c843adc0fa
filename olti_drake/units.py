"""Physical bounds of the values the tool reads, by the unit suffix of a column, key or parameter name.

A commanded angle beyond two turns either way (+-720 deg) or a length, coordinate or displacement beyond
+-100 m (1e5 mm) is not a measurement of a robot or a machine tool but a unit or typing slip; it is refused
where it is read, naming the file, line and column, before it reaches a solver (where it would end as
"not identifiable" or "SVD did not converge"). One table for CSV columns, JSON keys, the plan generator
and the CLI's lengths. At the package top (open to every layer); it imports nothing of the package.
"""

import math

#: Largest plausible magnitude by unit suffix: deg, mm.
UNIT_BOUNDS = {"_deg": 720.0, "_mm": 1e5}


def unit_bound(column: str) -> float:
    """The largest plausible magnitude of a value by its column's unit suffix (deg or mm; inf without one)."""
    for suffix, bound in UNIT_BOUNDS.items():
        if column.endswith(suffix):
            return bound
    return math.inf
