"""The volumetric result ``olti-volumetric/1`` (formats.md, *Machine tool in 3D*): writer and loader;
and the compensation tables as CSV (:func:`write_tables`).

The model part (ISO 230-1 names, representation, values at stated positions,
tool offsets, squareness) is :func:`olti_drake.model.volumetric3d.motions_document`;
this module adds what the identification knows -- stations, dead paths, the
gauge, the motions held at 0 and why, standard uncertainties (k = 1) of every
motion value at the same stated positions, the parameter covariance (for the
prediction's uncertainty), the campaign digest and the fit -- and reads it
all back, every key checked where it is read (one line naming file and key).
Units: mm, µrad.
"""

import os
from dataclasses import dataclass

import numpy as np

from olti_drake.errors import InputError
from olti_drake.io.csvio import json_numbers, read_json, write_table
from olti_drake.model.propagation import predicted_std, with_lack_of_fit
from olti_drake.model.volumetric3d import (ALL_MOTIONS, FORMAT, SQUARENESS, MachineConfig, VolumetricModel,
                                           axis_tables, error_grid, model_from_document, motions_document)


def motion_std(model: VolumetricModel, covariance, positions: dict) -> dict:
    """Standard uncertainty (k = 1) of every motion at ``positions[axis]`` (mm) from the parameter
    covariance: u(v(q))² = b(q)ᵀ C b(q), b the motion's B-spline basis at q (mm or µrad)."""
    C = np.asarray(covariance, float)
    basis = model.motions(model.zeros())
    out = {}
    for name in ALL_MOTIONS:
        s = model.slices[name]
        B = basis.basis(name[3], np.asarray(positions[name[3]], float))[:, model.free[name]]
        out[name] = predicted_std(B, C[s, s])
    return out


def uncertainty_block(model: VolumetricModel, covariance, positions: dict, stations_std_mm, dead_paths_std_mm,
                      scale: float = 1.0) -> dict:
    """The standard uncertainties (k = 1, times ``scale``: k of an expanded one) in a volumetric result's keys:
    every motion at ``positions[axis]`` (mm, :func:`motion_std`), the squareness (µrad), the tool offsets, the
    stations and dead paths (mm); ``covariance`` (P, P) over ``model.parameter_names()`` -- a result's, or one
    propagated by ``olti uncertainty``."""
    C = np.asarray(covariance, float)
    std = motion_std(model, C, positions)
    tool_std = np.zeros((len(model.config.tools), 3))
    for m, g in enumerate(model.tool_groups, start=1):
        tool_std[m] = np.sqrt(np.maximum(np.diag(C)[model.slices[g]], 0))
    return {"error_motions": {n: (scale * v).tolist() for n, v in std.items()},
            "squareness_urad": {s: scale * float(np.sqrt(max(C[model.slices[s], model.slices[s]][0, 0], 0.0)))
                                for s in SQUARENESS},
            "tool_offsets_mm": (scale * tool_std).tolist(),
            "stations_mm": (scale * np.asarray(stations_std_mm, float)).tolist(),
            "dead_paths_mm": (scale * np.asarray(dead_paths_std_mm, float)).tolist()}


def volumetric_result_dict(model: VolumetricModel, params, covariance, pitch_mm: float, fit, *, stations_mm,
                           dead_paths_mm, stations_std_mm, dead_paths_std_mm, gauge: str, gauge_conditions,
                           held: dict, observability: str, method: str, campaign: dict) -> dict:
    """The ``olti-volumetric/1`` object: the volumetric machine's own keys (the model part, stations, dead paths,
    the gauge's conditions, the motions held and the observability; the uncertainty of every motion value, the
    covariance) and the common fields by the one codec (:func:`olti_drake.io.documents.result_document`, from
    ``fit``: the identification's :class:`~olti_drake.estimation.calibration.Fit`). ``covariance`` (P, P) over
    ``model.parameter_names()`` (k = 1; held motions: rows of 0); ``held``: {motion: why it is held at 0}."""
    from olti_drake.io import documents

    doc = motions_document(model, params, pitch_mm)
    C = np.asarray(covariance, float)
    C = (C + C.T) / 2  # symmetric to the last bit (the propagation B Jᵀ U J B is, up to rounding)
    positions = {name[3]: doc["error_motions"][name]["positions_mm"] for name in ALL_MOTIONS}
    for name, entry in doc["error_motions"].items():
        entry["identified"] = name not in held
        if name in held:
            entry["note"] = held[name]
    doc.update({
        "pitch_mm": float(pitch_mm),
        "stations_mm": np.asarray(stations_mm, float).tolist(),
        "dead_paths_mm": np.asarray(dead_paths_mm, float).tolist(),
        "gauge_conditions": list(gauge_conditions), "held_motions": dict(held), "observability": observability})
    unc = dict(uncertainty_block(model, C, positions, stations_std_mm, dead_paths_std_mm),
               parameter_names=list(model.parameter_names()), covariance=C.tolist(),
               lack_of_fit_mm=float(getattr(fit, "lack_of_fit_mm", 0.0) or 0.0))
    return documents.result_document("volumetric", doc, fit, gauge=gauge, uncertainty=unc, method=method,
                                     campaign=campaign, empty_notes=True)


