"""Uncertainty budgets (000 Table 2; later 001 Table 4) as typed YAML.

A budget lists contributors; each says its value and unit, the coverage factor
k with which that value is stated (the papers use k = 1 and k = 2), its type
(A/B), and **what it acts on**:

* ``reading`` -- added to the interferometer reading along the beam (length);
* ``pose`` -- a random displacement of the laser head in the XY plane,
  isotropic, so its projection on the beam has this standard deviation
  (robot repeatability, radial error motions: 000 Table 2 u14, u21-u23);
* ``beam_direction`` -- an error of the beam orientation (angle), which only
  gives the cosine error (000 Table 2 u31, u32).

Standard uncertainties come out in mm (lengths) or rad (angles).
"""


import os
from dataclasses import dataclass, field
from typing import List

import numpy as np

from .csvio import InputError

LENGTH_UNITS_MM = {"nm": 1e-6, "um": 1e-3, "µm": 1e-3, "mm": 1.0, "m": 1e3}
ANGLE_UNITS_RAD = {"rad": 1.0, "mrad": 1e-3, "urad": 1e-6, "µrad": 1e-6,
                   "deg": np.pi / 180, "mdeg": np.pi / 180e3}
ACTS_ON = {"reading": LENGTH_UNITS_MM, "pose": LENGTH_UNITS_MM, "beam_direction": ANGLE_UNITS_RAD}


@dataclass
class Contributor:
    """One row of an uncertainty budget; ``value`` is an expanded uncertainty with factor ``k``.

    ``distribution`` (``normal`` or ``uniform``) is the shape the Monte Carlo
    draws with the standard uncertainty value/k (JCGM 101 §6.4).
    """

    symbol: str = ""
    name: str = ""
    value: float = 0.0
    unit: str = "um"
    k: float = 1.0
    type: str = "B"
    acts_on: str = "reading"
    distribution: str = "normal"

    def standard(self) -> float:
        """Standard uncertainty (k = 1): mm for lengths, rad for angles."""
        return self.value / self.k * ACTS_ON[self.acts_on][self.unit]


@dataclass
class Budget:
    """A named list of :class:`Contributor`; ``source`` cites the table it mirrors."""

    name: str = ""
    source: str = ""
    contributors: List[Contributor] = field(default_factory=list)

    def combined(self, acts_on: str) -> float:
        """Root-sum-square of the standard uncertainties acting on ``acts_on`` (mm or rad)."""
        return float(np.sqrt(sum(c.standard() ** 2 for c in self.contributors
                                 if c.acts_on == acts_on)))

    def validate(self, where: str = "budget") -> "Budget":
        for i, c in enumerate(self.contributors):
            label = f"{where}: contributors[{i}] ({c.symbol or c.name or '?'})"
            if c.acts_on not in ACTS_ON:
                raise InputError(f"{label}: acts_on must be one of {', '.join(ACTS_ON)}, got {c.acts_on!r}")
            if c.unit not in ACTS_ON[c.acts_on]:
                raise InputError(f"{label}: unit {c.unit!r} does not fit acts_on {c.acts_on!r} "
                                 f"(use one of {', '.join(ACTS_ON[c.acts_on])})")
            if not (np.isfinite(c.value) and c.value >= 0):
                raise InputError(f"{label}: value must be finite and >= 0, got {c.value!r}")
            if not (np.isfinite(c.k) and c.k > 0):
                raise InputError(f"{label}: k must be > 0, got {c.k!r}")
            if c.distribution not in ("normal", "uniform"):
                raise InputError(f"{label}: distribution must be 'normal' or 'uniform', got {c.distribution!r}")
            if c.type not in ("A", "B"):
                raise InputError(f"{label}: type must be 'A' or 'B', got {c.type!r}")
        return self


def paper000_budget() -> Budget:
    """000 Table 2 (k = 1): laser displacement at p* = (100, 100) mm, the paper's reflector P_1 (our P0)."""
    c = Contributor
    return Budget(
        name="paper 000 Table 2",
        source="Ibaraki & Usui, open-loop tracking interferometer for SCARA, Table 2 (k = 1)",
        contributors=[
            c("u11", "Wavelength accuracy", 0.04, "um", 1.0, "B", "reading"),
            c("u12", "Wavelength correction", 0.19, "um", 1.0, "B", "reading"),
            c("u13", "Environmental change", 0.09, "um", 1.0, "B", "reading"),
            c("u14", "Robot's repeatability", 10.0, "um", 1.0, "B", "pose"),
            c("u21", "Radial error motion of J1-axis", 5.0, "um", 1.0, "A", "pose"),
            c("u22", "Radial error motion of J2-axis", 5.0, "um", 1.0, "A", "pose"),
            c("u23", "Radial error motion of J4-axis", 10.0, "um", 1.0, "A", "pose"),
            c("u31", "Laser beam orientation by J1-axis", 7.17e-4, "rad", 1.0, "B", "beam_direction"),
            c("u32", "Laser beam orientation by J2-axis", 7.17e-4, "rad", 1.0, "B", "beam_direction"),
        ])


def load_budget(path) -> Budget:
    """Load a budget YAML file (schema :class:`Budget`); errors name the file and field."""
    from pydrake.common.yaml import yaml_load_typed  # lazy: keeps `olti --help` fast

    name = os.fspath(path)
    if not os.path.exists(name):
        raise InputError(f"{name}: budget file not found")
    try:
        budget = yaml_load_typed(schema=Budget, filename=name, allow_schema_with_no_yaml=True)
    except Exception as e:  # pydrake raises RuntimeError/TypeError with multi-line text
        raise InputError(f"{name}: {str(e).splitlines()[0]}") from None
    return budget.validate(name)
