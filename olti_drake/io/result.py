"""Identification results as ``result.json`` (format ``olti-result/1``: the parameters of Eq. (3)-(10) of 000, keys written by :func:`write_result`), and back.

Units: mm and degrees. Standard uncertainties (k = 1) go in ``uncertainty``
with the same keys and shapes as the values.
"""

import os

import numpy as np

from olti_drake.errors import InputError
from olti_drake.formats import ROBOT_RESULT as FORMAT
from olti_drake.io import documents
from olti_drake.io.csvio import json_numbers, read_json
from olti_drake.model.errormap import ErrorMap
from olti_drake.model.scara import ScaraModel


def _values(model: ScaraModel, P, d0) -> dict:
    out = {"L1_mm": float(model.L1_mm), "L2_mm": float(model.L2_mm)}
    if model.is_errormap:
        out["error_map"] = {"J1": model.map_dict(model.map1), "J2": model.map_dict(model.map2)}
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
    """The ``result.json`` object of an :class:`~olti_drake.estimation.identification.Identification`: its
    own values (model, lengths, maps or θ20, reflectors, dead paths) and the common fields written by the one
    codec (:func:`olti_drake.io.documents.result_document`).

    An error map identified without direction columns is one-directional: ``"bidirectional": false`` and
    ``forward_deg`` only in each map (formats.md, as the serial robots' result)."""
    model = ident.model
    values = {"model": "errormap" if model.is_errormap else "dh"}
    if model.is_errormap and not model.bidirectional:
        values["bidirectional"] = False
    values.update(_values(model, ident.reflectors_mm, ident.dead_paths_mm))
    # the same layout, filled with standard uncertainties; the common fields from the identification (its fit)
    return documents.result_document("scara", values, ident, gauge=ident.gauge,
                                     uncertainty=uncertainty_layout(model, ident.std), n_readings=ident.n_readings,
                                     campaign=ident.campaign)


def write_result(ident, path) -> None:
    from olti_drake.io.outputs import write_json

    write_json(path, result_dict(ident))


def load_result(path, outside: str = "error", identified: bool = False):
    """Read a result.json -> (ScaraModel, reflectors (Nt, 2) mm, dead paths (Nt,) mm, raw dict).

    ``identified``: the verb describes an identification (its uncertainty, its report), so a simulation
    truth (``olti simulate``'s truth.json: the result format with a ``truth`` key) is refused; where only
    the model is used (predict, compensate, design) a truth is a model like any other.

    The schema is checked where it is read (formats.md): link lengths > 0 mm, reflectors N x 2 and dead
    paths N mm, map grids ascending with forward/reverse deviations of the same length (deg), the
    standard uncertainties (if any) of the same shapes and >= 0, and every number finite and within the
    bound of its unit (``olti_drake.units.UNIT_BOUNDS``). A file of another kind (a machine-tool result, a campaign)
    is refused by its ``format``. Errors are one line naming the file and the key.
    """
    name = os.fspath(path)
    data = read_json(path, FORMAT, "a SCARA result (olti identify)")
    if identified and "truth" in data:
        raise InputError(f"{name}: a simulation truth (olti simulate), not an identified result (olti identify); "
                         f"a truth is given to olti report with --truth")
    kind = data.get("model")
    if kind not in ("dh", "errormap"):
        raise InputError(f"{name}: 'model' must be 'dh' or 'errormap', got {kind!r}")
    L1, L2 = (float(json_numbers(data, name, k, positive=True)) for k in ("L1_mm", "L2_mm"))
    maps = [_load_map(data, name, axis, outside) for axis in ("J1", "J2")] if kind == "errormap" else [None, None]
    # A map with forward_deg only is one-directional (formats.md: a campaign without dir columns); both alike.
    bidirectional = all("reverse_deg" in data["error_map"][a] for a in ("J1", "J2")) if kind == "errormap" else True
    if kind == "errormap" and bidirectional != any("reverse_deg" in data["error_map"][a] for a in ("J1", "J2")):
        raise InputError(f"{name}: key 'error_map': one map has reverse_deg and the other not (both "
                         f"bidirectional or both one-directional)")
    theta20 = float(json_numbers(data, name, "theta20_deg")) if kind == "dh" else None
    P = json_numbers(data, name, "reflectors_mm", (None, 2)) if "reflectors_mm" in data else np.zeros((0, 2))
    d0 = json_numbers(data, name, "dead_paths_mm", (len(P),)) if "dead_paths_mm" in data or len(P) else np.zeros(0)
    model = ScaraModel(L1, L2, theta20, *maps, bidirectional=bidirectional)
    if isinstance(data.get("uncertainty"), dict):
        _check_uncertainty(data["uncertainty"], uncertainty_layout(model, np.zeros(
            len(model.parameter_names()) + 3 * len(P))), name, "uncertainty")
    return model, P, d0, data


def _load_map(data, name, axis, outside) -> ErrorMap:
    maps = data.get("error_map")
    if not isinstance(maps, dict) or not isinstance(maps.get(axis), dict):
        raise InputError(f"{name}: missing key 'error_map.{axis}' (model errormap)")
    m, label = maps[axis], f"error_map.{axis}."
    grid = json_numbers(m, name, "grid_deg", (None,), label=label + "grid_deg")
    if np.any(np.diff(grid) <= 0) or not grid.size:
        raise InputError(f"{name}: key '{label}grid_deg': the map nodes must be strictly ascending")
    values = [json_numbers(m, name, k, (len(grid),), label=label + k) for k in ("forward_deg", "reverse_deg")
              if k in m or k == "forward_deg"]
    values += values[:1] if len(values) == 1 else []  # one-directional: the reverse values mirror the forward ones
    try:
        return ErrorMap(grid, *values, axis=axis, outside=outside)
    except ValueError as e:  # anything else ErrorMap refuses
        raise InputError(f"{name}: {e}") from None


def _check_uncertainty(unc: dict, layout: dict, name, prefix: str) -> None:
    """Standard uncertainties with the keys and shapes of the values (``layout``), finite and >= 0."""
    for key, like in layout.items():
        label = f"{prefix}.{key}"
        if isinstance(like, dict):
            if isinstance(unc.get(key), dict):
                _check_uncertainty(unc[key], like, name, label)
        elif key in unc:
            v = json_numbers(unc, name, key, np.shape(like), label=label)
            if np.any(v < 0):
                raise InputError(f"{name}: key '{label}': a standard uncertainty is < 0")
