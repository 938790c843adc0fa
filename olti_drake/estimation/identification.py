"""Identification of the SCARA models of paper 000 §3 as a Drake MathematicalProgram.

* D-H model (Eq. 3-5): e = [L1, L2, θ20, P_1..P_Nt, d0_1..d0_Nt].
* Error-map model (Eq. 6-10): e = [L1, L2, Δθ1,map(·, ±1), Δθ2,map(·, ±1), P, d0]
  (θ20 absorbed in the J2 map).

Both minimize Σ (‖p̂(k) − P_j‖ − d0_j − d_j(k))² (Eq. 5 / Eq. 10) on the one calibration engine:
:class:`Identifier` is the :class:`~olti_drake.estimation.calibration.Calibration` of the SCARA closed form
(:class:`olti_drake.model.scara.ScaraPositionModel`: Eq. 3 with Eq. 4 or Eq. 7-9, analytic Jacobian) read by the
shared distance measurement (:class:`olti_drake.model.measurements.StationDistanceMeasurement`, the reflectors
P_j and dead paths ``d0_j``: Eq. 5 / 10) with the gauge of :func:`olti_drake.model.gauges.scara_gauge`. What is
the SCARA's own stays here: the campaign checks, the start (the reflectors fitted on the nominal model, or
given), known reflectors as bounds, the implausible values, the readings near an untouched map node, the
under-resolution check of the map (Eq. 8-9) and the :class:`Identification`.

:attr:`Identifier.prog` holds one named decision variable per parameter
(``L1_mm``, ``J2_reverse_deg[3]``, ``P0_x_mm``, ``d0_0_mm``, ...) and the gauge
constraint. Add your own constraints and costs to it before
:meth:`Identifier.solve`. The solvers (LM steps as Drake programs, or a Drake
NLP solver), the identifiability check and the uncertainty are the shared
machinery of :mod:`olti_drake.estimation.calibration`.

Units: mm and degrees in every parameter, residual and Jacobian.
"""

import os
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from olti_drake.errors import InputError
from olti_drake.io.csvio import CampaignData
from olti_drake.io.csvio import check_spread
from olti_drake.model.errormap import ErrorMap
from olti_drake.model.gauges import scara_gauge
from olti_drake.model.measurements import StationDistanceMeasurement
from olti_drake.model.scara import PAPER_L1_MM, PAPER_L2_MM, ScaraModel, ScaraPositionModel
from olti_drake.estimation.calibration import LeastSquaresProgram, SolverOptions, UnidentifiableError  # noqa: F401 (re-exported)
from olti_drake.estimation.calibration import Calibration, deferred_covariance, lazy_covariance, station_fit
from olti_drake.units import unit_bound


@dataclass
class IdentificationOptions(SolverOptions):
    """What to identify (units mm, deg), plus the solver options of :class:`SolverOptions`.

    ``grid1_deg``/``grid2_deg``: map nodes (default: distinct commanded angles).
    ``reflectors_mm``: initial reflector positions (e.g. from the Eq. (2)
    search); ``fix_reflectors`` makes them known (then N_t = 2 suffices).
    """

    model: str = "errormap"
    grid1_deg: Optional[np.ndarray] = None
    grid2_deg: Optional[np.ndarray] = None
    nominal_L1_mm: float = PAPER_L1_MM
    nominal_L2_mm: float = PAPER_L2_MM
    reflectors_mm: Optional[np.ndarray] = None
    fix_reflectors: bool = False
    #: Run :meth:`Identifier.resolution_check` at an error-map fit's solution (a reduced fit on the readings at
    #: every second node, on the fit's linearization).
    check_resolution: bool = True


