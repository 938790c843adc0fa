"""A seeded error truth of a five-axis machine outside the model family of :mod:`olti_drake.model.five_axis_errors`
(issue 25, item 4): location errors of 10–50 µm and 20–100 µrad, smooth harmonic error motions of the rotary axes
with a backlash term (reverse ≠ forward), and the linear axes' sine motions of
:func:`olti_drake.model.volumetric3d.synthetic_truth`. Units: mm, deg (commands), µrad.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Tuple

import numpy as np

from olti_drake.model.five_axis import FiveAxisMachine
from olti_drake.model.five_axis_errors import (COMPONENTS, evaluate_loop, gauge_patterns, linear_config,
                                               location_names, radial)
from olti_drake.model.volumetric3d import synthetic_truth as linear_truth

@dataclass
class FiveAxisTruth:
    """A continuous error truth of a five-axis machine, not in the model family (smooth harmonics, not
    piecewise linear; a backlash term: reverse ≠ forward).

    ``location[name]``: location errors by ISO name (mm, µrad; :func:`location_names`); ``harmonics[(L, c)]``:
    (amplitudes, periods deg, phases rad) of rotary axis L's error motion E_cL (mm or µrad), made gauge-conform
    (:meth:`motion_values`); ``backlash[(L, c)]``: (b, b') — forward minus reverse = b + b'·q (unit, unit/deg);
    ``linear``: the linear axes' motions (:class:`~olti_drake.model.volumetric3d.SineMotions`) or None;
    ``tool_offsets_mm`` (n_tools, 3) the true tool points in the tool frame."""

    machine: FiveAxisMachine
    location: Dict[str, float]
    harmonics: Dict[Tuple[str, str], Tuple[np.ndarray, np.ndarray, np.ndarray]]
    backlash: Dict[Tuple[str, str], Tuple[float, float]]
    linear: object = None
    tool_offsets_mm: np.ndarray = field(default_factory=lambda: np.zeros((1, 3)))

    def _raw(self, L, q) -> np.ndarray:
        out = np.zeros((len(q), 6))
        for r, c in enumerate(COMPONENTS):
            a, period, phase = self.harmonics.get((L, c), (np.zeros(0),) * 3)
            out[:, r] = (np.sin(2 * np.pi * np.multiply.outer(q, 1.0 / np.asarray(period)) + phase) * a).sum(-1)
        return out

    def _gauge_basis(self, L, q) -> np.ndarray:
        """(len(q)·6, 10) the model's gauge patterns (:func:`gauge_patterns`), rows component-fastest."""
        P = gauge_patterns(self.machine, L, q)
        return P.reshape(-1, P.shape[-1])

    def motion_values(self, L, q, direction) -> np.ndarray:
        """(M, 6) E_XL … E_CL (mm, µrad) at commands q (deg) approached in ``direction`` (±1): the harmonics less
        their least-squares part on the gauge patterns over the travel (so the truth obeys the model's gauge up to
        the grid's discretization), plus direction·(b + b' q)/2."""
        k = self.machine.axes.index(L)
        lo, hi = (v if np.isfinite(v) else s for v, s in zip((self.machine.lower[k], self.machine.upper[k]),
                                                              (-180.0, 180.0)))  # (a continuous joint: one turn)
        cache = self.__dict__.setdefault("_gauge_coef", {})  # the fit over the travel depends on L only: once
        if L not in cache:
            dense = np.linspace(lo, hi, 721)
            cache[L] = np.linalg.lstsq(self._gauge_basis(L, dense), self._raw(L, dense).ravel(), rcond=None)[0]
        coef = cache[L]
        q = np.asarray(q, float)
        out = self._raw(L, q) - (self._gauge_basis(L, q) @ coef).reshape(len(q), 6)
        d = np.broadcast_to(np.asarray(direction, float), q.shape)
        for r, c in enumerate(COMPONENTS):
            b, slope = self.backlash.get((L, c), (0.0, 0.0))
            out[:, r] += d * 0.5 * (b + slope * q)
        return out

    def errors(self, L, q, direction) -> np.ndarray:
        """(M, 6) location + error motions of rotary axis L (the ``rotary_errors`` of :func:`evaluate_loop`)."""
        loc = np.zeros(6)
        for name, value in self.location.items():
            if name[4] == L:
                loc[COMPONENTS.index(name[2])] = value
        return loc + self.motion_values(L, q, direction)

    def truth_positions(self, commands, directions=None, tool=None, frame: str = "workpiece") -> np.ndarray:
        """The true tool points (M, 3) mm of commands (M, n_axes) (mm, deg) with the approach directions (M,
        n_rotary) ±1 (default +1) and tool indices, in ``frame``."""
        c = self.machine.check_commands(commands)
        d = np.ones((len(c), len(self.machine.rotary))) if directions is None else np.asarray(directions, float)
        t = np.asarray(self.tool_offsets_mm, float)[np.zeros(len(c), int) if tool is None else np.asarray(tool)]
        return evaluate_loop(self.machine, c, lambda L, q: self.errors(L, q, d[:, self.machine.rotary.index(L)]),
                             self.linear, t, frame)[0]


def synthetic_truth(machine: FiveAxisMachine, seed: int, location: bool = True, motions: bool = True,
                    backlash: bool = True, linear: bool = False, tool_offsets_mm=((0.0, 0.0, 0.0),)) -> FiveAxisTruth:
    """A seeded :class:`FiveAxisTruth`: location errors of 10–50 µm and 20–100 µrad (random signs); per rotary
    axis and component two or three sines of periods between 1/5 and 1/1.3 of the travel (radial/axial up to
    4 µm, tilt up to 15 µrad, angular positioning up to 40 µrad); backlash 5–20 µrad on the angular positioning
    and 0.5–2 µm on the radial motions, varying linearly over the travel. An axis turning a full turn is
    continuous where -180 and +180 deg meet, as a real one: 2-5 whole cycles per turn, a constant backlash; the linear axes' motions of
    :func:`olti_drake.model.volumetric3d.synthetic_truth` when ``linear``."""
    rng = np.random.default_rng(seed)
    loc, harm, lash = {}, {}, {}
    for L in machine.rotary:
        k = machine.axes.index(L)
        span = float(np.clip(machine.upper[k] - machine.lower[k], 1.0, 360.0))
        for name in location_names(L) if location else ():
            lo, hi = (0.010, 0.050) if name.endswith("_mm") else (20.0, 100.0)
            loc[name] = float(rng.choice([-1.0, 1.0]) * rng.uniform(lo, hi))
        for c in COMPONENTS if motions else ():
            amp = {"X": 0.004, "Y": 0.004, "Z": 0.003, "A": 15.0, "B": 15.0, "C": 40.0}[c]
            n = int(rng.integers(2, 4))
            cycles = rng.uniform(1.3, 5.0, n)
            if span >= 360.0:  # (a full turn: -180 and +180 deg are one angle, a whole number of cycles per turn)
                cycles = np.maximum(2.0, np.round(cycles))
            harm[(L, c)] = (amp * rng.uniform(0.3, 1.0, n), span / cycles, rng.uniform(0, 2 * np.pi, n))
            if backlash and c in (L,) + radial(L):
                b = rng.uniform(5.0, 20.0) if c == L else rng.uniform(0.0005, 0.002)
                slope = 0.1 * b / span * rng.uniform(-1, 1) if span < 360.0 else 0.0  # (rng drawn either way)
                lash[(L, c)] = (float(b), float(slope))
    lin = linear_truth(linear_config(machine), seed + 1) if linear else None
    return FiveAxisTruth(machine, loc, harm, lash, lin, np.asarray(tool_offsets_mm, float).reshape(-1, 3))


