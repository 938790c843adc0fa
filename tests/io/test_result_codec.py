"""One result codec (issue 22, item 2): every kind's result document is written by one function.

* :func:`olti_drake.io.documents.result_document` writes ``format``, ``kind``, the kind's own values and the common
  fields (:data:`~olti_drake.io.documents.COMMON_FIELDS`) in one order and one spelling; the four kinds' writers
  (SCARA, serial robot, multilateration, volumetric) call it -- through the library and through the CLI.
* A document of each kind round-trips through ``read_result`` and the kind's own loader, with its ``kind`` key and
  without it (a file written before the key).
* The result files shipped with the project (``data/``, ``tests/data/``) still load.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from olti_drake.io import documents
from olti_drake.io.documents import COMMON_FIELDS, read_result, result_document
from olti_drake.formats import RESULT_FORMAT, RESULT_FORMATS

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "data" / "paper000" / "campaign.csv"
TOOL = (40.0, -25.0, 60.0)
TOOLS = ((0.0, 0.0, 100.0), (150.0, 0.0, 100.0), (0.0, 150.0, 140.0))
KINDS = ("scara", "serial", "multilateration", "volumetric")
#: The common fields every identification's document has (the others only when not empty).
ALWAYS = ("gauge", "residual_rms_mm", "n_readings", "uncertainty", "iterations", "condition_number", "solver",
          "outliers", "converged", "warnings")
#: Spellings of the common fields the documents must not use.
OTHER_SPELLINGS = ("converged_by", "rms_mm", "residual_rms", "residuals_rms_mm", "n_rows", "readings", "condition",
                   "cond", "uncertainties", "std", "campaign_digest", "resolution", "warning", "note")


from tests.io.test_result_kinds import campaigns  # noqa: E402,F401 (the same seeded campaigns, a fixture)


def _library_document(kind, campaigns) -> dict:
    """The result document of ``kind`` by the library call of its writer (test_result_kinds' route)."""
    from tests.io.test_result_kinds import _todays_route

    return _todays_route(kind, campaigns, None)


class _Recorder:
    """``documents.result_document`` that records the kinds it wrote and the documents it returned."""

    def __init__(self):
        self.kinds, self.docs = [], []

    def __call__(self, kind, *args, **kw):
        doc = _ORIGINAL(kind, *args, **kw)
        self.kinds.append(kind)
        self.docs.append(doc)
        return doc


_ORIGINAL = result_document


@pytest.fixture(scope="module")
def written(campaigns):
    """{kind: document} by the library, each written by the one codec (recorded through a monkeypatch)."""
    mp = pytest.MonkeyPatch()
    rec = _Recorder()
    mp.setattr(documents, "result_document", rec)
    try:
        out = {}
        for kind in KINDS:
            n = len(rec.kinds)
            out[kind] = _library_document(kind, campaigns)
            assert rec.kinds[n:] == [kind], (kind, rec.kinds[n:])  # one call, of its kind
            assert rec.docs[-1] is out[kind]  # the document is the codec's, as it returned it
    finally:
        mp.undo()
    return out


def test_the_four_kinds_are_written_by_the_one_codec(written):
    assert sorted(written) == sorted(KINDS)
    for kind, doc in written.items():
        assert list(doc)[:2] == ["format", "kind"] and doc["format"] == RESULT_FORMAT[kind] and doc["kind"] == kind


def test_the_cli_routes_write_through_the_one_codec(campaigns, tmp_path, monkeypatch):
    from olti_drake.cli.verbs import main

    rec = _Recorder()
    monkeypatch.setattr(documents, "result_document", rec)
    tools = ";".join(",".join(str(v) for v in t) for t in TOOLS)
    argv = {"scara": ["identify", campaigns["scara"], "--model", "dh"],
            "serial": ["identify", campaigns["serial"], "--model", "dh", "--robot", "ur5", "--tool-frame", "tool0",
                       "--tool-offset-mm", "40,-25,60"],
            "multilateration": ["multilaterate", campaigns["multilateration"]],
            "volumetric": ["identify", campaigns["volumetric"], "--model", "volumetric", "--tool-offsets-mm", tools]}
    for kind, args in argv.items():
        out = tmp_path / f"{kind}.json"
        assert main([str(a) for a in args] + ["--out", str(out)]) == 0, kind
        assert rec.kinds[-1] == kind
        assert json.loads(out.read_text()) == json.loads(json.dumps(rec.docs[-1]))
    assert sorted(rec.kinds) == sorted(KINDS)


def test_the_common_fields_have_one_spelling_and_one_order(written):
    types = {"gauge": str, "residual_rms_mm": float, "n_readings": int, "uncertainty": dict, "iterations": int,
             "condition_number": float, "solver": str, "outliers": list, "converged": str, "warnings": list,
             "campaign": dict, "notes": list, "smoothing": dict, "resolution_check": dict}
    for kind, doc in json.loads(json.dumps(written)).items():
        for key in ALWAYS + ("campaign",):
            assert key in doc, (kind, key)
        for key in COMMON_FIELDS:
            if key in doc:
                assert isinstance(doc[key], types[key]), (kind, key, type(doc[key]))
        assert not [k for k in OTHER_SPELLINGS if k in doc], kind
        # the common fields in the codec's order, wherever the kind's own keys are
        assert [k for k in doc if k in COMMON_FIELDS] == [k for k in COMMON_FIELDS if k in doc], kind
        unc = doc["uncertainty"]
        assert unc["k"] == 1 and isinstance(unc["method"], str) and "JCGM 100" in unc["method"], kind
        assert list(unc)[-2:] == ["k", "method"], kind
        assert doc["residual_rms_mm"] >= 0 and doc["n_readings"] > 0 and doc["converged"], kind
        assert doc["campaign"]["sha256"], kind


def test_the_codec_itself():
    class FitLike:  # the SCARA's Identification spells its residuals residuals_mm
        residuals_mm = np.array([3.0, -4.0])
        iterations, condition_number, solver, outliers = np.int64(3), np.float64(12.5), "lm", []
        converged_by, warnings, notes = "gradient", [], []

    doc = result_document("scara", {"format": "x", "model": "dh", "L1_mm": 1.0}, FitLike(), gauge="g",
                          uncertainty={"L1_mm": 0.1, "k": 2})
    assert list(doc) == ["format", "kind", "model", "L1_mm"] + list(ALWAYS)
    assert doc["format"] == RESULT_FORMAT["scara"] and doc["residual_rms_mm"] == pytest.approx(np.sqrt(12.5))
    assert doc["n_readings"] == 2 and type(doc["iterations"]) is int and type(doc["condition_number"]) is float
    assert doc["uncertainty"] == {"L1_mm": 0.1, "k": 1, "method": documents.UNCERTAINTY_METHOD}
    doc = result_document("volumetric", {}, FitLike(), gauge="g", uncertainty={}, n_readings=7, empty_notes=True,
                          campaign={"readings": 7}, notes=["n"], tail={"extra": 1})
    assert doc["n_readings"] == 7 and doc["notes"] == ["n"] and list(doc)[-3:] == ["campaign", "notes", "extra"]
    assert result_document("volumetric", {}, FitLike(), gauge="g", uncertainty={}, empty_notes=True)["notes"] == []
    with pytest.raises(ValueError, match="unknown result kind"):
        result_document("robot", {}, FitLike(), gauge="g", uncertainty={})


def _load_by_kind(kind, path):
    """The kind's own loader (it checks the schema)."""
    if kind == "scara":
        from olti_drake.io.result import load_result

        return load_result(path)
    if kind == "serial":
        from olti_drake.io.serial_io import load_serial_result

        return load_serial_result(path)
    if kind == "multilateration":
        from olti_drake.estimation.multilateration import load_result

        return load_result(path)
    from olti_drake.io.volumetric_io import load_volumetric_result

    return load_volumetric_result(path)


@pytest.mark.parametrize("kind", KINDS)
def test_a_document_of_each_kind_round_trips_through_read_result(kind, written, tmp_path):
    from olti_drake.io.outputs import write_json

    doc = written[kind]
    path = tmp_path / "result.json"
    write_json(path, doc)
    got_kind, got = read_result(path)
    assert got_kind == kind and got == json.loads(json.dumps(doc))
    _load_by_kind(kind, path)
    # as a file written before the 'kind' key: the kind told from the format (and the robot object) as then
    legacy = {k: v for k, v in got.items() if k != "kind"}
    old = tmp_path / "legacy.json"
    old.write_text(json.dumps(legacy))
    assert read_result(old) == (kind, legacy)
    _load_by_kind(kind, old)


def test_shipped_result_files_still_load():
    files = [p for d in ("data", "tests/data") for p in sorted((ROOT / d).rglob("*.json"))]
    results = [p for p in files if json.loads(p.read_text()).get("format") in RESULT_FORMATS]
    assert results, "no shipped result file found"  # data/paper000/truth.json at least
    for path in results:
        kind, doc = read_result(path)
        assert kind in KINDS
        _load_by_kind(kind, path)