@lazy_covariance  # (the (n, n) matrix formed when read: a result file carries the standard uncertainties)
@dataclass
class Identification:
    """The identified model, its uncertainty (k = 1, linear propagation) and diagnostics."""

    model: ScaraModel
    reflectors_mm: np.ndarray
    dead_paths_mm: np.ndarray
    names: List[str]
    x: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    residuals_mm: np.ndarray
    iterations: int
    condition_number: float
    gauge: str
    solver: str
    outliers: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    n_readings: int = 0
    converged_by: str = ""
    warnings: list = field(default_factory=list)
    #: The campaign identified from: {"readings": N, "sha256": ...} (:func:`csvio.campaign_digest`).
    campaign: dict = field(default_factory=dict)
    #: Error-map models: the under-resolution check (:meth:`Identifier.resolution_check`), None if not possible.
    resolution: Optional[dict] = None
    #: The user's own decision variables (added to ``prog``), by name: their solved values (``Fit.extra``).
    extra: dict = field(default_factory=dict)
    #: The maps' smoothness prior when asked for (``--smoothing``; ``Fit.smoothing``), else None.
    smoothing: Optional[dict] = None

    @property
    def residual_rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_mm ** 2)))

    def value(self, name: str) -> float:
        return float(self.x[self.names.index(name)])

    def uncertainty(self, name: str) -> float:
        return float(self.std[self.names.index(name)])


#: Reach (L1 + L2) beyond that of any SCARA robot made (the largest reach about 1.2 m), mm: with the
#: nominal lengths, the bound on the spread of one reflector's readings (csvio.check_spread).
MAX_SCARA_REACH_MM = 2000.0

#: Most nodes a map grid may have: the identification's dense matrices grow as the square of the
#: 4 * nodes map parameters (2 maps x 2 directions); 2001 nodes (e.g. 0.1 deg over 200 deg) is 8004
#: parameters, a 0.5 GB covariance -- a finer grid is a slip (a step in the wrong unit), not a plan.
MAX_GRID_NODES = 2001


def parse_grid(text: str, name: str) -> np.ndarray:
    """``start:stop:step`` (inclusive) or a comma list, degrees, e.g. ``-140:60:10``: finite, strictly
    ascending, within +-720 deg (``csvio.UNIT_BOUNDS``), at most :data:`MAX_GRID_NODES` nodes. Errors are
    one line naming the option ``name``."""
    form = (f"{name}: expected START:STOP:STEP (degrees, STOP >= START, STEP > 0) or a comma list, "
            f"got {text!r}")
    try:
        if ":" in text:
            a, b, s = (float(v) for v in text.split(":"))
        else:
            g = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise InputError(form) from None
    if ":" in text:
        if not (np.isfinite([a, b, s]).all() and s > 0 and b >= a):
            raise InputError(form)
        n = (b - a) / s
        if n + 1 > MAX_GRID_NODES:
            raise InputError(f"{name}: {text!r} has {n + 1:.3g} nodes, more than {MAX_GRID_NODES} "
                             f"(use a coarser step)")
        n = int(round(n))
        if abs(a + n * s - b) > 1e-9 * max(1.0, abs(b)):
            raise InputError(f"{name}: step {s:g} does not divide [{a:g}, {b:g}]")
        g = a + s * np.arange(n + 1)
    if g.size == 0 or np.any(np.diff(g) <= 0) or not np.all(np.isfinite(g)):
        raise InputError(f"{name}: grid must be finite and strictly ascending, got {text!r}")
    if g.size > MAX_GRID_NODES:
        raise InputError(f"{name}: {g.size} nodes, more than {MAX_GRID_NODES}")
    if np.abs(g).max() > unit_bound("_deg"):
        raise InputError(f"{name}: nodes beyond +-{unit_bound('_deg'):g} deg, outside any physical range")
    return g


