"""The machine-tool case of paper 001: an XY machine with volumetric errors, measured by an
"open-loop" tracking interferometer on a rotary table set at several positions.

Units: mm (µm in the error fields, as "thousandths of the command unit" of
:class:`~olti_drake.errormap.HarmonicDeviation`, which serves linear axes too).

* :class:`VolumetricError` -- E_XX, E_YY (linear positioning deviations),
  E_YX, E_XY (straightness) as smooth functions of the command, the squareness
  of Y to X; optionally bidirectional through the deviations' backlash terms.
* :func:`simulate_machine_campaign` -- every station position j, every target
  i: the rotary table turns the beam toward the *command* target from the
  *estimated* station (Eq. 1 of 001); the reading is the interferometer model
  of :mod:`olti_drake.interferometer` (cosine error, beam loss, λ/64, budget
  noise: 001 Table 4).
"""

import os
from dataclasses import dataclass, field
from typing import Union

import numpy as np

from .csvio import write_table
from .errormap import Harmonic, HarmonicDeviation, NoDeviation
from .interferometer import InterferometerOptions, simulate_readings

Deviation = Union[HarmonicDeviation, NoDeviation]


# A few µm over 100 mm, like 001 Fig. 10: scale errors of tens of µm/m, pitch harmonics, straightness.
def _exx():
    return HarmonicDeviation(slope_mdeg_per_deg=0.06, harmonics=[Harmonic(3.0, 80.0, 20.0)])  # 60 µm/m + 3 µm


def _eyy():
    return HarmonicDeviation(slope_mdeg_per_deg=-0.04, harmonics=[Harmonic(2.5, 60.0, -50.0)])


def _eyx():
    return HarmonicDeviation(harmonics=[Harmonic(2.0, 150.0, 0.0)])


def _exy():
    return HarmonicDeviation(harmonics=[Harmonic(1.5, 120.0, 90.0)])


@dataclass
class VolumetricError:
    """2D volumetric error of an XY machine (ISO 230-1 names), µm over mm commands.

    Actual = command + (E_XX(x) + E_XY(y) − squareness·y, E_YY(y) + E_YX(x)):
    E_XX, E_YY positioning deviations of X and Y, E_YX straightness of X (a Y
    deviation along X), E_XY straightness of Y, squareness (µrad) of Y to X.
    """

    EXX: Deviation = field(default_factory=_exx)
    EYY: Deviation = field(default_factory=_eyy)
    EYX: Deviation = field(default_factory=_eyx)
    EXY: Deviation = field(default_factory=_exy)
    squareness_urad: float = 8.0

    def actual(self, commands_mm, dir_x=1.0, dir_y=1.0) -> np.ndarray:
        """Actual positions (N, 2) mm of the commands (N, 2) mm approached in (dir_x, dir_y)."""
        c = np.atleast_2d(np.asarray(commands_mm, dtype=float))
        x, y = c[:, 0], c[:, 1]
        dx = self.EXX(x, dir_x) + self.EXY(y, dir_y) - 1e-6 * self.squareness_urad * y
        dy = self.EYY(y, dir_y) + self.EYX(x, dir_x)
        return c + np.column_stack([dx, dy])


def square_targets(size_mm: float = 100.0, step_mm: float = 20.0, origin_mm=(0.0, 0.0), perimeter: bool = True):
    """Command target positions (N_i, 2) mm on a square grid; ``perimeter`` keeps its border only
    (001 §3.2: 20 positions, 20 mm steps, within 100 × 100 mm)."""
    n = int(round(size_mm / step_mm))
    ticks = np.arange(n + 1) * step_mm
    X, Y = np.meshgrid(ticks, ticks)
    keep = np.ones_like(X, dtype=bool)
    if perimeter:
        keep = (X == 0) | (Y == 0) | (X == ticks[-1]) | (Y == ticks[-1])
    return np.column_stack([X[keep], Y[keep]]) + np.asarray(origin_mm, dtype=float)


def paper001_budget():
    """001 Table 4 (k = 2) as a :class:`~olti_drake.budget.Budget` (the shipped YAML's content)."""
    from .budget import load_budget

    return load_budget(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data",
                                    "budget_paper001.yaml"))


@dataclass
class MachineScenario:
    """A simulated 001 campaign: machine error, targets, station positions, estimates, instrument.

    ``station_estimate_sigma_um``: error of the rotation-centre estimate of
    001 §2.2 (11.5 µm at k = 2 in the paper); ``zero_angle_sigma_urad``: of the
    zero-angle alignment (u41). Defaults: the paper's experiment (Fig. 10).
    """

    error: VolumetricError = field(default_factory=VolumetricError)
    size_mm: float = 100.0
    step_mm: float = 20.0
    stations_mm: list[list[float]] = field(default_factory=lambda: [[-120.0, -80.0], [220.0, -60.0], [50.0, 240.0]])
    station_estimate_sigma_um: float = 5.75
    zero_angle_sigma_urad: float = 2.8
    interferometer: InterferometerOptions = field(default_factory=InterferometerOptions)
    seed: int = 0


def simulate_machine_campaign(scenario: MachineScenario, budget=None):
    """Readings of every target from every station (001 §2, §3.2): (columns dict, truth dict).

    Columns follow formats.md (station, target, x_cmd_mm, y_cmd_mm,
    displacement_mm, valid); the counter of station j is zeroed at its first
    target, so its dead path L0_j is that distance.
    """
    rng = np.random.default_rng(scenario.seed)
    budget = budget or paper001_budget()
    cmd = square_targets(scenario.size_mm, scenario.step_mm)
    actual = scenario.error.actual(cmd)
    P = np.asarray(scenario.stations_mm, dtype=float)
    P_est = P + 1e-3 * scenario.station_estimate_sigma_um * rng.standard_normal(P.shape)
    n_i, n_j = len(cmd), len(P)
    i, j = np.tile(np.arange(n_i), n_j), np.repeat(np.arange(n_j), n_i)
    # Eq. (1) of 001: aim from the estimated station at the command position; zero-angle error per station.
    aim = np.degrees(np.arctan2(cmd[i, 1] - P_est[j, 1], cmd[i, 0] - P_est[j, 0]))
    aim += np.degrees(1e-6 * scenario.zero_angle_sigma_urad * rng.standard_normal(n_j))[j]
    L0 = np.hypot(*(actual[0] - P).T)
    reading, valid, miss = simulate_readings(P[j], aim, actual[i], L0[j], scenario.interferometer, budget, rng)
    cols = {"station": j, "target": i, "x_cmd_mm": cmd[i, 0], "y_cmd_mm": cmd[i, 1],
            "displacement_mm": np.where(valid, reading, np.nan), "valid": valid.astype(int)}
    truth = {"format": "olti-multilateration/1", "targets_mm": actual.tolist(), "stations_mm": P.tolist(),
             "dead_paths_mm": L0.tolist(), "commands_mm": cmd.tolist(),
             "gauge": "simulation truth: the machine's command frame", "residual_rms_mm": 0.0,
             "n_readings": int(valid.sum()), "stations_estimate_mm": P_est.tolist(), "seed": scenario.seed}
    return cols, truth


def write_machine_campaign(columns: dict, path) -> None:
    """The machine-tool campaign CSV of formats.md."""
    write_table(path, columns, {"station": "%d", "target": "%d", "x_cmd_mm": "%.6f", "y_cmd_mm": "%.6f",
                                "displacement_mm": "%.9f", "valid": "%d"},
                comments=["olti_drake machine-tool campaign (001, formats.md): mm; valid 0 = beam lost"])
