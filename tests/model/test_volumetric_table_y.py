"""The volumetric topology ``table-y`` (the table carries Y; the column X and the ram Z on it carry the tool): the
linear axes of the shipped A/C trunnion (``models/trunnion_ac.urdf``), issue 25 item 2.

Its representation is the 3-axis model's one chain (:mod:`olti_drake.model.volumetric3d`) with that stacking:
checked against an independent composition of the motions' homogeneous transforms (scipy rotations), by its Abbe
arms (what each carriage's rotation swings), and by its Jacobians; a simulated 3-axis campaign of the trunnion's
linear axes (sines, outside the B-spline family) identified with ``--topology table-y`` recovers every motion
within its stated u; that result is taken by ``--linear`` for the trunnion (its motions moving the five-axis tool
point as the volumetric model does, to 1e-9 mm) and refused, in one line naming both stackings, for the serial
swivel head."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from olti_drake.errors import InputError
from olti_drake.model.volumetric3d import (AXES, COMPONENTS, TOPOLOGIES, URAD, MachineConfig, VolumetricModel,
                                           chain_state, command_jacobian, synthetic_truth, tool_positions)
from olti_calls import error_line, olti_in
from tests.model.test_five_axis_linear import SWIVEL, TOOLS, TRUNNION, commands, identified_linear

TABLE_Y = dict(zip(("tool_chain", "work_chain"), TOPOLOGIES["table-y"]))
TRAVEL = {"X": (-300.0, 300.0), "Y": (-250.0, 250.0), "Z": (0.0, 450.0)}  # (the trunnion's)


def config(**kw):
    return MachineConfig(**{**TABLE_Y, "travel_mm": TRAVEL, "knot_spacing_mm": 150.0, "tool_offsets_mm": TOOLS,
                            **kw})


def random_commands(cfg, n, seed):
    lo, hi = (np.array([cfg.travel_mm[a][e] for a in AXES]) for e in (0, 1))
    rng = np.random.default_rng(seed)
    return rng.uniform(lo, hi, (n, 3)), rng.integers(0, len(cfg.tools), n)


def composed(cfg, motions, c, tool):
    """Tool points (M, 3) mm by the 4x4 product A_Y(q) A_X(q) A_Z(q) [t; 1], workpiece to tool, written out here:
    A_k = Trans(q_k s_k + δ_k) Rx Ry Rz(ε_k), s_Y = Rz(E_C0Y) e_y, s_Z = Ry(E_B0Z) Rx(E_A0Z) e_z
    (docs/machine_3d.md)."""
    c0y, b0z, a0z = np.asarray(motions.squareness_urad, float) * URAD
    s = {"X": np.eye(3)[0], "Y": Rotation.from_euler("z", c0y).apply(np.eye(3)[1]),
         "Z": Rotation.from_euler("YX", [b0z, a0z]).apply(np.eye(3)[2])}
    T = np.broadcast_to(np.eye(4), (len(c), 4, 4))
    for a in ("Y", "X", "Z"):  # (the work chain reversed, then the tool chain)
        q = c[:, AXES.index(a)]
        e = motions.evaluate(a, q)
        A = np.tile(np.eye(4), (len(c), 1, 1))
        A[:, :3, :3] = Rotation.from_euler("XYZ", e[:, 3:] * URAD).as_matrix()  # (intrinsic: Rx Ry Rz)
        A[:, :3, 3] = q[:, None] * s[a] + e[:, :3]
        T = T @ A
    t = cfg.tools[tool] + motions.tool_offset_errors_mm[tool]
    return np.einsum("mij,mj->mi", T[:, :3, :3], t) + T[:, :3, 3]


def test_table_y_is_the_trunnions_stacking():
    from olti_drake.cli.verbs import build_parser
    from olti_drake.model.five_axis import FiveAxisMachine
    from olti_drake.model.five_axis_errors import linear_config

    trunnion = linear_config(FiveAxisMachine.from_file(TRUNNION))
    assert (trunnion.tool_chain, trunnion.work_chain) == TOPOLOGIES["table-y"] and trunnion.topology == "table-y"
    assert config().chain == ("Y", "X", "Z")
    assert linear_config(FiveAxisMachine.from_file(SWIVEL)).topology == "serial"
    identify = build_parser()._subparsers._group_actions[0].choices["identify"]
    choices = next(a.choices for a in identify._actions if a.dest == "topology")
    assert tuple(choices) == tuple(TOPOLOGIES)  # (the CLI offers every named stacking, no other)


def test_the_chain_is_the_composition_of_the_motions():
    cfg = config()
    truth = synthetic_truth(cfg, 3, amplitude_urad=300.0, squareness_urad=(400.0, -300.0, 250.0))
    c, tool = random_commands(cfg, 40, 1)
    np.testing.assert_allclose(tool_positions(cfg, truth, c, tool), composed(cfg, truth, c, tool), atol=1e-9)
    other = MachineConfig(**{**cfg.__dict__, "tool_chain": ("X", "Y", "Z"), "work_chain": ()})
    assert np.abs(tool_positions(other, truth, c, tool) - composed(cfg, truth, c, tool)).max() > 1e-3


@pytest.mark.parametrize("name, swings", [("E_CY", "X"), ("E_AY", "Z"), ("E_AX", "Z"), ("E_AZ", "")])
def test_each_carriage_swings_what_it_carries(name, swings):
    """An angular motion of a carriage rotates what is downstream of it in the chain workpiece, Y, X, Z, tool:
    Y's yaw (the table) swings the X travel, its pitch the Z travel; X's roll (the column) the Z travel but not the
    table's Y (on a serial X-Y-Z machine it would); Z's tilt (the ram) the tool only. A 30 µrad constant beyond the
    first knot, the carriage and one other axis at their travel ends (tool 0 at the chain's point)."""
    cfg = config(tool_offsets_mm=((0.0, 0.0, 0.0),))
    model = VolumetricModel(cfg)
    x = model.zeros()
    x[model.slices[name]] = 30.0
    for k, a in enumerate(AXES):
        c = np.zeros((1, 3))
        c[0, k] = cfg.travel_mm[a][1]
        c[0, AXES.index(name[3])] = cfg.travel_mm[name[3]][1]  # (the rotating carriage at its travel end)
        moved = model.positions(c, 0, x)[0] - model.positions(c, 0, model.zeros())[0]
        swung = a in swings  # (the tool at the chain's point: the carriage's own travel is not swung)
        assert (np.linalg.norm(moved) > 1e-3) == swung, (a, moved)
    if name == "E_AX":  # (the contrast: on the serial stacking, Y rides on X)
        serial = VolumetricModel(config(tool_chain=("X", "Y", "Z"), work_chain=(), tool_offsets_mm=((0, 0, 0),)))
        x = serial.zeros()
        x[serial.slices[name]] = 30.0
        c = np.array([[300.0, 250.0, 0.0]])
        assert np.linalg.norm(serial.positions(c, 0, x) - serial.positions(c, 0, serial.zeros())) > 1e-3


def test_the_drake_diagram_reads_what_the_numpy_twin_reads():
    """The 3D campaign's Drake diagram on the table-y stacking: the rows, readings (to 1e-9 mm) and truth of the
    numpy twin (tests/sim/test_machine3d_diagram.py's check, on this chain)."""
    from tests.sim.test_machine3d_diagram import test_diagram_reads_what_the_numpy_twin_reads as diagram_reads_the_twin

    diagram_reads_the_twin(TOPOLOGIES["table-y"])


def test_jacobians_match_finite_differences():
    cfg = config()
    model = VolumetricModel(cfg, identify_tool_offsets=True)
    c, tool = random_commands(cfg, 12, 2)
    x = np.random.default_rng(3).standard_normal(model.n_params) * 5.0
    p, J = model.jacobian(c, tool, x)
    h = 1e-3
    fd = np.stack([(model.positions(c, tool, x + h * e) - model.positions(c, tool, x - h * e)) / (2 * h)
                   for e in np.eye(model.n_params)], axis=-1)
    np.testing.assert_allclose(J, fd, atol=1e-9)
    motions = synthetic_truth(cfg, 4)
    c = c * 0.99  # (a step either way stays within the travel)
    Jc = command_jacobian(cfg, motions, chain_state(cfg, motions, c, tool))
    for k in range(3):
        d = np.eye(3)[k] * 1e-3
        fd = (tool_positions(cfg, motions, c + d, tool) - tool_positions(cfg, motions, c - d, tool)) / 2e-3
        np.testing.assert_allclose(Jc[:, :, k], fd, atol=1e-9)


# ----------------------------------------------------------------------------------------------- the trunnion
@pytest.fixture(scope="module")
def trunnion():
    from olti_drake.model.five_axis import FiveAxisMachine

    return FiveAxisMachine.from_file(TRUNNION)


@pytest.fixture(scope="module")
def trunnion_result(trunnion, tmp_path_factory):
    """(path, truth): ``olti identify --model volumetric --topology table-y`` of a simulated 3-axis campaign of the
    trunnion's linear axes (:func:`test_five_axis_linear.identified_linear`)."""
    return identified_linear(trunnion, tmp_path_factory.mktemp("table_y"), seed=4)


def test_table_y_identification_recovers_every_motion_within_its_u(trunnion_result):
    from olti_drake.io.volumetric_io import load_volumetric_result

    path, truth = trunnion_result
    res = load_volumetric_result(path)
    assert res.doc["topology"] == {"tool_chain": ["X", "Z"], "work_chain": ["Y"]} and not res.doc["held_motions"]
    z = []
    for name, entry in res.doc["error_motions"].items():
        q, u = np.array(entry["positions_mm"]), np.array(res.doc["uncertainty"]["error_motions"][name])
        err = np.array(entry["values"]) - truth.evaluate(name[3], q)[:, COMPONENTS.index(name[2])]
        z.append(err[u > 0] / u[u > 0])
    z = np.concatenate(z)
    rms = float(np.sqrt(np.mean(z ** 2)))
    print(f"\ntable-y volumetric fit: max |error|/u {np.abs(z).max():.2f}, RMS {rms:.2f} over {z.size} values")
    assert np.abs(z).max() < 4.0 and 0.3 < rms < 2.0, (np.abs(z).max(), rms)


def test_linear_from_the_table_y_result_moves_the_trunnion_tool_as_the_volumetric_model(trunnion, trunnion_result):
    """``--linear``'s motions (load_linear_from: relocated about the loop's carriage frames) in the five-axis loop
    move the tool points of the 3 tools as the volumetric model of the same result does, to 1e-9 mm, at random
    linear commands (rotary axes at 0: the volumetric model has none)."""
    from olti_drake.io.five_axis_io import load_linear_from
    from olti_drake.io.volumetric_io import load_volumetric_result
    from olti_drake.model.five_axis_errors import FiveAxisErrors, FiveAxisPositionModel

    path, _ = trunnion_result
    vol = load_volumetric_result(path)
    c = commands(trunnion, 300, 5, rotary_zero=True)
    tool = np.arange(len(c)) % len(TOOLS)
    tools = np.asarray(vol.doc["tool_offsets_mm"])  # (as identified: the configured ones and their errors)
    linear = load_linear_from(path, trunnion, c, "the commands").motions
    errors = FiveAxisErrors(trunnion, location=False, motions=False, linear=linear, tool_offsets_mm=tools)
    five = FiveAxisPositionModel(trunnion, errors, c, tool=tool)
    deviation = five.positions(np.zeros(five.n_params)) - trunnion.tool_points(c) - tools[tool]
    volumetric = vol.model.positions(c[:, :3], tool, vol.params) - c[:, :3] - tools[tool]
    assert np.abs(volumetric).max() > 5e-3  # (the motions are there: µm-sized, with 190 mm Abbe arms)
    np.testing.assert_allclose(deviation, volumetric, atol=1e-9)


def test_a_result_of_another_topology_is_refused_in_one_line(trunnion_result, tmp_path, capsys):
    """The trunnion's table-y result for the serial swivel head: one line naming both stackings and the
    --topology that gives the head's; the API refuses it the same way."""
    from olti_drake.io.five_axis_io import load_linear_from, write_five_axis_campaign
    from olti_drake.model.five_axis import FiveAxisMachine
    from olti_drake.model.five_axis_truth import synthetic_truth as five_truth
    from tests.estimation.test_five_axis_identify import distance_campaign

    swivel = FiveAxisMachine.from_file(SWIVEL)
    write_five_axis_campaign(tmp_path / "c.csv", distance_campaign(swivel, five_truth(swivel, seed=1), 6, 1))
    code, out, err = olti_in("identify", tmp_path / "c.csv", "--machine", SWIVEL, "--model", "geometric",
                          "--linear", trunnion_result[0], "--out", tmp_path / "r.json", capsys=capsys)
    error_line(code, err)
    assert err.startswith("error: --linear "), err
    assert ("tool_chain ['X', 'Z'], work_chain ['Y'] (--topology table-y)" in err
            and "tool_chain ['X', 'Y', 'Z'], work_chain [] (--topology serial)" in err), err
    assert not (tmp_path / "r.json").exists()
    with pytest.raises(InputError, match=r"\(--topology table-y\).*\(--topology serial\)"):
        load_linear_from(trunnion_result[0], swivel)


def test_olti_identify_takes_the_table_y_result_for_the_trunnion(trunnion, trunnion_result, tmp_path, capsys):
    """``olti identify --machine trunnion_ac.urdf --workpiece-frame workpiece --tool-frame tool --model geometric
    --linear vol.json``: exit 0, the result names the file by its sha256, and load_machine5_result rebuilds the
    model with the table-y motions (its tool points differ from the perfect linear axes' by the motions' µm)."""
    from olti_drake.io.five_axis_io import file_sha256, load_machine5_result, write_five_axis_campaign
    from olti_drake.model.five_axis_errors import (FiveAxisErrors, FiveAxisPositionModel, RelocatedMotions,
                                                   carriage_offsets)
    from olti_drake.model.five_axis_truth import synthetic_truth as five_truth
    from tests.estimation.test_five_axis_identify import TABLE_STATIONS, distance_campaign, no_dropped_truth

    truth = no_dropped_truth(five_truth(trunnion, seed=2, motions=False))
    truth.linear = RelocatedMotions(trunnion_result[1], carriage_offsets(trunnion))
    write_five_axis_campaign(tmp_path / "c.csv", distance_campaign(trunnion, truth, 40, 3, TABLE_STATIONS,
                                                                   "workpiece"))
    code, _, err = olti_in("identify", tmp_path / "c.csv", "--machine", TRUNNION, "--workpiece-frame",
                        "workpiece", "--tool-frame", "tool", "--model", "geometric", "--linear", trunnion_result[0],
                        "--out", tmp_path / "r.json", capsys=capsys)
    assert code == 0, err
    res = load_machine5_result(tmp_path / "r.json")
    assert res.document["linear_from"]["sha256"] == file_sha256(trunnion_result[0])
    print(f"\ntrunnion geometric with --linear: residual RMS {1e3 * res.document['residual_rms_mm']:.2f} um")
    assert res.document["residual_rms_mm"] < 2e-3  # (1 µm noise; 4.8 µm without --linear)
    c = commands(trunnion, 20, 6) * 0.9
    perfect = FiveAxisPositionModel(trunnion, FiveAxisErrors(trunnion, motions=False), c, held=res.held)
    assert np.abs(res.position_model(c).positions(res.x) - perfect.positions(res.x)).max() > 1e-3