class Identifier(Calibration):
    """The identification problem of 000 §3 for one campaign and model.

    The :class:`~olti_drake.estimation.calibration.Calibration` of :attr:`measurement`, the shared distance
    measurement (:class:`~olti_drake.model.measurements.StationDistanceMeasurement`, 000 Eq. 5 / 10: r =
    ‖p̂(k) − P_j‖ − d0_j − d_j(k), mm) of the SCARA position model :attr:`model`
    (:class:`~olti_drake.model.scara.ScaraPositionModel`: one pose per reading), with the gauge of
    :func:`~olti_drake.model.gauges.scara_gauge` (its sentence: :attr:`gauge`). Build it, optionally add
    constraints/costs to :attr:`prog` (its decision variables are :attr:`variables`, named as :attr:`names`),
    then call :meth:`solve`. Batched residuals for the Monte Carlo: :meth:`residual_rows`.
    """

    budget_kind = "scara"  # (000 Table 2 / 001 Table 4: Calibration.default_budget)
    reading_keys = ("line", "reflector")  # (Calibration.reading_label)

    rank_hint = "check the reflector layout (e.g. coincident reflectors) or fix a parameter"
    untouched_hint = "set a coarser map grid"
    #: A link length identified outside [1/f, f] x its nominal value is refused: the start or the units are wrong.
    LENGTH_FACTOR = ScaraPositionModel.LENGTH_FACTOR
    #: A joint deviation (map node, theta20) beyond this is no positioning deviation, deg.
    MAX_DEVIATION_DEG = ScaraPositionModel.MAX_DEVIATION_DEG

    def __init__(self, data: CampaignData, options: IdentificationOptions = None):
        o = options or IdentificationOptions()
        if o.model not in ("dh", "errormap"):
            raise InputError(f"model must be 'dh' or 'errormap', got {o.model!r}")
        self.options = o
        self._data = data
        self._check_reflectors()
        self.robot0 = self._robot_start()
        self.n_t = data.n_reflectors
        self.n_robot = len(self.robot0.parameter_names())
        model = ScaraPositionModel(self.robot0, data.commands)
        measurement = self._measurement(data, *self._start_reflectors(model.positions()), model)
        gauge = scara_gauge(self.robot0, len(measurement.names), o.fix_reflectors)
        super().__init__(measurement, o, gauge if len(gauge.b) else None, data.source or "campaign")
        self.gauge = gauge.sentence
        if o.fix_reflectors:
            idx = slice(self.n_robot, self.n_robot + 2 * self.n_t)
            self.prog.AddBoundingBoxConstraint(self.x0[idx], self.x0[idx], self.variables[idx])

    def _measurement(self, data: CampaignData, P, d0, model=None) -> StationDistanceMeasurement:
        """000 Eq. (10) of the campaign's readings: the robot at its commands (one pose per reading, ``model``:
        built when not given) from the reflectors (Nt, 2) mm with dead paths d0 (Nt,) mm to start."""
        model = ScaraPositionModel(self.robot0, data.commands) if model is None else model
        return StationDistanceMeasurement(model, model.all_poses, data.reflector, data.displacement_mm, P, d0,
                                          self.n_t, dead_path="d0")

    @property
    def model(self) -> ScaraPositionModel:
        """The position model: 000 Eq. (3) with Eq. (4) or Eq. (7)-(9) at the campaign's commands."""
        return self.measurement.model

    @property
    def data(self) -> CampaignData:
        """The campaign. Setting another of the same commands and reflectors (e.g. other readings: the layout
        design's synthetic campaigns) re-reads it; the program, its start and gauge stay."""
        return self._data

    @data.setter
    def data(self, data: CampaignData):
        self._data = data
        _, P, d0 = self.measurement.split(self.x0)
        self.measurement = self._measurement(data, P, d0)
        self.residual_rows = self.measurement.residual_rows

    def solve(self) -> "Identification":
        """Check identifiability, solve, estimate uncertainty and flag outliers (000 Eq. 5 / 10)."""
        from olti_drake.io.csvio import campaign_digest

        self._resolution = None
        f = self.fit()  # (runs the under-resolution check: at_solution)
        model, P, d0 = self.split(f.x)
        resolution = self._resolution
        gross, fixed = getattr(self, "_gross", None), getattr(self, "_fixed_off", None)
        if resolution and "warning" in resolution and (gross or fixed):
            # A blunder (or a wrong fixed reflector) misses any map: the held-out miss says nothing of the node
            # spacing until it is gone.
            if gross:
                lines = ", ".join(f"line {o['line']}" for o in gross[:5]) + (" and more" if len(gross) > 5 else "")
                why = (f"the gross outlier(s) above ({lines}) inflate that miss -- refit with --loss huber (or "
                       f"correct the reading)")
            else:
                why = "the fixed reflectors above inflate that miss -- correct --reflectors-mm"
            resolution["warning"] = (
                f"under-resolution check not conclusive: the held-out readings miss the map fitted on every second "
                f"node by RMS {1e3 * resolution['held_out_rms_mm']:.1f} um = {resolution['ratio']:.1f} x the "
                f"budget's reading uncertainty, but {why} before judging the node spacing (no finer plan yet)")
        warnings = (([fixed] if fixed else []) + list(f.warnings)
                    + ([resolution["warning"]] if resolution and "warning" in resolution else []))
        notes = list(f.notes)
        if self.robot0.is_errormap and not self.robot0.bidirectional:
            notes.append(ONE_DIRECTIONAL_NOTE)
        return Identification(model, P, d0, f.names, f.x, f.std, deferred_covariance(f), f.residuals, f.iterations,
                              f.condition_number, self.gauge, f.solver, f.outliers, notes, len(f.residuals),
                              f.converged_by, warnings, campaign_digest(self.data), resolution, dict(f.extra),
                              f.smoothing)

    def at_solution(self, x, r, J) -> None:
        """The under-resolution check of an error map (:meth:`resolution_check`), run by :meth:`fit`."""
        if self.robot0.is_errormap and self.options.check_resolution:
            self._resolution = self.resolution_check(x, (r, J))

    def resolution_check(self, x, at=None) -> Optional[dict]:
        """Is the map resolved between its nodes? Held-out readings at every second node (000 Eq. 8-9).

        The residual cannot tell: at the default grid every reading sits on a node, so a deviation with a
        period under ~2 node spacings is fitted perfectly at the nodes and wrong between them. Here the map
        is fitted on every second node of each axis (ends kept) from the readings whose commands are all on
        those nodes; the readings at the dropped nodes, held out, are predicted by it. Their RMS miss against
        the budget's reading uncertainty (:data:`RESOLUTION_WARNING_RATIO`) says whether the true deviation
        changes within two node spacings -- then the map may miss as much between its own nodes, and readings
        between the nodes (a finer plan) are needed to know. Returns None when no reading can be held out.
        ``at``: the residuals and Jacobian at x (default evaluated).

        The coarse map is this model with the dropped nodes' values interpolated between the kept ones (a
        linear reparametrization, exact at every command), so its fit is :meth:`reduced_fit` at ``x``, the fine
        fit's solution, with the fine fit's last residuals and Jacobian: no evaluation, no second program.
        """
        from olti_drake.estimation.calibration import RESIDUAL_WARNING_RATIO, _rms
        from olti_drake.model.budget import ReadingErrors

        c = self.data.commands
        coarse = [np.union1d(m.grid_deg[::2], m.grid_deg[-1:]) for m in (self.robot0.map1, self.robot0.map2)]
        on = [_on_nodes(cmd, g) for cmd, g in ((c.theta1_deg, coarse[0]), (c.theta2_deg, coarse[1]))]
        keep = on[0] & on[1]
        if keep.all() or not keep.any():
            return None
        spacing = [float(np.diff(g).max()) if g.size > 1 else 0.0 for g in coarse]
        how = (f"map on every second node (J1 {spacing[0]:g} deg, J2 {spacing[1]:g} deg spacing) from the "
               f"{int(keep.sum())} readings on them; {int((~keep).sum())} readings at the dropped nodes held out "
               f"and predicted")
        T, kept = self._coarse_parameters(coarse)
        x = np.asarray(x, dtype=float)
        try:
            y, r = self.reduced_fit(T, x[kept], x, keep, [self.names[i] for i in kept], at)
            problems = self.implausible(T @ y)
            if problems:
                raise InputError(f"the coarse map's solution is physically impossible: {'; '.join(problems)}")
        except InputError as e:  # too few readings left, or the coarse fit refused: say so, do not fail
            return {"method": how, "done": False, "why": str(e)}
        budget = self.options.budget if self.options.budget is not None else self.default_budget()
        u = _rms(ReadingErrors(budget).std(self.beam_lengths(T @ y, r)))
        out = {"method": how, "done": True, "held_out_rms_mm": _rms(r[~keep]), "fitted_rms_mm": _rms(r[keep]),
               "reading_u_mm": u, "ratio": _rms(r[~keep]) / u}
        if out["ratio"] > RESIDUAL_WARNING_RATIO:
            out["warning"] = (
                f"under-resolution check: readings at the dropped nodes, held out, miss the map fitted on every "
                f"second node by RMS {1e3 * out['held_out_rms_mm']:.1f} um = {out['ratio']:.1f} x the budget's "
                f"reading uncertainty: the true deviation changes within two node spacings, so the map may miss "
                f"as much between its own nodes, where no reading looks -- measure between the nodes (finer plan)")
        return out

    def _coarse_parameters(self, coarse):
        """The map on the ``coarse`` grids (subsets of the fine ones, deg) as fine parameters x = T y: T (n, k)
        sparse -- the identity on the lengths, reflectors and dead paths, linear interpolation of the kept nodes
        (000 Eq. 9) at every fine node -- and ``kept`` (k,), the fine index of each coarse parameter."""
        import scipy.sparse as sp

        blocks, kept, at = [sp.identity(2)], [np.arange(2)], 2
        nb = len(self.robot0.branches)  # 2, or 1 for a one-directional map (forward block only)
        for m, g in zip((self.robot0.map1, self.robot0.map2), coarse):
            nodes = np.concatenate([m.grid_deg] * nb)
            directions = np.repeat([1.0, -1.0][:nb], m.n_nodes)
            w = ErrorMap(g, np.zeros(g.size), np.zeros(g.size), axis=m.axis).weights(nodes, directions)
            blocks.append(w if nb == 2 else w[:, :g.size])
            i = np.searchsorted(m.grid_deg, g)
            kept += [at + b * m.n_nodes + i for b in range(nb)]
            at += nb * m.n_nodes
        blocks.append(sp.identity(len(self.names) - at))
        kept.append(np.arange(at, len(self.names)))
        return sp.block_diag(blocks, format="csr"), np.concatenate(kept)

    def implausible(self, x) -> list:
        """Link lengths not positive or outside [1/f, f] x nominal (f = :attr:`LENGTH_FACTOR`); joint deviations
        beyond :attr:`MAX_DEVIATION_DEG` (:meth:`ScaraPositionModel.implausible`). The reflectors are bounded where
        the campaign is read (their readings' spread, :meth:`_check_reflectors`)."""
        return self.model.implausible(np.asarray(x, dtype=float)[:self.n_robot])

    def layout(self, v, uncertainty: bool = False) -> dict:
        """A parameter-shaped vector (e.g. uncertainties) in the result's keys and shapes (formats.md)."""
        from olti_drake.io.result import uncertainty_layout

        return uncertainty_layout(self.robot0, v)

    def _explain(self, error: UnidentifiableError) -> UnidentifiableError:
        """A map node no reading touches is also named by the campaign lines that command that axis near it
        (often one mistyped angle)."""
        where = self._node_readings(error.names[0]) if error.names else ""
        return UnidentifiableError(f"{error}; {where}", error.names) if where else error

    def _node_readings(self, name: str) -> str:
        """Where the readings near a map-node parameter's node are (file lines, directions), or ''."""
        import re

        m = re.fullmatch(r"(J[12])_(forward|reverse)_deg\[(\d+)\]", name)
        if m is None or not self.robot0.is_errormap:
            return ""
        axis, i = m.group(1), int(m.group(3))
        grid = (self.robot0.map1 if axis == "J1" else self.robot0.map2).grid_deg
        c = self.data.commands
        cmd, dirs = (c.theta1_deg, c.dir1) if axis == "J1" else (c.theta2_deg, c.dir2)
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
        near = np.flatnonzero((cmd > lo) & (cmd < hi) | (cmd == grid[i]))
        if not near.size:
            return f"no reading commands {axis} between {lo:g} and {hi:g} deg"
        lines = ", ".join(f"{self.data.source}:{self.data.line[k]}" for k in near[:3])
        lines += " ..." if near.size > 3 else ""
        sides = sorted({f"{d:+.0f}" for d in dirs[near]})
        side = "" if self.data.one_directional else f" (direction {', '.join(sides)} only)"
        return (f"the only readings near the {axis} node {grid[i]:g} deg are at {lines}{side} -- check "
                f"{'that command' if near.size == 1 else 'those commands'}")

    # -- model -------------------------------------------------------------------------------
    def _check_reflectors(self):
        o, d = self.options, self.data
        # A reading far from its reflector's others (a typo, a unit slip) is named by line before the start
        # values are built from it. The bound holds for any SCARA: none reaches beyond MAX_SCARA_REACH_MM.
        reach = max(o.nominal_L1_mm + o.nominal_L2_mm, MAX_SCARA_REACH_MM)
        check_spread(d.displacement_mm, d.reflector, d.line, d.source, "displacement_mm", 2 * reach, "reflector",
                     f"twice the reach, at most {reach:g} mm for any SCARA")
        counts = np.bincount(d.reflector)
        if counts.size < 3 and not o.fix_reflectors:
            raise UnidentifiableError(
                f"{d.source}: {counts.size} reflector position(s); with unknown reflector positions at least 3 "
                f"are needed (000 §3.2.2 Remark 1) -- P and d0 of every reflector are not identifiable")
        few = np.flatnonzero(counts < 3)
        if few.size:
            raise UnidentifiableError(
                f"{d.source}: reflector {few[0]} has {counts[few[0]]} valid reading(s); each reflector needs at "
                f"least 3 (its position P{few[0]} and dead path d0_{few[0]} are 3 unknowns)",
                [f"P{few[0]}_x_mm", f"P{few[0]}_y_mm", f"d0_{few[0]}_mm"])

    def _robot_start(self) -> ScaraModel:
        o, c = self.options, self.data.commands
        if o.model == "dh":
            return ScaraModel(o.nominal_L1_mm, o.nominal_L2_mm, 0.0)
        maps = []
        for axis, grid, cmd in (("J1", o.grid1_deg, c.theta1_deg), ("J2", o.grid2_deg, c.theta2_deg)):
            # Distinct commanded angles; files written elsewhere may carry 1e-12 deg of float noise.
            g = np.unique(np.round(cmd, 9)) if grid is None else np.asarray(grid, dtype=float)
            if grid is None and g.size > MAX_GRID_NODES:
                raise InputError(f"{self.data.source}: {g.size} distinct {axis} commands would be {g.size} map nodes, "
                                 f"more than {MAX_GRID_NODES}; give the {axis} map grid (--grid{axis[1]}-deg)")
            out = (cmd < g[0] - 1e-9) | (cmd > g[-1] + 1e-9)
            if out.any():
                k = np.flatnonzero(out)[0]
                raise InputError(f"{self.data.source}:{self.data.line[k]}: {axis} command {cmd[k]:g} deg is outside "
                                 f"the {axis} map grid [{g[0]:g}, {g[-1]:g}] deg")
            maps.append(ErrorMap(g, np.zeros(g.size), np.zeros(g.size), axis=axis))
        # A campaign without direction columns: one branch per joint, no backlash (formats.md).
        return ScaraModel(o.nominal_L1_mm, o.nominal_L2_mm, None, *maps, bidirectional=not self.data.one_directional)

    def split(self, x):
        """Parameter vector -> (ScaraModel, reflectors (Nt, 2) mm, dead paths (Nt,) mm)."""
        xm, P, d0 = self.measurement.split(x)
        return self.robot0.with_parameters(xm), P, d0

    def residual_rows(self, X, displacement_mm=None):
        """Eq. (10) residuals of T parameter vectors at once, Jacobian row-compressed
        (:meth:`StationDistanceMeasurement.residual_rows`).

        Args:
            X: (T, n) parameter vectors (layout of :attr:`names`).
            displacement_mm: readings (K,) or per trial (T, K); default the campaign's.

        Returns:
            r (T, K) mm; cols (K, m) parameter indices shared by all trials;
            vals (T, K, m) the matching dr/dx entries: the robot's few non-zeros
            (kinematics), −u on P_j, −1 on d0_j, u the unit vector from P_j to p̂(k).
        """
        return self.measurement.residual_rows(X, displacement_mm)

    # -- start -----------------------------------------------------------------------------------
    def _start_reflectors(self, p):
        """Reflectors (Nt, 2) and dead paths (Nt,) mm to start: fitted per reflector on the nominal model (its
        positions p (K, 2) mm at the commands; :func:`~olti_drake.estimation.calibration.station_fit`), from
        ``reflectors_mm`` when given (which ``fix_reflectors`` keeps)."""
        o = self.options
        P0 = None if o.reflectors_mm is None else np.asarray(o.reflectors_mm, dtype=float).reshape(-1, 2)
        if P0 is not None and len(P0) != self.n_t:
            raise InputError(f"reflectors_mm gives {len(P0)} positions but the campaign has {self.n_t} reflectors")
        fits = [self._reflector_fit(j, p, None if P0 is None else P0[j]) for j in range(self.n_t)]
        if P0 is None:
            for j, f in enumerate(fits):
                rows = self.data.reflector == j
                self._check_reading_sign(j, p[rows], self.data.displacement_mm[rows], f)
        P = np.array([f[0] for f in fits]) if P0 is None or not o.fix_reflectors else P0
        self._fixed_off = None
        if P0 is not None and o.fix_reflectors:  # fixed where the readings do not put them: the fit would absorb it
            off = np.linalg.norm(np.array([f[0] for f in fits]) - P0, axis=1)
            if off.max() > FIXED_REFLECTOR_MM:
                j = int(np.argmax(off))
                self._fixed_off = (
                    f"the fixed reflectors (--reflectors-mm with --fix-reflectors) are not where the readings put "
                    f"them: P{j} is {off[j]:.4g} mm from its fit on the nominal arm ({fits[j][0][0]:.3f}, "
                    f"{fits[j][0][1]:.3f}) mm (over {FIXED_REFLECTOR_MM:g} mm); the lengths and maps absorb that "
                    f"error and every warning below follows from it -- check --reflectors-mm, or leave out "
                    f"--fix-reflectors")
        return P, np.array([f[1] for f in fits])


    def _reflector_fit(self, j, p, start):
        """station_fit of reflector j's readings on the nominal positions p; when its Gauss-Newton meets a singular
        step (readings of flipped sign may, depending on rounding), the flipped readings are tried first, so that
        the cause is named as such (:meth:`_check_reading_sign`)."""
        from olti_drake.estimation.calibration import StationFitFailed

        rows = self.data.reflector == j
        try:
            return station_fit(p[rows], self.data.displacement_mm[rows], start)
        except StationFitFailed:
            if start is None:
                self._check_reading_sign(j, p[rows], self.data.displacement_mm[rows], None)
            raise

    def _check_reading_sign(self, j, p, d, fit):
        """Refuse reflector j's readings d (mm) when they fit distances from the nominal tool points p only with
        their sign flipped (start-fit RMS over :data:`SIGN_CHECK_MM` as given, 10 x less flipped): the layout
        or the solution would be blamed otherwise."""
        from olti_drake.estimation.calibration import _rms, lengths

        given = np.inf if fit is None else _rms(lengths(p - fit[0]) - fit[1] - d)  # (None: no fit as given)
        if not given > SIGN_CHECK_MM:
            return
        try:
            P, L0 = station_fit(p, -d)
        except ValueError:
            return
        flipped = _rms(lengths(p - P) - L0 + d)
        if flipped < min(0.1 * given, 10 * SIGN_CHECK_MM):
            as_given = "no fit" if not np.isfinite(given) else f"start-fit RMS {given:.4g} mm"
            raise InputError(f"{self.data.source}: reflector {j}: refused -- its readings fit distances from the "
                             f"nominal arm only with their sign flipped ({as_given} as given, "
                             f"{flipped:.4g} mm flipped): displacement_mm must grow as the beam lengthens (formats.md)")


