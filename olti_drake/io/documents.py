"""The kind of a result document, and the one reader of any result file (issue 22).

Every result the tool writes names its format and its kind (:mod:`olti_drake.formats`: the format ids, the
kinds). :func:`result_kind` tells the kind of a document -- from its ``kind`` key, or, for the files written
before that key (``olti-result/1``, ``olti-multilateration/1``, ``olti-volumetric/1`` without ``kind``), from the
format as then: an ``olti-result/1`` with a ``robot`` object is a serial robot's, without one a SCARA's.
Anything else is refused in one line naming the file. :func:`read_result` reads a file and returns
``(kind, document)``; every verb that takes a result dispatches on that kind once. The kind's own loader
(``io.result.load_result``, ``io.serial_io.load_serial_result``, ``estimation.multilateration.load_result``,
``io.volumetric_io.load_volumetric_result``) then checks the schema where it reads it.

:func:`result_document` is the one writer of a result document: the header, the kind's own values, and the
fields every identification has (:data:`COMMON_FIELDS`: gauge, residual RMS, readings, uncertainty with ``k`` and
``method``, the solver's facts, campaign digest, notes) in one order and one spelling, from the identification's
fit. The four kinds' writers (``io.result.result_dict``, ``io.serial_io.serial_result_dict``,
``MultilaterationResult.to_dict``, ``io.volumetric_io.volumetric_result_dict``) give it only what is the kind's.
"""

import os

from olti_drake.errors import InputError
from olti_drake.formats import (MULTILATERATION_RESULT, RESULT_FORMAT, RESULT_FORMATS, RESULT_KINDS, RESULT_WHAT,
                                ROBOT_RESULT, VOLUMETRIC_RESULT)

#: The kind of a result file written before the ``kind`` key, by its format (``olti-result/1``: see
#: :func:`result_kind`).
_LEGACY_KIND = {ROBOT_RESULT: "scara", MULTILATERATION_RESULT: "multilateration", VOLUMETRIC_RESULT: "volumetric"}
#: Kinds as a verb's message lists them.
_NAMES = {"scara": "SCARA", "serial": "serial-robot", "multilateration": "multilateration", "volumetric": "volumetric",
          "machine5": "five-axis machine"}


def _either(words) -> str:
    words = list(words)
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " or " + words[-1]


def kinds_text(kinds) -> str:
    """'SCARA, serial-robot and volumetric results' (for messages)."""
    names = [_NAMES[k] for k in kinds]
    return (names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]) + " results"


def result_kind(doc, name) -> str:
    """``"scara"``, ``"serial"``, ``"multilateration"`` or ``"volumetric"``: the kind of the result document
    ``doc`` read from the file ``name`` (module doc); InputError (one line naming the file) for a document that is
    not a result, an unknown ``kind``, or a ``kind`` its ``format`` does not carry."""
    name = os.fspath(name)
    fmt = doc.get("format") if isinstance(doc, dict) else None
    if fmt not in RESULT_FORMATS:
        raise InputError(f"{name}: 'format' must be {_either(repr(f) for f in RESULT_FORMATS)} for a result, "
                         f"got {fmt!r}")
    if "kind" not in doc:  # written before the 'kind' key: the kind as it was told then
        return "serial" if fmt == ROBOT_RESULT and isinstance(doc.get("robot"), dict) else _LEGACY_KIND[fmt]
    kind = doc["kind"]
    if kind not in RESULT_KINDS:
        raise InputError(f"{name}: key 'kind': unknown result kind {kind!r} (expected "
                         f"{_either(repr(k) for k in RESULT_KINDS)})")
    if RESULT_FORMAT[kind] != fmt:
        raise InputError(f"{name}: key 'kind' {kind!r} does not go with 'format' {fmt!r} (a {kind} result is "
                         f"{RESULT_FORMAT[kind]!r})")
    return kind


def read_result(path, kinds=None, user: str = "", refuse: bool = True) -> tuple:
    """``(kind, document)`` of any result file (JSON, checked as every JSON file; :func:`result_kind`).

    ``kinds``: the kinds the caller takes (a file that is not JSON is told which); another kind is refused
    (unless not ``refuse``) in one line naming the file, its kind and format, and what ``user`` (e.g.
    ``"olti predict"``) takes."""
    from olti_drake.io.csvio import read_json

    doc = read_json(path, None, _either(RESULT_WHAT[k] for k in kinds) if kinds else "a result")
    kind = result_kind(doc, path)
    if refuse and kinds is not None and kind not in kinds:
        raise not_taken(path, kind, doc, kinds, user)
    return kind, doc


def not_taken(path, kind: str, doc: dict, kinds, user: str = "") -> InputError:
    """The one-line refusal of a result of ``kind`` by a ``user`` that takes ``kinds`` only."""
    return InputError(f"{os.fspath(path)}: {RESULT_WHAT[kind]}, 'format' {doc['format']!r}: {user or 'this'} takes "
                      f"{kinds_text(kinds)}")


