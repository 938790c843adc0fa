"""One identification type for every kind (issue 22 item 3): ``od.calibration_problem(...).fit()`` and
``problem.identification(result)`` return an :class:`olti_drake.Identification` whatever the kind -- the SCARA of
000, an N-joint robot, the 001 multilateration, the volumetric machine, a five-axis machine -- with the same
fields (names, x, std, covariance, residuals), and ``fit.document(path)`` / ``fit.write(path)`` give the file
``olti identify`` writes for that campaign. Campaigns are seeded random ones of truths outside the fitted family
(tests/io/test_result_kinds.py, tests/estimation/test_five_axis_identify.py)."""

import json

import numpy as np
import pytest

import olti_drake as od
from olti_drake.io.outputs import OutputError
from numeric_files import json_differences
from tests.estimation.test_five_axis_identify import SIX_TABLE_STATIONS, TRUNNION, distance_campaign
from tests.estimation.test_five_axis_uncertainty import identified
from tests.io.test_result_kinds import TOOL, TOOLS, campaigns, results  # noqa: F401 (module fixtures)

KINDS = ("scara", "serial", "multilateration", "volumetric", "machine5")
FIVE_AXIS = dict(machine=TRUNNION, workpiece_frame="workpiece", tool_frame="tool")


@pytest.fixture(scope="module")
def five_axis(tmp_path_factory):
    """(campaign, result written by ``olti identify --machine ... --model geometric``): 40 random commands from
    six table stations of a truth with error motions (outside the geometric family)."""
    from olti_drake.model.five_axis import FiveAxisMachine
    from olti_drake.model.five_axis_truth import synthetic_truth

    machine = FiveAxisMachine.from_file(TRUNNION, "workpiece", "tool")
    cols = distance_campaign(machine, synthetic_truth(machine, seed=3), 40, 2, SIX_TABLE_STATIONS, "workpiece")
    return identified(tmp_path_factory.mktemp("machine5"), cols, "--model", "geometric")


def _problem(kind, campaigns, five_axis):
    if kind == "scara":
        return od.calibration_problem(campaigns["scara"], model="errormap")
    if kind == "serial":
        return od.calibration_problem(campaigns["serial"], model="errormap", robot="ur5", tool_frame="tool0",
                                      tool_offset_mm=TOOL, grid_step_deg=30.0)
    if kind == "multilateration":
        return od.calibration_problem(campaigns["multilateration"], model="multilateration", gauge="best-fit")
    if kind == "volumetric":
        return od.calibration_problem(campaigns["volumetric"], model="volumetric",
                                      tool_offsets_mm=[list(t) for t in TOOLS])
    return od.calibration_problem(five_axis[0], model="geometric", **FIVE_AXIS)


def _cli_document(kind, results, five_axis) -> dict:
    path = five_axis[1] if kind == "machine5" else results[kind][0]
    return json.loads(path.read_text())


@pytest.fixture(scope="module")
def fits(campaigns, five_axis):
    """{kind: (problem, its fit())}."""
    out = {}
    for kind in KINDS:
        problem = _problem(kind, campaigns, five_axis)
        out[kind] = (problem, problem.fit())
    return out


@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_fits_to_the_one_type_with_the_same_fields(kind, fits):
    _, fit = fits[kind]
    assert type(fit) is od.Identification and fit.kind == kind
    n = len(fit.names)
    assert n > 0 and fit.x.shape == (n,) and fit.std.shape == (n,) and fit.covariance.shape == (n, n)
    assert np.all(np.isfinite(fit.std)) and np.all(fit.std >= 0)
    # std is the covariance's diagonal (k = 1), whichever kind computed it
    np.testing.assert_allclose(np.sqrt(np.diag(fit.covariance)), fit.std, rtol=1e-9, atol=1e-15)
    assert fit.residuals.ndim == 1 and fit.residuals.size > n // 4 and np.all(np.isfinite(fit.residuals))
    values, us = fit.values(), fit.uncertainties()
    assert list(values) == fit.names and values[fit.names[0]] == fit.x[0] and us[fit.names[-1]] == fit.std[-1]
    assert isinstance(fit.converged_by, str) and fit.converged_by
    assert fit.lack_of_fit_mm >= 0.0
    # The kind's own result is there, and its attributes read through (code written against it keeps working).
    assert fit.result is not None and kind in repr(fit)
    with pytest.raises(AttributeError):
        fit.no_such_field_anywhere


@pytest.mark.parametrize("kind", KINDS)
def test_the_document_is_the_file_olti_identify_writes(kind, fits, results, five_axis, tmp_path):
    """fit.document(path) against the CLI's result of the same campaign and options: every field equal, numbers
    within 1e-9 relative (the same fit; another process)."""
    _, fit = fits[kind]
    cli_path = five_axis[1] if kind == "machine5" else results[kind][0]
    mine = json.loads(json.dumps(fit.document(cli_path)))
    diffs = json_differences(mine, _cli_document(kind, results, five_axis), rel_tol=1e-9, abs_tol=1e-12)
    assert not diffs, diffs[:5]
    assert mine["kind"] == kind


@pytest.mark.parametrize("kind", ("serial", "machine5"))
def test_write_names_files_relative_to_where_it_writes_and_loads_back(kind, fits, tmp_path):
    """A result written elsewhere names its robot or machine file relative to its own folder and loads back into
    the verbs (olti validate / predict read it): written twice only with force, never over an input."""
    problem, fit = fits[kind]
    out = tmp_path / "deeper" / "r.json"
    out.parent.mkdir()
    assert fit.write(out) == str(out)
    doc = json.loads(out.read_text())
    assert doc["kind"] == kind
    from olti_drake.io.five_axis_io import load_machine5_result
    from olti_drake.io.serial_io import load_serial_result

    # the verbs' readers take it (they resolve the robot or machine file from the result's own folder)
    (load_serial_result if kind == "serial" else load_machine5_result)(str(out))
    before = out.read_bytes()
    with pytest.raises(OutputError, match="r.json"):
        fit.write(out)
    assert out.read_bytes() == before
    fit.write(out, force=True)
    with pytest.raises(OutputError):
        fit.write(problem.source, force=True)  # the campaign is an input: never replaced
    assert problem.inputs()[0] == problem.source


@pytest.mark.parametrize("kind", ("scara", "volumetric"))
def test_another_solver_gives_the_same_type_and_document(kind, fits, campaigns, five_axis):
    """Gauss-Newton through Clarabel on problem.prog, turned back by identification(): the same type, and a
    solution within 1 % of its own u of LM's (both stop at their own tolerance)."""
    from pydrake.solvers import ClarabelSolver

    problem = _problem(kind, campaigns, five_axis)
    ident = problem.identification(problem.gauss_newton(ClarabelSolver()))
    lm = fits[kind][1]
    assert type(ident) is od.Identification and ident.kind == kind and ident.names == lm.names
    assert np.max(np.abs(ident.x - lm.x) / lm.std) < 0.01
    np.testing.assert_allclose(ident.std, lm.std, rtol=1e-3)
    assert ident.converged_by and "given" in ident.solver