#: A fixed reflector farther than this (mm) from its free fit on the nominal arm is named as the cause.
FIXED_REFLECTOR_MM = 2.0
#: A reflector's start fit on the nominal arm above this RMS (mm) is checked for readings of flipped sign.
SIGN_CHECK_MM = 1.0

#: The note of an error-map result identified from a campaign without direction columns (formats.md).
ONE_DIRECTIONAL_NOTE = "one-directional campaign (no dir columns): single-branch maps, no backlash identified"


def identify(data: CampaignData, options: IdentificationOptions = None) -> Identification:
    """Identify the model of ``options.model`` from the campaign (000 Eq. 5 or Eq. 10)."""
    return Identifier(data, options).solve()


def _on_nodes(commands_deg, grid_deg, tol_deg: float = 1e-9) -> np.ndarray:
    """Which commands lie on a node of the ascending ``grid_deg`` (within ``tol_deg``): the nearest node of each,
    by bisection (10⁴ commands x 350 nodes: no (M, N) difference array)."""
    i = np.clip(np.searchsorted(grid_deg, commands_deg), 1, max(len(grid_deg) - 1, 1))
    below, above = grid_deg[i - 1], grid_deg[np.minimum(i, len(grid_deg) - 1)]
    return np.minimum(np.abs(commands_deg - below), np.abs(commands_deg - above)) <= tol_deg


