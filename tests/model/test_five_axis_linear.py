"""Linear axes of a five-axis machine from an earlier volumetric result (issue 25 item 2: ``olti identify --machine
... --linear RESULT.json``): the volumetric motions re-expressed about the loop's carriage frames match the 3-axis
model's kinematics, a volumetric identification of a simulated 3-axis campaign carries over to the five-axis
identification of a thin campaign of the same machine, and what does not fit is refused in one line.

The truth: the linear axes' motions of :func:`olti_drake.model.volumetric3d.synthetic_truth` (sums of sines, in the
volumetric model's convention) and the rotary location errors of
:func:`olti_drake.model.five_axis_truth.synthetic_truth`, on the shipped swivel-head B/C machine (serial X-Y-Z)."""

import json
from importlib.resources import files

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.io.budget import default_budget
from olti_drake.io.csvio import write_machine_campaign
from olti_drake.io.five_axis_io import load_linear_from, load_machine5_result, write_five_axis_campaign
from olti_drake.model.budget import ReadingErrors
from olti_drake.model.five_axis import FiveAxisMachine
from olti_drake.model.five_axis_errors import (FiveAxisErrors, FiveAxisPositionModel, RelocatedMotions,
                                               carriage_offsets, linear_config)
from olti_drake.model.five_axis_truth import synthetic_truth
from olti_drake.model.volumetric3d import MachineConfig, tool_positions
from olti_drake.model.volumetric3d import synthetic_truth as linear_truth
from tests.estimation.test_five_axis_identify import distance_campaign, no_dropped_truth
from olti_calls import error_line, olti_in

MODELS = files("olti_drake") / "models"
SWIVEL = str(MODELS / "swivel_head_bc.urdf")
TRUNNION = str(MODELS / "trunnion_ac.urdf")
#: The 3-axis campaign's tools, relative to the spindle reference point (the five-axis tool frame's origin), mm.
TOOLS = ((0.0, 0.0, -150.0), (150.0, 0.0, -150.0), (0.0, 150.0, -190.0))
STATIONS_3D = np.array([[-700, -600, -300], [800, -550, -250], [700, 650, 150], [-650, 600, 250], [0, 0, 700]], float)
BED = np.array([[-900.0, -700.0, 900.0], [900.0, -650.0, 950.0], [850.0, 700.0, 1100.0], [-800.0, 750.0, 1000.0]])
TABLE = np.array([[-700.0, -650.0, 40.0], [720.0, -680.0, 90.0], [680.0, 700.0, 60.0], [-710.0, 690.0, 120.0]])


def commands(machine, n, seed, rotary_zero=False):
    rng = np.random.default_rng(seed)
    c = rng.uniform(machine.lower, machine.upper, (n, len(machine.axes)))
    if rotary_zero:
        c[:, 3:] = 0.0
    return c


@pytest.mark.parametrize("model", [SWIVEL, TRUNNION])
def test_relocated_motions_move_the_tool_as_the_volumetric_model(model):
    """At zero rotary commands the five-axis loop with the relocated motions moves the tool point (the tool frame's
    origin) as volumetric3d's chain does with the same motions, to rounding; the motions taken as they are would
    not (their angular motions turn about other points)."""
    m = FiveAxisMachine.from_file(model)
    cfg = linear_config(m)
    motions = linear_truth(cfg, 5)
    c = commands(m, 200, 1, rotary_zero=True)
    volumetric = tool_positions(cfg, motions, c[:, :3], np.zeros(len(c), int)) - c[:, :3]
    for linear, close in ((RelocatedMotions(motions, carriage_offsets(m)), True), (motions, False)):
        pm = FiveAxisPositionModel(m, FiveAxisErrors(m, location=False, motions=False, linear=linear), c)
        diff = np.abs(pm.positions(np.zeros(pm.n_params)) - m.tool_points(c) - volumetric).max()
        assert (diff < 1e-9) if close else (diff > 1e-3), diff


