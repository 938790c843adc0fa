"""Uncertainty budgets (000 Table 2, 001 Table 4): the reading-error model.

A budget lists contributors; each says its value and unit, the coverage factor
k with which that value is stated (the papers use k = 1 and k = 2), its type
(A/B), and **what it acts on**:

* ``reading`` -- added to the interferometer reading along the beam (length);
* ``pose`` -- a random displacement of the laser head in the XY plane,
  isotropic, so its projection on the beam has this standard deviation
  (robot repeatability, radial error motions: 000 Table 2 u14, u21-u23);
* ``beam_direction`` -- an error of the beam orientation (angle), which only
  gives the cosine error (000 Table 2 u31, u32).

Standard uncertainties come out in mm (lengths) or rad (angles). :class:`ReadingErrors` turns a budget
into per-reading error distributions (the input of the linear propagation and the Monte Carlo). Budget
files (YAML, the same schema) are read by :mod:`olti_drake.io.budget`.

A budget that cannot be right is refused where it is loaded (:func:`olti_drake.io.budget.load_budget`) and
before it is propagated (:class:`ReadingErrors`), by :meth:`Budget.validate`: it needs at
least one contributor and one that is not zero (else every uncertainty would be 0 and a design would
divide by it); every value must be finite, >= 0 and physically plausible -- a standard uncertainty
(value/k) of at most :data:`MAX_LENGTH_MM` = 1000 mm (1 m) for a length and :data:`MAX_ANGLE_RAD` =
10 deg for a beam direction (beyond, the small-error models of 000 Eq. 5 and the cosine error no longer
hold, and squares overflow) -- with a coverage factor 0 < k <= :data:`MAX_K` = 10; unknown units,
``acts_on``, distributions and types are refused. Errors are one line naming the file (or budget) and
the contributor.
"""

from dataclasses import dataclass, field
from typing import List

import numpy as np

from olti_drake.errors import InputError

LENGTH_UNITS_MM = {"nm": 1e-6, "um": 1e-3, "µm": 1e-3, "mm": 1.0, "m": 1e3}
ANGLE_UNITS_RAD = {"rad": 1.0, "mrad": 1e-3, "urad": 1e-6, "µrad": 1e-6,
                   "deg": np.pi / 180, "mdeg": np.pi / 180e3}
ACTS_ON = {"reading": LENGTH_UNITS_MM, "pose": LENGTH_UNITS_MM, "beam_direction": ANGLE_UNITS_RAD}
MAX_LENGTH_MM = 1000.0          # a length contributor (standard uncertainty) above 1 m is absurd
MAX_ANGLE_RAD = np.radians(10)  # a beam-direction contributor above 10 deg is absurd
MAX_K = 10.0                    # coverage factors in use are 1..3


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

    def validate(self, where: str = "") -> "Budget":
        """Refuse a budget that cannot be right (module docstring); ``where`` names the file. Returns self."""
        where = where or f"budget {self.name!r}"
        if not self.contributors:
            raise InputError(f"{where}: no contributors (a budget needs at least one uncertainty contributor)")
        for i, c in enumerate(self.contributors):
            _check_contributor(c, f"{where}: contributors[{i}] ({c.symbol or c.name or '?'})")
        if all(c.value == 0 for c in self.contributors):
            raise InputError(f"{where}: every contributor is 0 (the budget would give zero uncertainty)")
        return self


#: What a contributor in a file must state: its defaults (um, k = 1, reading) would silently give a value another
#: meaning -- a contributor in nm, stated at k = 2 or acting on the pose would be read 1000 x, 2 x or on the
#: wrong term.
STATED_KEYS = {"unit": "the unit of its value", "k": "the coverage factor its value is stated with",
               "acts_on": "what it acts on: reading, pose or beam_direction"}


def check_stated(contributors, where: str) -> None:
    """Refuse (one line naming the contributor and the key) a contributor of a budget file, as read (a list of
    mappings), that leaves a key of :data:`STATED_KEYS` to its default."""
    for i, c in enumerate(contributors or []):
        if not isinstance(c, dict):
            continue
        missing = [key for key in STATED_KEYS if key not in c]
        if missing:
            raise InputError(f"{where}: contributors[{i}] ({c.get('symbol') or c.get('name') or '?'}): no "
                             f"'{missing[0]}' given ({STATED_KEYS[missing[0]]}; not assumed)")