def identifier_at_result(result_path, data):
    """The :class:`Identifier` of a result's model and grids on a campaign, and the result's x.

    Raises InputError when the campaign and the result do not match (reflector count).
    """
    from olti_drake.io.result import load_result

    model, P, d0, raw = load_result(result_path, outside="clamp", identified=True)
    opts = IdentificationOptions(model=raw["model"], nominal_L1_mm=model.L1_mm, nominal_L2_mm=model.L2_mm)
    if model.is_errormap:
        opts.grid1_deg, opts.grid2_deg = model.map1.grid_deg, model.map2.grid_deg
    if model.is_errormap and model.bidirectional == data.one_directional:
        raise InputError(f"{os.fspath(result_path)}: its error maps are "
                         f"{'bidirectional' if model.bidirectional else 'one-directional'}, but the campaign "
                         f"{data.source} {'has no' if data.one_directional else 'has'} direction columns (dir1, dir2)")
    ident = Identifier(data, opts)
    smoothing = raw.get("smoothing") if model.is_errormap else None
    if isinstance(smoothing, dict) and isinstance(smoothing.get("weight"), (int, float)):
        ident.add_smoothing_prior(smoothing["weight"])  # the estimator that made the result, propagated
    if len(P) != ident.n_t or len(d0) != ident.n_t:
        raise InputError(f"{os.fspath(result_path)}: {len(P)} reflectors, but the campaign {data.source} has "
                         f"{ident.n_t}")
    return ident, np.concatenate([model.parameter_vector(), P.ravel(), d0])
