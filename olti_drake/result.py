"""Identification results as ``result.json`` (shared/spec/formats.md), and back.

Units: mm and degrees. Standard uncertainties (k = 1) go in ``uncertainty``
with the same keys and shapes as the values.
"""

import json
import os

import numpy as np

from .csvio import InputError, read_json
from .errormap import ErrorMap
from .kinematics import ScaraModel

FORMAT = "olti-result/1"


def _values(model: ScaraModel, P, d0) -> dict:
    out = {"L1_mm": float(model.L1_mm), "L2_mm": float(model.L2_mm)}
    if model.is_errormap:
        out["error_map"] = {"J1": model.map1.to_dict(), "J2": model.map2.to_dict()}
    else:
        out["theta20_deg"] = float(model.theta20_deg)
    out["reflectors_mm"] = np.asarray(P, dtype=float).reshape(-1, 2).tolist()
    out["dead_paths_mm"] = np.asarray(d0, dtype=float).tolist()
    return out


def uncertainty_layout(model: ScaraModel, v) -> dict:
    """A vector in the parameter order of ``model`` + reflectors + dead paths, in the result's keys and
    shapes without the map grids: the layout of the ``uncertainty`` object (formats.md)."""
    v = np.asarray(v, dtype=float)
    n = len(model.parameter_names())
    n_t = (len(v) - n) // 3
    out = _values(model.with_parameters(v[:n]), v[n:n + 2 * n_t], v[n + 2 * n_t:])
    for axis in out.get("error_map", {}):
        out["error_map"][axis].pop("grid_deg")
    return out


def result_dict(ident) -> dict:
    """The ``result.json`` object of an :class:`~olti_drake.identification.Identification`."""
    model = ident.model
    out = {"format": FORMAT, "model": "errormap" if model.is_errormap else "dh"}
    out.update(_values(model, ident.reflectors_mm, ident.dead_paths_mm))
    out["gauge"] = ident.gauge
    out["residual_rms_mm"] = ident.residual_rms_mm
    out["n_readings"] = ident.n_readings
    unc = uncertainty_layout(model, ident.std)  # the same layout, filled with standard uncertainties
    unc.update({"k": 1, "method": "linear propagation of the identification Jacobian (JCGM 100), "
                                  "residual-based reading uncertainty"})
    out["uncertainty"] = unc
    out["iterations"] = ident.iterations
    out["condition_number"] = ident.condition_number
    out["solver"] = ident.solver
    out["outliers"] = ident.outliers
    out["converged"] = ident.converged_by
    out["warnings"] = list(ident.warnings)
    if ident.campaign:
        out["campaign"] = ident.campaign
    if getattr(ident, "resolution", None):
        out["resolution_check"] = ident.resolution
    if ident.notes:
        out["notes"] = ident.notes
    return out


def write_result(ident, path) -> None:
    with open(path, "w", encoding="utf-8") as f:
        json.dump(result_dict(ident), f, indent=1)
        f.write("\n")


def load_result(path, outside: str = "error"):
    """Read a result.json -> (ScaraModel, reflectors (Nt, 2) mm, dead paths (Nt,) mm, raw dict).

    Errors name the file and the missing or bad key.
    """
    name = os.fspath(path)
    data = read_json(path, FORMAT)
    kind = data.get("model")
    need = ["L1_mm", "L2_mm"] + (["theta20_deg"] if kind == "dh" else ["error_map"])
    if kind not in ("dh", "errormap"):
        raise InputError(f"{name}: 'model' must be 'dh' or 'errormap', got {kind!r}")
    missing = [k for k in need if k not in data]
    if missing:
        raise InputError(f"{name}: missing key '{missing[0]}' (model {kind})")
    try:
        if kind == "dh":
            model = ScaraModel(float(data["L1_mm"]), float(data["L2_mm"]), float(data["theta20_deg"]))
        else:
            maps = []
            for axis in ("J1", "J2"):
                if axis not in data["error_map"]:
                    raise InputError(f"{name}: missing key 'error_map.{axis}'")
                maps.append(ErrorMap.from_dict(data["error_map"][axis], axis, outside))
            model = ScaraModel(float(data["L1_mm"]), float(data["L2_mm"]), None, *maps)
    except (TypeError, ValueError) as e:
        raise InputError(f"{name}: {e}") from None
    P = np.asarray(data.get("reflectors_mm", []), dtype=float).reshape(-1, 2)
    d0 = np.asarray(data.get("dead_paths_mm", []), dtype=float)
    return model, P, d0, data