def _check_contributor(c: Contributor, label: str) -> None:
    if c.acts_on not in ACTS_ON:
        raise InputError(f"{label}: acts_on must be one of {', '.join(ACTS_ON)}, got {c.acts_on!r}")
    if c.unit not in ACTS_ON[c.acts_on]:
        raise InputError(f"{label}: unit {c.unit!r} does not fit acts_on {c.acts_on!r} "
                         f"(use one of {', '.join(ACTS_ON[c.acts_on])})")
    if not (isinstance(c.value, (int, float)) and np.isfinite(c.value) and c.value >= 0):
        raise InputError(f"{label}: value must be finite and >= 0, got {c.value!r}")
    if not (isinstance(c.k, (int, float)) and np.isfinite(c.k) and 0 < c.k <= MAX_K):
        raise InputError(f"{label}: k must be > 0 and <= {MAX_K:g}, got {c.k!r}")
    if c.distribution not in ("normal", "uniform"):
        raise InputError(f"{label}: distribution must be 'normal' or 'uniform', got {c.distribution!r}")
    if c.type not in ("A", "B"):
        raise InputError(f"{label}: type must be 'A' or 'B', got {c.type!r}")
    is_angle = c.acts_on == "beam_direction"
    limit = MAX_ANGLE_RAD if is_angle else MAX_LENGTH_MM
    if c.standard() > limit:
        bound = f"{np.degrees(limit):g} deg" if is_angle else f"{limit / 1e3:g} m"
        raise InputError(f"{label}: value {c.value:g} {c.unit} (k = {c.k:g}) is a standard uncertainty above "
                         f"{bound}, not physically plausible for {c.acts_on} (a unit slip?)")


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


def paper001_budget() -> Budget:
    """001 Table 4 (k = 2): laser displacement at Pos A, target (X, Y) = (100, 100) mm (001 §4.3).

    The content of the shipped ``data/budget_paper001.yaml`` (a test holds them equal); the default
    budget of the simulated machine campaigns. Units as stated: µm and rad.
    """
    c = Contributor
    return Budget(
        name="paper 001 Table 4",
        source="Ibaraki, Sato & Takeuchi, open-loop tracking interferometer for machine tool volumetric error "
               "measurement (2D), Table 4 (k = 2)",
        contributors=[
            c("u11", "Wavelength accuracy", 0.02, "um", 2.0, "B", "reading"),
            c("u12", "Resolution of interferometer", 0.006, "um", 2.0, "B", "reading", "uniform"),
            c("u13", "Wavelength correction", 0.07, "um", 2.0, "B", "reading"),
            c("u14", "Dead path accuracy", 0.12, "um", 2.0, "B", "reading"),
            c("u15", "Environmental change", 0.04, "um", 2.0, "A", "reading"),
            c("u16", "Machine's repeatability", 0.18, "um", 2.0, "A", "reading"),
            c("u21", "Radial error motion of rotary axis", 2.2, "um", 2.0, "A", "pose"),
            c("u41", "Uncertainty in C-axis zero angular position", 2.8e-6, "rad", 2.0, "A", "beam_direction"),
            c("u42", "Angular positioning error of C-axis", 22.0e-6, "rad", 2.0, "A", "beam_direction"),
            c("u43", "Uncertainty in C-axis center position", 35.2e-6, "rad", 2.0, "A", "beam_direction"),
            c("u44", "Uncertainty due to machine tool positioning error", 60.6e-6, "rad", 2.0, "A",
              "beam_direction"),
        ])


@dataclass
class ReadingErrors:
    """The budget as per-reading error distributions (lengths mm, angles rad): the input of the linear
    propagation and the Monte Carlo (:mod:`olti_drake.estimation.uncertainty`)."""

    budget: Budget

    def __post_init__(self):  # a constructed budget is checked before it is propagated, as a loaded one is
        self.budget.validate()

    def _terms(self, acts_on):
        return [c for c in self.budget.contributors if c.acts_on == acts_on]

    def std(self, distance_mm) -> np.ndarray:
        """Standard uncertainty of every reading (K,) mm -- the linear method's input.

        The cosine error -D ψ²/2 of ψ ~ N(0, u_ψ²) has standard deviation D u_ψ²/√2.
        """
        D = np.asarray(distance_mm, dtype=float)
        u_psi = self.budget.combined("beam_direction")
        return np.sqrt(self.budget.combined("reading") ** 2 + self.budget.combined("pose") ** 2
                       + (D * u_psi ** 2) ** 2 / 2)

    def draw(self, rng: np.random.Generator, distance_mm, trials: int) -> np.ndarray:
        """(trials, K) reading errors, mm: every contributor drawn independently (JCGM 101)."""
        D = np.asarray(distance_mm, dtype=float)
        shape = (trials, D.size)
        err = np.zeros(shape)
        for c in self._terms("reading") + self._terms("pose"):
            err += _sample(rng, c.standard(), c.distribution, shape)
        psi = np.zeros(shape)
        for c in self._terms("beam_direction"):
            psi += _sample(rng, c.standard(), c.distribution, shape)
        return err - D * psi ** 2 / 2


def _sample(rng, std, distribution, shape):
    if distribution == "uniform":  # rectangular with the same standard deviation
        a = std * np.sqrt(3.0)
        return rng.uniform(-a, a, shape)
    return std * rng.standard_normal(shape)