@dataclass
class VolumetricDocument:
    """A loaded result: the model and its parameters, the covariance (P, P) over ``model.parameter_names()``
    (k = 1), and the document itself."""

    model: VolumetricModel
    params: np.ndarray
    covariance: np.ndarray
    doc: dict
    source: str

    @property
    def motions(self):
        return self.model.motions(self.params)

    @property
    def lack_of_fit_mm(self) -> float:
        """The model error every predicted point shares (mm, k = 1): ``uncertainty.lack_of_fit_mm`` (0 when absent:
        a result written before it was stated)."""
        from olti_drake.io.serial_io import checked_lack_of_fit

        try:
            return checked_lack_of_fit(self.doc["uncertainty"].get("lack_of_fit_mm", 0.0), "uncertainty.lack_of_fit_mm")
        except InputError as e:
            raise InputError(f"{self.source}: {e}") from None

    def position_std(self, commands_mm, tool) -> np.ndarray:
        """Standard uncertainty (k = 1) of the predicted x, y, z (M, 3) mm: J C Jᵀ per point (linear, JCGM 100),
        J the model's Jacobian at the command (clamped into the travel), C the result's covariance, and the
        result's lack of fit in quadrature (:attr:`lack_of_fit_mm`)."""
        from olti_drake.model.volumetric3d import clamp_commands

        _, J = self.model.jacobian(clamp_commands(self.model.config, commands_mm), tool, self.params)
        return with_lack_of_fit(predicted_std(J, self.covariance), self.lack_of_fit_mm)


def load_volumetric_result(path) -> VolumetricDocument:
    """Read an ``olti-volumetric/1`` result, checked: the model part (``model_from_document``), stations
    N x 3 and dead paths N (mm), the gauge sentence, the uncertainty (standard uncertainties >= 0 of the
    shapes of the values, a symmetric covariance over the model's parameter names). One-line errors
    name the file and the key."""
    name = os.fspath(path)
    doc = read_json(path, FORMAT, "a volumetric result (olti identify --model volumetric)")
    try:
        model, params = model_from_document(doc, name)
    except ValueError as e:
        raise InputError(" ".join(str(e).split())) from None
    S = json_numbers(doc, name, "stations_mm", (None, 3))
    json_numbers(doc, name, "dead_paths_mm", (len(S),))
    if not isinstance(doc.get("gauge"), str) or not doc["gauge"]:
        raise InputError(f"{name}: key 'gauge': expected the sentence stating the gauge, got {doc.get('gauge')!r}")
    unc = doc.get("uncertainty")
    if not isinstance(unc, dict):
        raise InputError(f"{name}: missing key 'uncertainty'")
    names = list(model.parameter_names())
    if unc.get("parameter_names") != names:
        raise InputError(f"{name}: key 'uncertainty.parameter_names': expected the {len(names)} parameter names "
                         f"of the model ({names[0]}, ...)")
    C = json_numbers(unc, name, "covariance", (len(names), len(names)), label="uncertainty.covariance")
    scale = np.sqrt(np.outer(np.abs(np.diag(C)), np.abs(np.diag(C))))
    if np.any(np.abs(C - C.T) > 1e-9 * scale) or np.any(np.diag(C) < 0):
        raise InputError(f"{name}: key 'uncertainty.covariance': not symmetric with a diagonal >= 0")
    checks = [("stations_mm", S.shape), ("dead_paths_mm", (len(S),)),
              ("tool_offsets_mm", (len(model.config.tools), 3))]
    for key, shape in checks:
        if np.any(json_numbers(unc, name, key, shape, label=f"uncertainty.{key}") < 0):
            raise InputError(f"{name}: key 'uncertainty.{key}': a standard uncertainty is < 0")
    for motion in ALL_MOTIONS:
        n_pos = len(doc["error_motions"][motion].get("positions_mm", []))
        v = json_numbers(unc.get("error_motions", {}), name, motion, (n_pos,),
                         label=f"uncertainty.error_motions.{motion}")
        if np.any(v < 0):
            raise InputError(f"{name}: key 'uncertainty.error_motions.{motion}': a standard uncertainty is < 0")
    return VolumetricDocument(model, params, C, doc, name)


def write_tables(directory, motions, config: MachineConfig, pitch_mm: float, grid_pitch_mm=None) -> list:
    """Compensation tables as CSV in ``directory``: ``axis_X.csv``, ``axis_Y.csv``, ``axis_Z.csv``
    (one row per position, the six motions in ISO 230-1 names with units) and, with
    ``grid_pitch_mm``, ``grid_tool<m>.csv`` per tool (positioning-error vectors). Atomic writes;
    the caller checks the outputs first (``olti_drake.io.outputs.preflight``). Returns the paths."""
    paths = []
    for axis, cols in axis_tables(motions, config, pitch_mm).items():
        path = os.path.join(directory, f"axis_{axis}.csv")
        fmt = {c: ("%.6f" if c == "position_mm" else "%.9f" if c.endswith("_mm") else "%.6f") for c in cols}
        write_table(path, cols, fmt, comments=[f"olti_drake volumetric error motions of axis {axis} "
                                               f"(ISO 230-1 names; mm, urad; docs/machine_3d.md)"])
        paths.append(path)
    for m in range(len(config.tools)) if grid_pitch_mm else ():
        cols = error_grid(motions, config, grid_pitch_mm, tool=m)
        path = os.path.join(directory, f"grid_tool{m}.csv")
        write_table(path, cols, {c: "%.6f" if "cmd" in c else "%.9f" for c in cols},
                    comments=[f"olti_drake positioning-error vectors of tool {m} (offset "
                              f"{config.tools[m].tolist()} mm): actual - command - offset, mm"])
        paths.append(path)
    return paths