#: The common fields of every result document, in the order :func:`result_document` writes them (after
#: ``format``, ``kind`` and the kind's own values; before the kind's ``tail``). Optional ones (``smoothing``,
#: ``campaign``, ``resolution_check``, ``notes``) are left out when empty.
COMMON_FIELDS = ("gauge", "residual_rms_mm", "n_readings", "uncertainty", "iterations", "condition_number",
                 "solver", "outliers", "converged", "warnings", "smoothing", "campaign", "resolution_check", "notes")

#: How the standard uncertainties of an identification are obtained, unless the kind states its own
#: (the machine kinds name the budget propagated).
UNCERTAINTY_METHOD = ("linear propagation of the identification Jacobian (JCGM 100), residual-based reading "
                      "uncertainty")


def residual_rms(residuals) -> float:
    """RMS of the residuals (mm; 0 for none): a result's ``residual_rms_mm``."""
    import numpy as np

    r = np.asarray(residuals, float)
    return float(np.sqrt(np.mean(np.square(r)))) if r.size else 0.0


def result_document(kind: str, values: dict, fit, *, gauge: str, uncertainty: dict,
                    method: str = UNCERTAINTY_METHOD, n_readings=None, campaign=None, notes=(), tail=None,
                    empty_notes: bool = False) -> dict:
    """The one writer of a result document (issue 22): ``format`` and ``kind``, the kind's own ``values``,
    then the :data:`COMMON_FIELDS` in one order and one spelling, then the kind's ``tail``.

    ``values``: the kind's own keys (its parameters in its layout, e.g. ``model``/``L1_mm``/``error_map``/
    ``reflectors_mm`` of the SCARA, ``robot`` and the named errors of a serial robot, ``targets_mm`` and
    ``stations_mm`` of a multilateration, the ISO motions of a volumetric result). ``fit``: what every
    identification has -- the engine's :class:`~olti_drake.estimation.calibration.Fit` or the SCARA's
    ``Identification``: ``residuals`` (or ``residuals_mm``), ``iterations``, ``condition_number``, ``solver``,
    ``outliers``, ``converged_by``, ``warnings``, ``notes``, optionally ``smoothing`` (the maps' roughness prior)
    and ``resolution`` (an error map's under-resolution check). ``uncertainty``: the standard uncertainties
    (k = 1) in the kind's keys (``layout(std, uncertainty=True)``); ``k`` and ``method`` are added here.
    ``n_readings``: the readings identified from (default: one per residual). ``notes``: said after the fit's.
    ``tail``: the kind's keys written last (a serial robot's ``covariance``, ``priors``, ``dropped``).
    ``empty_notes``: write ``notes`` even when there are none (the volumetric result always had the key)."""
    if kind not in RESULT_FORMAT:
        raise ValueError(f"unknown result kind {kind!r} (expected {_either(repr(k) for k in RESULT_KINDS)})")
    residuals = getattr(fit, "residuals", None)
    if residuals is None:
        residuals = getattr(fit, "residuals_mm")
    out = {"format": RESULT_FORMAT[kind], "kind": kind,
           **{k: v for k, v in values.items() if k not in ("format", "kind")}}
    out["gauge"] = gauge
    out["residual_rms_mm"] = residual_rms(residuals)
    out["n_readings"] = int(len(residuals) if n_readings is None else n_readings)
    out["uncertainty"] = {**uncertainty, "k": 1, "method": method}
    out["iterations"] = int(fit.iterations)
    out["condition_number"] = float(fit.condition_number)
    out["solver"] = fit.solver
    out["outliers"] = list(fit.outliers)
    out["converged"] = fit.converged_by
    out["warnings"] = list(fit.warnings)
    smoothing = getattr(fit, "smoothing", None)
    if smoothing:  # the maps' roughness prior (method, weight, ...): olti uncertainty re-adds it
        out["smoothing"] = dict(smoothing)
    if campaign:
        out["campaign"] = campaign
    resolution = getattr(fit, "resolution", None)
    if resolution:
        out["resolution_check"] = resolution
    all_notes = list(fit.notes) + list(notes)
    if all_notes or empty_notes:
        out["notes"] = all_notes
    out.update(tail or {})
    return out


def with_kind(kind: str, doc: dict) -> dict:
    """``doc`` as a result of ``kind`` is written: ``format`` and ``kind`` first, then the rest in order."""
    if doc.get("format", RESULT_FORMAT[kind]) != RESULT_FORMAT[kind]:
        raise ValueError(f"a {kind} result is {RESULT_FORMAT[kind]!r}, not {doc['format']!r}")
    return {"format": RESULT_FORMAT[kind], "kind": kind, **{k: v for k, v in doc.items() if k not in
                                                             ("format", "kind")}}
