"""Uncertainty of a robot identified from a model file (issue 13, item 7): every parameter, and the predicted
tool point over the workspace.

* :func:`calibration_at_result` -- the identification program of a result on its own campaign, at the
  identified values (the model, stations and dead paths or the tracker frame, the drift), with the gauge of
  :func:`~olti_drake.model.serial.find_gauge`: the input of the linear propagation (JCGM 100) and of the Monte
  Carlo (JCGM 101) of :mod:`olti_drake.estimation.uncertainty`.
* :func:`tool_point_uncertainty` -- u of the predicted tool point, u_p = sqrt(diag(J_p C J_pᵀ)) per coordinate
  (mm, k = 1), for commands and directions, from the covariance C of the model's parameters (linear) or from
  Monte Carlo samples of them (the sample spread of the predicted points).
* :func:`workspace_uncertainty` -- the same over seeded workspace poses in the model's commanded ranges: the 3D
  map the report and ``olti uncertainty --map`` show as slices.

Units: mm and degrees; uncertainties standard (k = 1).
"""

from __future__ import annotations

import numpy as np

from olti_drake.errors import InputError
from olti_drake.model.propagation import predicted_std


def calibration_at_result(result, campaign):
    """(program, x): the result's identification program on ``campaign`` at the identified values.

    ``result``: :class:`~olti_drake.io.serial_io.SerialResult`; ``campaign``:
    :class:`~olti_drake.io.serial_io.SerialCampaign` (the one the result came from)."""
    from olti_drake.estimation.calibration import SolverOptions
    from olti_drake.estimation.serial_identification import SerialCalibration
    from olti_drake.model.chain import robot_plane
    from olti_drake.model.serial import DistanceMeasurement, PointMeasurement, find_gauge

    model = result.model
    if campaign.kind == "distance":
        if result.stations_mm is None:
            raise InputError(f"{campaign.source}: a distance campaign, but the result was identified from tracker "
                             f"points")
        labels = np.unique(campaign.station)
        if not np.array_equal(labels, result.station_labels):
            raise InputError(f"{campaign.source}: stations {list(labels)}, the result has "
                             f"{list(result.station_labels)}: not the campaign of this result")
        data = result.data
        drift = "drift_mm_per_h" in data
        if drift and campaign.time_s is None:
            raise InputError(f"{campaign.source}: the result has a dead-path drift (--drift): the campaign needs "
                             f"its 'time_s' column")
        meas = DistanceMeasurement(model, campaign.commands, campaign.dirs, campaign.station,
                                   campaign.displacement_mm, result.stations_mm, result.dead_paths_mm,
                                   time_h=campaign.time_s / 3600.0 if drift else None,
                                   drift_mm_per_h=data.get("drift_mm_per_h"),
                                   drift_reference_h=data.get("drift_reference_h"),
                                   plane=robot_plane(model.chain, model.chain_params) if model.planar_reduced
                                   else None)  # as build_problem
    else:
        if result.tracker_frame is None:
            raise InputError(f"{campaign.source}: a point (tracker) campaign, but the result was identified from "
                             f"distances")
        meas = PointMeasurement(model, campaign.commands, campaign.dirs, campaign.points_mm, result.tracker_frame)
    cal = SerialCalibration(meas, SolverOptions(), find_gauge(meas), campaign.source, campaign.line)
    return cal, meas.start_vector()


def zero_held_uncertainties(out: dict, measurement) -> dict:
    """Set the uncertainty of every held coordinate of ``out`` (an uncertainty layout, and its ``expanded``) to 0.

    A planar robot holds its stations' height and the tool offset along the plane's normal: they are not
    parameters, yet the layout writes the held values where a free coordinate's u goes (the same layout
    serves values and uncertainties)."""
    model = measurement.model
    held_tool = [k for k, t in enumerate(("tool_x_mm", "tool_y_mm", "tool_z_mm")) if t in model.held_tool]
    axis = getattr(measurement, "held_axis", None)
    for block in (out, out.get("expanded", {})):
        for k in held_tool:
            block["tool_offset_mm"][k] = 0.0
        if axis is not None and "stations_mm" in block:
            for row in block["stations_mm"]:
                row[axis] = 0.0
    return out


def tool_point_uncertainty(model, commands, dirs, cov=None, samples=None) -> tuple:
    """(p (M, 3), u (M, 3)) mm: the predicted tool points and their standard uncertainties per coordinate.

    ``cov``: (n, n) covariance of the model's parameters (``model.names``; the linear method), or
    ``samples``: (T, n) Monte Carlo samples of them (their tool points' spread, ddof = 1)."""
    p, jac = model.jacobian(commands, dirs)
    if samples is not None:
        pts = np.stack([model.positions(commands, dirs, s) for s in samples])
        return p, pts.std(axis=0, ddof=1)
    return p, predicted_std(jac.tocsr(), cov, dim=3)


def workspace_uncertainty(model, n_poses: int = 400, seed: int = 0, cov=None, samples=None) -> dict:
    """Predicted tool points and their u over seeded workspace poses (uniform in the model's commanded
    ranges, random approach directions for bidirectional maps): {poses_deg, dirs, points_mm, u_mm (M, 3),
    u_norm_mm (M,)} -- u_norm = ‖u‖ = sqrt(u_x² + u_y² + u_z²)."""
    rng = np.random.default_rng(seed)
    ranges = model.command_ranges()
    q = rng.uniform(ranges[:, 0], ranges[:, 1], size=(n_poses, len(ranges)))
    dirs = rng.choice([-1.0, 1.0], size=q.shape) if model.bidirectional else None
    p, u = tool_point_uncertainty(model, q, dirs, cov=cov, samples=samples)
    return {"poses_deg": q, "dirs": dirs, "points_mm": p, "u_mm": u, "u_norm_mm": np.linalg.norm(u, axis=1)}