def test_relocated_motions_derivative_is_their_slope():
    """The command Jacobian reads the motions' derivative in q: the relocated one's matches finite differences."""
    m = FiveAxisMachine.from_file(TRUNNION)
    moved = RelocatedMotions(linear_truth(linear_config(m), 5), carriage_offsets(m))
    for a in "XYZ":
        q, h = np.linspace(*linear_config(m).travel_mm[a], 7)[1:-1], 1e-4
        slope = (moved.evaluate(a, q + h) - moved.evaluate(a, q - h)) / (2 * h)
        np.testing.assert_allclose(moved.evaluate(a, q, derivative=1), slope, atol=1e-8)


# ----------------------------------------------------------------------------------------------- the flow
@pytest.fixture(scope="module")
def swivel():
    return FiveAxisMachine.from_file(SWIVEL)


def identified_linear(machine, directory, seed=7, knot_spacing_mm=200.0, n=150):
    """(path, truth motions): ``olti identify --model volumetric --topology <the machine's>`` on a simulated 3-axis
    campaign of the machine's linear axes (the travel's corners and ``n`` random commands, 3 tools, 5 stations, 001
    Table 4 noise; knots every ``knot_spacing_mm``): the truth :func:`linear_truth` on those knots (sines of periods
    >= 4 intervals: outside the spline family), in the volumetric model's convention."""
    from olti_drake.cli.verbs import main

    cfg = linear_config(machine)
    cfg = MachineConfig(cfg.tool_chain, cfg.work_chain, cfg.travel_mm, knot_spacing_mm, TOOLS)
    motions = linear_truth(cfg, seed, amplitude_urad=20.0)
    rng = np.random.default_rng(seed + 1)
    lo, hi = (np.array([cfg.travel_mm[a][e] for a in "XYZ"]) for e in (0, 1))
    corners = [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    c = np.vstack([corners, rng.uniform(lo, hi, (n, 3))])
    cmd, tool = np.tile(c, (3, 1)), np.repeat(np.arange(3), len(c))
    D = np.linalg.norm(tool_positions(cfg, motions, cmd, tool)[:, None] - STATIONS_3D[None], axis=-1)
    reading = D - 0.5 + ReadingErrors(default_budget("machine")).draw(rng, D.ravel(), 1)[0].reshape(D.shape)
    i, j = np.repeat(np.arange(len(cmd)), len(STATIONS_3D)), np.tile(np.arange(len(STATIONS_3D)), len(cmd))
    write_machine_campaign({"station": j, "target": i, "x_cmd_mm": cmd[i, 0], "y_cmd_mm": cmd[i, 1],
                            "z_cmd_mm": cmd[i, 2], "tool": tool[i], "displacement_mm": reading.ravel()},
                           directory / "campaign3.csv")
    code = main(["identify", str(directory / "campaign3.csv"), "--model", "volumetric", "--topology", cfg.topology,
                 "--tool-offsets-mm", ";".join(",".join(f"{v:g}" for v in t) for t in TOOLS),
                 "--knot-spacing-mm", f"{knot_spacing_mm:g}", "--out", str(directory / "vol.json")])
    assert code == 0
    return directory / "vol.json", motions


@pytest.fixture(scope="module")
def volumetric_result(swivel, tmp_path_factory):
    """:func:`identified_linear` of the swivel head's (serial X-Y-Z) linear axes."""
    return identified_linear(swivel, tmp_path_factory.mktemp("vol"))


@pytest.fixture(scope="module")
def thin_campaign(swivel, volumetric_result, tmp_path_factory):
    """(campaign, truth, the result with --linear, the result without): a thin five-axis campaign (60 poses from
    4 stations on the bed and 4 riding on the table) of the truth -- location errors of the rotary axes, the
    volumetric truth's linear motions about the loop's carriage frames -- identified (geometric) through the
    command line with ``--linear`` and through the API without."""
    from olti_drake.cli.verbs import main

    truth = synthetic_truth(swivel, seed=4, motions=False)
    truth.linear = RelocatedMotions(volumetric_result[1], carriage_offsets(swivel))
    d = tmp_path_factory.mktemp("five")

    def write(t, name):
        a = distance_campaign(swivel, t, 60, 2, BED, "base")
        b = distance_campaign(swivel, t, 60, 3, TABLE, "workpiece")
        b["station"] = b["station"] + len(BED)
        write_five_axis_campaign(d / name, {k: list(a[k]) + list(b[k]) for k in a})
        return d / name

    first = identify(swivel, write(truth, "first.csv"))  # (what it drops depends on commands and stations only)
    truth = no_dropped_truth(truth, tuple(first["dropped"]))
    path = write(truth, "campaign.csv")
    assert main(["identify", str(path), "--machine", SWIVEL, "--model", "geometric", "--linear",
                 str(volumetric_result[0]), "--out", str(d / "with.json")]) == 0
    return path, truth, d / "with.json", identify(swivel, path)


def identify(machine, path, **options):
    """The olti-machine5/1 document of a geometric identification through the API."""
    from olti_drake.estimation.five_axis import FiveAxisIdentification, FiveAxisOptions
    from olti_drake.io.five_axis_io import machine5_result_dict, read_five_axis_campaign

    ident = FiveAxisIdentification(read_five_axis_campaign(path, machine), machine,
                                   FiveAxisOptions(model="geometric", **options))
    return json.loads(json.dumps(machine5_result_dict(ident, ident.fit(), SWIVEL)))


def z_scores(doc, truth):
    """|identified − true| / u per identified location error of a result document (held ones excluded)."""
    u = doc["uncertainty"]["location_errors"]
    return {n: abs(v - truth.location[n]) / u[n] for n, v in doc["location_errors"].items() if n not in doc["dropped"]}


def test_linear_axes_from_the_volumetric_result_recover_the_location_errors(thin_campaign, volumetric_result):
    _, truth, with_path, without = thin_campaign
    with_linear = json.loads(with_path.read_text())
    z_with, z_without = z_scores(with_linear, truth), z_scores(without, truth)
    assert len(z_with) == 7 and max(z_with.values()) < 3.0, z_with
    assert with_linear["dropped"] == without["dropped"]  # (what a campaign separates is structural)
    # the errors in units of the --linear result's u, both ways (without, the misfit also inflates its own u)
    u = with_linear["uncertainty"]["location_errors"]
    rms = {k: float(np.sqrt(np.mean([((doc["location_errors"][n] - truth.location[n]) / u[n]) ** 2 for n in z_with])))
           for k, doc in (("with", with_linear), ("without", without))}
    assert rms["with"] < 0.5 * rms["without"], (rms, z_with, z_without)
    from olti_drake.io.five_axis_io import file_sha256

    assert with_linear["linear_from"]["sha256"] == file_sha256(volumetric_result[0]) and "linear_from" not in without
    assert any(n.startswith("linear axes:") and "held fixed, not estimated" in n for n in with_linear["notes"])


def test_the_volumetric_uncertainty_is_carried_into_the_result(swivel, thin_campaign, volumetric_result):
    """The u with --linear holds the volumetric result's own: larger than the same identification's u with the
    linear motions taken as exact (fit without the propagation)."""
    from olti_drake.estimation.calibration import Calibration
    from olti_drake.estimation.five_axis import FiveAxisIdentification, FiveAxisOptions
    from olti_drake.io.five_axis_io import read_five_axis_campaign

    ident = FiveAxisIdentification(read_five_axis_campaign(thin_campaign[0], swivel), swivel,
                                   FiveAxisOptions(model="geometric", linear=str(volumetric_result[0])))
    exact = Calibration.fit(ident)
    doc = json.loads(thin_campaign[2].read_text())
    loc = ident.layout(exact.std)["location_errors"]
    ratio = {n: doc["uncertainty"]["location_errors"][n] / loc[n] for n in loc if n not in doc["dropped"]}
    assert min(ratio.values()) >= 1.0 - 1e-9 and max(ratio.values()) > 1.2, ratio


def test_the_result_carries_the_linear_axes_into_predictions(swivel, thin_campaign, volumetric_result):
    """load_machine5_result rebuilds the model with the volumetric motions (the file checked by its sha256): its
    tool points at the identified values are the model's with those motions, not the perfect linear axes'."""
    res = load_machine5_result(thin_campaign[2])
    c = commands(swivel, 30, 9) * 0.9
    pm = res.position_model(c)
    known = load_linear_from(volumetric_result[0], swivel).motions
    ref = FiveAxisPositionModel(swivel, FiveAxisErrors(swivel, motions=False, linear=known), c, held=res.held)
    np.testing.assert_allclose(pm.positions(res.x), ref.positions(res.x), atol=1e-12)
    perfect = FiveAxisPositionModel(swivel, FiveAxisErrors(swivel, motions=False), c, held=res.held)
    assert np.abs(pm.positions(res.x) - perfect.positions(res.x)).max() > 1e-3


def test_what_does_not_fit_is_refused_in_one_line(swivel, thin_campaign, volumetric_result, tmp_path, capsys):
    path, vol_path = thin_campaign[0], volumetric_result[0]
    code, _, err = olti_in("identify", path, "--machine", SWIVEL, "--model", "geometric", "--linear",
                           thin_campaign[2], "--out", tmp_path / "r.json", capsys=capsys)
    error_line(code, err, "'format' must be 'olti-volumetric/1'")
    code, _, err = olti_in("identify", path, "--model", "volumetric", "--linear", vol_path, "--out",
                           tmp_path / "v.json", capsys=capsys)
    error_line(code, err, "--linear", "--machine")
    beyond = commands(swivel, 5, 10)
    beyond[2, 0] = 450.0  # (the volumetric travel of X: the machine's, [-400, 400] mm)
    with pytest.raises(InputError, match=r"travel_mm X \[-400, 400\] does not cover the X commands of the "
                                         r"points, \[.*, 450\] mm"):
        load_linear_from(vol_path, swivel, beyond, "the points")
    doc = json.loads(vol_path.read_text())
    doc["topology"] = {"tool_chain": ["Z"], "work_chain": ["Y", "X"]}
    (tmp_path / "table.json").write_text(json.dumps(doc))
    with pytest.raises(InputError,
                       match=r"topology tool_chain \['Z'\], work_chain \['Y', 'X'\] \(--topology table-xy\)"):
        load_linear_from(tmp_path / "table.json", swivel)
    # (the trunnion: X, Z on the head, Y on the table)
    with pytest.raises(InputError, match=r"\(--topology serial\); machine model .* \(--topology table-y\)$"):
        load_linear_from(vol_path, FiveAxisMachine.from_file(TRUNNION))


def test_identified_linear_axes_are_held_motion_by_motion():
    """The linear axes identified with the rotary ones (``FiveAxisErrors(linear="identify")``): what a campaign
    cannot separate is held motion by motion, each named with its reason -- a single tool on the spindle axis
    reads no roll of Z, a straightness trades with its own tilt -- not the 18 motions and 3 squareness errors at
    once as one group (before: 'linear: trades with the measurement's gauge', all 87 parameters held)."""
    from olti_drake.model.five_axis_errors import separable
    from olti_drake.model.volumetric3d import ALL_MOTIONS, SQUARENESS
    from tests.estimation.test_five_axis_identify import SIX_TABLE_STATIONS

    m = FiveAxisMachine.from_file(TRUNNION)
    rng = np.random.default_rng(11)
    c, d = rng.uniform(m.lower, m.upper, (200, 5)), rng.choice([-1.0, 1.0], (200, 2))
    em = FiveAxisErrors(m, motions=False, linear="identify", knot_spacing_mm=200.0)
    sep = separable(FiveAxisPositionModel(m, em, c, d), np.asarray(SIX_TABLE_STATIONS))
    linear = [g for g in sep.dropped if g in ALL_MOTIONS or g[:-5] in SQUARENESS]
    assert "linear" not in sep.dropped and 1 <= len(linear) <= 8, sep.dropped
    assert "E_CZ" in linear and sep.reasons["E_CZ"] == "no reading depends on it"
    kept = [g for g in ALL_MOTIONS if g not in linear] + [f"{q}_urad" for q in SQUARENESS if f"{q}_urad" not in linear]
    assert len(kept) >= 13 and all(sep.separable[g] for g in kept)
    held = FiveAxisPositionModel(m, em, c, d, held=sep.dropped)
    assert held.n_params == em.n_params - sum(em.slices[g].stop - em.slices[g].start if g in em.slices else 1
                                              for g in sep.dropped)
