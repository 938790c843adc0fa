"""The five-axis machine model (issue 25, items 1-2): the numpy twin equals Drake, the analytic Jacobian equals
finite differences, bad model files are refused in one line, the synthetic truth is outside the model family, and
a least-squares fit recovers the location errors."""

import re
from importlib.resources import files

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.model.five_axis import FiveAxisMachine
from olti_drake.model.five_axis_errors import (FiveAxisErrors, FiveAxisPositionModel, location_names, node_grid,
                                               separable)
from olti_drake.model.five_axis_truth import synthetic_truth
from olti_drake.model.measurements import StationDistanceMeasurement
from olti_drake.threads import single_thread_blas

MODELS = files("olti_drake") / "models"
TRUNNION = str(MODELS / "trunnion_ac.urdf")
SWIVEL = str(MODELS / "swivel_head_bc.urdf")


@pytest.fixture(scope="module")
def trunnion():
    return FiveAxisMachine.from_file(TRUNNION, "workpiece", "tool")


@pytest.fixture(scope="module")
def swivel():
    return FiveAxisMachine.from_file(SWIVEL, "workpiece", "tool")


def commands(machine, n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(machine.lower, machine.upper, (n, len(machine.axes))), rng.choice([-1.0, 1.0], (n, 2))


# ---------------------------------------------------------------------- the machine and its twin
def test_trunnion_reads_as_a_five_axis_table_table_machine(trunnion):
    assert trunnion.axes == ("X", "Y", "Z", "A", "C")
    np.testing.assert_allclose(trunnion.lower, [-300, -250, 0, -120, -180])
    np.testing.assert_allclose(trunnion.upper, [300, 250, 450, 30, 180])
    sides = {e.letter: e.side for e in trunnion.loop if hasattr(e, "letter")}
    assert sides == {"C": "table", "A": "table", "Y": "table", "X": "head", "Z": "head"}


@pytest.mark.parametrize("path", [TRUNNION, SWIVEL])
def test_twin_equals_drake_relative_transform(path):
    machine = FiveAxisMachine.from_file(path, "workpiece", "tool")
    c, _ = commands(machine, 60, seed=1)
    twin, drake = machine.transforms(c), machine.drake_transforms(c)
    assert np.abs(twin[:, :3, 3] - drake[:, :3, 3]).max() <= 1e-9  # mm
    assert np.abs(twin[:, :3, :3] - drake[:, :3, :3]).max() <= 1e-12
    # the base frame: the head side alone, as Drake's base -> tool
    context = machine.plant.CreateDefaultContext()
    base = machine.plant.world_frame()
    for row, T in zip(c[:5], machine.transforms(c[:5], frame="base")):
        for a, q in zip(machine.axes, row):
            j = machine.plant.GetJointByName(a)
            j.set_translation(context, q / 1000) if a in "XYZ" else j.set_angle(context, np.radians(q))
        want = machine.plant.CalcRelativeTransform(context, base, machine.frames[1]).translation() * 1000
        assert np.abs(T[:3, 3] - want).max() <= 1e-9


def test_commands_outside_the_travel_are_refused_naming_row_and_axis(trunnion):
    c = np.zeros((3, 5))
    c[2, 3] = 45.0
    with pytest.raises(InputError, match=r"row 2: A = 45 deg is outside its travel \[-120, 30\] deg"):
        trunnion.transforms(c)


def _variant(tmp_path, name, text):
    path = tmp_path / f"{name}.urdf"
    path.write_text(text)
    return path


SOURCE = (MODELS / "trunnion_ac.urdf").read_text()
BAD = {
    "planar": (SOURCE.replace('name="A" type="revolute"', 'name="A" type="planar"'), r"joint 'A' is planar"),
    "letter": (SOURCE.replace('name="Y" type="prismatic"', 'name="slide" type="prismatic"'),
               r"prismatic joint 'slide' is not named by an axis letter"),
    "revolute_x": (SOURCE.replace('name="A" type="revolute"', 'name="Q" type="revolute"'),
                   r"revolute joint 'Q' is not named by an axis letter \(A, B, C"),
    "direction": (SOURCE.replace('<axis xyz="1 0 0"/>\n    <limit lower="-2.09',
                                 '<axis xyz="0 1 0"/>\n    <limit lower="-2.09'),
                  r"joint 'A' turns about \[0.0, 1.0, 0.0\] .* A must be along x"),
    "unconnected": (re.sub(r'<joint name="table_surface".*?</joint>', "", SOURCE, flags=re.S),
                    r"frame 'workpiece' is not connected to the machine base"),
    "off_loop": (SOURCE.replace("</robot>", '<link name="probe"/><joint name="B" type="revolute"><parent link="base"/>'
                                '<child link="probe"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="1" '
                                'velocity="1"/></joint></robot>'), r"joint 'B' is not on the loop"),
    "no_travel": (SOURCE.replace('<limit lower="-0.25" upper="0.25" effort="1000" velocity="1"/>', ""),
                  r"prismatic joint 'Y' has no finite travel limits"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_model_files_are_refused_in_one_line(tmp_path, case):
    text, message = BAD[case]
    path = _variant(tmp_path, case, text)
    with pytest.raises(InputError, match=message) as info:
        FiveAxisMachine.from_file(path, "workpiece", "tool")
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_missing_frame_and_file_are_refused(tmp_path):
    with pytest.raises(InputError, match=r"no tool frame 'spindle_nose' \(links: base"):
        FiveAxisMachine.from_file(TRUNNION, "workpiece", "spindle_nose")
    with pytest.raises(InputError, match="file not found"):
        FiveAxisMachine.from_file(tmp_path / "none.urdf")


def test_an_axis_letter_used_twice_is_refused(tmp_path):
    limit = "<axis><xyz>1 0 0</xyz><limit><lower>-0.1</lower><upper>0.1</upper></limit></axis>"
    path = tmp_path / "twice.sdf"
    path.write_text(f"""<?xml version="1.0"?><sdf version="1.9"><model name="m">
      <link name="base"/><link name="tool"/><link name="workpiece"/>
      <joint name="X" type="prismatic"><parent>base</parent><child>tool</child>{limit}</joint>
      <joint name="w" type="fixed"><parent>base</parent><child>workpiece</child></joint>
      <model name="sub"><link name="foot"/><link name="slide"/>
        <joint name="X" type="prismatic"><parent>foot</parent><child>slide</child>{limit}</joint>
      </model>
      <joint name="mount" type="fixed"><parent>base</parent><child>sub::foot</child></joint></model></sdf>""")
    with pytest.raises(InputError, match="axis letter 'X' names two joints"):
        FiveAxisMachine.from_file(path, "workpiece", "tool")


# ---------------------------------------------------------------------- the error model
def test_parameter_names_follow_iso_230_7(trunnion):
    em = FiveAxisErrors(trunnion, pitch_deg=15.0)
    assert location_names("C") == ("E_X0C_mm", "E_Y0C_mm", "E_A0C_urad", "E_B0C_urad", "E_C0C_urad")
    assert location_names("A") == ("E_Y0A_mm", "E_Z0A_mm", "E_B0A_urad", "E_C0A_urad", "E_A0A_urad")
    assert em.names[:5] == location_names("A") and em.names[5:10] == location_names("C")
    assert "E_CC_forward_urad[3]" in em.names and "E_CC_reverse_urad[24]" in em.names
    assert "E_XC_forward_mm[0]" in em.names and "E_CC_reverse_urad[25]" not in em.names
    np.testing.assert_allclose(node_grid(-120, 30, 15), np.arange(-120, 31, 15))
    one = FiveAxisErrors(trunnion, bidirectional=False)
    assert not any("reverse" in n for n in one.names)


def _fd_check(model, x, seed=0):
    """Every location-error and tool column and a seeded sample of the map and linear ones."""
    p, J = model.jacobian(x)
    A = J.tocsr().toarray()
    F = np.zeros_like(A)
    plain = [i for i, n in enumerate(model.names) if "[" not in n]
    sample = np.random.default_rng(seed).choice([i for i in range(model.n_params) if i not in plain], 60, replace=False)
    for i in plain + sorted(sample):
        name = model.names[i]
        h = 1e-3 if name.endswith("mm") else 1.0  # mm; µrad
        e = np.zeros_like(x)
        e[i] = h
        F[:, i] = ((model.positions(x + e) - model.positions(x - e)) / (2 * h)).ravel()
    np.testing.assert_allclose(p, model.positions(x), atol=1e-12)
    cols = plain + sorted(sample)
    scale = np.abs(F[:, cols]).max()
    assert scale > 0 and np.abs(A[:, cols] - F[:, cols]).max() <= 1e-6 * scale
    return A


@pytest.mark.parametrize("frame", ["workpiece", "base"])
@pytest.mark.parametrize("path", [TRUNNION, SWIVEL])
def test_analytic_jacobian_equals_central_differences(path, frame):
    machine = FiveAxisMachine.from_file(path, "workpiece", "tool")
    c, d = commands(machine, 25, seed=2)
    em = FiveAxisErrors(machine, pitch_deg=30.0, linear="identify", knot_spacing_mm=150.0,
                        tool_offsets_mm=[(0, 0, 0), (40.0, 0, -30.0)], identify_tool_offsets=True)
    model = FiveAxisPositionModel(machine, em, c, d, tool=np.arange(25) % 2, frame=frame)
    rng = np.random.default_rng(3)
    x = rng.normal(size=model.n_params) * np.where([n.endswith("mm") for n in model.names], 0.02, 50.0)
    A = _fd_check(model, x)
    table_axes = [e.letter for e in machine.loop if getattr(e, "side", "") == "table" and e.kind == "revolute"]
    cols = [i for i, n in enumerate(model.names) if n.startswith(tuple(f"E_X0{L}" for L in table_axes))]
    # a station on the bed does not see the table's rotary axes; one riding on the table does
    assert (np.abs(A[:, cols]).max() == 0) == (frame == "base")


def test_directions_are_required_for_a_bidirectional_model(trunnion):
    c, _ = commands(trunnion, 4, seed=4)
    with pytest.raises(InputError, match="directions: the error model is bidirectional"):
        FiveAxisPositionModel(trunnion, FiveAxisErrors(trunnion), c)


def test_station_distance_measurement_reads_the_model(trunnion):
    c, d = commands(trunnion, 30, seed=5)
    model = FiveAxisPositionModel(trunnion, FiveAxisErrors(trunnion, pitch_deg=30.0), c, d)
    stations = np.array([[300.0, 200.0, 100.0], [-300.0, 250.0, 0.0], [0.0, -300.0, 150.0]])
    points, station = np.repeat(np.arange(30), 3), np.tile(np.arange(3), 30)
    truth = synthetic_truth(trunnion, seed=6)
    reading = np.linalg.norm(truth.truth_positions(c, d)[points] - stations[station], axis=1) - 500.0
    meas = StationDistanceMeasurement(model, points, station, reading, stations, np.full(3, 500.0))
    x = meas.start_vector()
    r, J = meas.residuals(x)
    assert r.shape == (90,) and J.shape == (90, len(meas.names))
    assert 1e-4 < np.abs(r).max() < 0.5  # the truth's errors, tens of µm
    e = np.zeros_like(x)
    e[3] = 1.0  # E_B0A, µrad
    np.testing.assert_allclose(J[:, 3].toarray().ravel(), (meas.residuals(x + e)[0] - meas.residuals(x - e)[0]) / 2,
                               atol=1e-9)
    assert meas.roughness().shape[1] == len(meas.names)


# ---------------------------------------------------------------------- the truth and a fit
def test_truth_is_not_in_the_model_family(trunnion):
    truth = synthetic_truth(trunnion, seed=7)
    for L in trunnion.rotary:
        k = trunnion.axes.index(L)
        grid = node_grid(trunnion.lower[k], trunnion.upper[k], 15.0)
        mid = (grid[:-1] + grid[1:]) / 2
        at_nodes = truth.motion_values(L, grid, 1.0)
        linear = (at_nodes[:-1] + at_nodes[1:]) / 2
        bend = np.abs(truth.motion_values(L, mid, 1.0) - linear).max(axis=0)
        assert np.all(bend[:3] > 1e-5) and np.all(bend[3:] > 0.01)  # mm, µrad: not piecewise linear
        lash = truth.motion_values(L, grid, 1.0) - truth.motion_values(L, grid, -1.0)
        assert np.abs(lash[:, "XYZABC".index(L)]).min() > 1.0  # µrad: reverse ≠ forward
    for name, v in truth.location.items():
        assert (0.010 <= abs(v) <= 0.050) if name.endswith("_mm") else (20.0 <= abs(v) <= 100.0)


def _gauss_newton(model, y, extra=None, steps=4):
    """Least squares of the model's points on ``y`` (+ ``extra`` rows A x = 0), a few Gauss-Newton steps."""
    x = model.start_vector()
    for _ in range(steps):
        p, J = model.jacobian(x)
        A, r = J.tocsr().toarray(), (p - y).ravel()
        if extra is not None:
            A, r = np.vstack([A, extra]), np.concatenate([r, extra @ x])
        with single_thread_blas():  # (BLAS threads spin on a shared machine)
            x = x - np.linalg.lstsq(A, r, rcond=None)[0]
    return x


def test_location_errors_are_recovered_from_noise_free_tool_points(trunnion):
    c, d = commands(trunnion, 200, seed=8)
    truth = synthetic_truth(trunnion, seed=9, motions=False)
    model = FiveAxisPositionModel(trunnion, FiveAxisErrors(trunnion, motions=False), c)
    x = _gauss_newton(model, truth.truth_positions(c, d))
    for name, v in zip(model.names, x):
        assert abs(v - truth.location[name]) < (1e-3 if name.endswith("_mm") else 1e-2), name  # < 1 µm, 0.01 µrad


def test_a_fit_with_error_motions_finds_the_location_errors_of_a_harmonic_truth(trunnion):
    c, d = commands(trunnion, 400, seed=10)
    truth = synthetic_truth(trunnion, seed=3)
    model = FiveAxisPositionModel(trunnion, FiveAxisErrors(trunnion, pitch_deg=7.5), c, d)
    gauge = np.array([g.row for g in model.gauge_constraints()])
    x = _gauss_newton(model, truth.truth_positions(c, d), np.vstack([1e2 * gauge, 1.0 * model.roughness().toarray()]),
                      steps=2)
    rms = np.sqrt(np.mean((model.positions(x) - truth.truth_positions(c, d)) ** 2))
    assert 1e-5 < rms < 1e-3  # mm: the truth is not in the family, the 7.5-deg map comes within a µm
    for name in model.names[:10]:
        tol = 0.5e-3 if name.endswith("_mm") else 3.0
        assert abs(x[model.names.index(name)] - truth.location[name]) < tol, name


def test_separable_names_what_a_campaign_cannot_see(trunnion):
    c, d = commands(trunnion, 200, seed=11)
    model = FiveAxisPositionModel(trunnion, FiveAxisErrors(trunnion, pitch_deg=30.0), c, d)
    stations = np.array([[300.0, 200.0, 100.0], [-300.0, 250.0, 0.0], [0.0, -300.0, 150.0], [250, -250, -50]])
    sep = separable(model, stations)
    # a rotation of the workpiece frame about C is the stations' gauge; C's tilt about x trades with A's zero
    # (R_x(a) commutes with a tilt about x downstream) and C's position in y, up to the gauge
    assert "E_C0C_urad" in sep.dropped and "gauge" in sep.reasons["E_C0C_urad"]
    assert sep.dropped == ("E_A0A_urad", "E_C0C_urad")  # the fewest; the zero angles first (PREFER_DROPPING)
    assert "E_A0C_urad" in sep.reasons["E_A0A_urad"] and "E_Y0C_mm" in sep.reasons["E_A0A_urad"]
    largest = separable(model, stations, prefer=())
    assert "E_A0A_urad" not in largest.dropped and len(largest.dropped) == 2  # (greedy by the null space's share)
    assert "E_C0C_urad: dropped, trades with the measurement's gauge" in sep.describe().splitlines()
    for name in ("E_X0C_mm", "E_B0C_urad", "E_Z0A_mm", "E_B0A_urad", "E_CC", "E_XA"):
        assert sep.separable[name], name


def test_one_point_per_angle_holds_that_axis_angular_motions(trunnion):
    """A point fixed on the C table (the tool point put on it at every A, C: one R-test ball) is one point of C's
    carrier at each angle: C's angular motions trade with its translational ones (t = -ω × w moves nothing), A's
    do not (the same ball seen from A's carrier moves with C). Points spread over the travel: nothing held. Both
    branches read at >= 5 points count; the reason names the axis."""
    from olti_drake.model.five_axis_errors import one_point_motions
    from tests.estimation.test_five_axis_identify import _onto

    def onto(c, ball):
        c[:, :3] = _onto(trunnion, c, ball)
        return c[np.all((c >= trunnion.lower) & (c <= trunnion.upper), axis=1)]  # (the linear axes reach it)

    rng = np.random.default_rng(21)
    c = np.column_stack([np.zeros((80, 3)), rng.uniform(-30, 30, 80), rng.uniform(-180, 180, 80)])
    em = FiveAxisErrors(trunnion, pitch_deg=30.0)
    one = onto(c.copy(), np.array([100.0, 0.0, 150.0]))
    held = one_point_motions(FiveAxisPositionModel(trunnion, em, one, rng.choice([-1.0, 1.0], (len(one), 2))))
    assert set(held) == {"E_AC", "E_BC", "E_CC"}, held
    assert all("see axis C move one point only (one nest, ball or reflector per angle" in w for w in held.values())
    two = np.vstack([one, onto(c.copy(), np.array([-60.0, 80.0, 200.0]))])
    assert len(one) >= 40 and len(two) >= 80
    assert one_point_motions(FiveAxisPositionModel(trunnion, em, two, rng.choice([-1.0, 1.0], (len(two), 2)))) == {}
    spread, dirs = commands(trunnion, 60, seed=22)
    assert one_point_motions(FiveAxisPositionModel(trunnion, em, spread, dirs)) == {}


def test_known_linear_motions_and_tool_offsets_enter_as_in_the_truth(trunnion):
    """An earlier volumetric result's motions (here the truth's own) taken over: the model at the truth's location
    errors is the truth, to rounding; and an absurd value is named."""
    c, d = commands(trunnion, 50, seed=12)
    truth = synthetic_truth(trunnion, seed=13, motions=False, linear=True, tool_offsets_mm=[(0, 0, 0), (0, 30, -10)])
    em = FiveAxisErrors(trunnion, motions=False, linear=truth.linear, tool_offsets_mm=truth.tool_offsets_mm)
    model = FiveAxisPositionModel(trunnion, em, c, tool=np.arange(50) % 2)
    x = np.array([truth.location[n] for n in model.names])
    y = truth.truth_positions(c, d, tool=np.arange(50) % 2)
    assert np.abs(model.positions(x) - y).max() < 1e-10
    assert np.abs(model.positions(np.zeros_like(x)) - y).max() > 0.01  # (the location errors matter)
    assert model.implausible(x) == []
    x[0] = 25.0
    assert model.implausible(x) == ["E_Y0A_mm = 25 (over 10)"]


def test_held_parameters_leave_x_and_the_rest_is_unchanged(trunnion):
    c, d = commands(trunnion, 20, seed=14)
    em = FiveAxisErrors(trunnion, pitch_deg=30.0)
    full = FiveAxisPositionModel(trunnion, em, c, d)
    held = FiveAxisPositionModel(trunnion, em, c, d, held=("E_C0C_urad", "E_ZA"))
    assert held.n_params == full.n_params - 1 - 2 * 6  # E_ZA: 6 nodes of the A grid, both branches
    assert "E_C0C_urad" not in held.names and not any(n.startswith("E_ZA_") for n in held.names)
    x = np.random.default_rng(15).normal(size=held.n_params)
    np.testing.assert_allclose(held.positions(x), full.positions(held.theta(x)), atol=1e-12)
    A_held, A_full = held.jacobian(x)[1].tocsr().toarray(), full.jacobian(held.theta(x))[1].tocsr().toarray()
    np.testing.assert_allclose(A_held, A_full[:, held.free_cols], atol=1e-12)
    assert held.roughness().shape[1] == held.n_params
    assert all(g.row.shape == (held.n_params,) for g in held.gauge_constraints())
    assert len(held.gauge_constraints()) == len(full.gauge_constraints()) - 1  # E_ZA's mean tie
    with pytest.raises(InputError, match="held: 'E_Q0C' is no parameter"):
        FiveAxisPositionModel(trunnion, em, c, d, held=("E_Q0C",))


def test_one_engine_fits_a_distance_campaign_of_table_riding_stations(trunnion):
    """The engine's Calibration over StationDistanceMeasurement of the five-axis model (001 Eq. (3)): with what
    the campaign cannot separate held (named), the location errors that trade with nothing are within 3 u."""
    from olti_drake.estimation.calibration import Calibration

    rng = np.random.default_rng(16)
    c, d = commands(trunnion, 150, seed=17)
    truth = synthetic_truth(trunnion, seed=1, motions=False)
    P = np.array([[300, 200, 100], [-300, 250, 0], [0, -300, 150], [250, -250, -50], [0, 0, 300]], float)
    em = FiveAxisErrors(trunnion, motions=False)
    sep = separable(FiveAxisPositionModel(trunnion, em, c), P)
    assert sep.dropped == ("E_A0A_urad", "E_C0C_urad")  # the fewest: one of a trio, then the gauge
    model = FiveAxisPositionModel(trunnion, em, c, held=sep.dropped)
    points, station = np.repeat(np.arange(150), 5), np.tile(np.arange(5), 150)
    L0 = np.full(5, 400.0)
    reading = (np.linalg.norm(truth.truth_positions(c, d)[points] - P[station], axis=1) - L0[station]
               + rng.normal(0, 2e-4, points.size))
    meas = StationDistanceMeasurement(model, points, station, reading, P + rng.normal(0, 1, P.shape), L0 + 1.0)
    fit = Calibration(meas).fit()
    assert np.sqrt(np.mean(fit.residuals ** 2)) < 3e-4
    trio = {"E_A0A_urad", "E_A0C_urad", "E_Y0C_mm"}
    for name, v, u in zip(fit.names[:model.n_params], fit.x, fit.std):
        if name not in trio:
            assert abs(v - truth.location[name]) < 3 * u, name


def _pattern_vector(model, letter, column):
    """x whose motions of ``letter`` are gauge pattern ``column`` (of gauge_patterns, constants left out) on both
    branches, 1 µm / 1 µrad."""
    from olti_drake.model.five_axis_errors import gauge_patterns

    em = model.errors
    grid = em.maps[(letter, "X")].emap.grid_deg
    P = gauge_patterns(model.machine, letter, grid, constants=False)[:, :, column]
    x = np.zeros(model.n_params)
    for r, c in enumerate("XYZABC"):
        x[em.slices[f"E_{c}{letter}"]] = np.tile(P[:, r], 2) * (1e-3 if r < 3 else 1.0)
    return x, grid


def test_the_gauge_patterns_are_what_the_readings_cannot_see(trunnion, swivel):
    """The rotating first harmonic of C's radial motions (table) is a constant offset of the workpiece frame; of
    B's (head), an offset of the tool point in the head: exact at the grid's nodes. The gauge rows are not
    orthogonal to it (they fix it)."""
    for machine in (trunnion, swivel):
        letter = "C" if machine is trunnion else "B"
        em = FiveAxisErrors(machine, pitch_deg=30.0)
        grid = em.maps[(letter, "X")].emap.grid_deg
        c, d = commands(machine, len(grid), seed=18)
        c[:, machine.axes.index(letter)] = grid
        model = FiveAxisPositionModel(machine, em, c, d)
        x, _ = _pattern_vector(model, letter, 0)
        shift = model.positions(x) - model.positions()
        if machine is trunnion:  # (the pattern d = 1 µm along x of the table frame)
            np.testing.assert_allclose(shift, np.broadcast_to(shift[0], shift.shape), atol=1e-12)
        else:  # the tool point moved in the head frame (d = 1 µm along z, B's first radial direction)
            moved = machine.tool_points(c, (0, 0, 1e-3)) - machine.tool_points(c)
            np.testing.assert_allclose(shift, moved, atol=1e-12)
        A = np.array([g.row for g in model.gauge_constraints()])
        assert np.abs(A @ x).max() > 0.1 * np.abs(x).max()


def test_the_iso_names_do_not_depend_on_the_files_frame_conventions(trunnion, tmp_path):
    """The same trunnion written with turned joint frames (C's frame turned 90 deg about x, its axis then local y;
    the spindle frames turned about z): the same tool points for the same errors, the errors being along the
    machine axes at zero commands whatever the file's frames."""
    turned = (SOURCE.replace('<origin xyz="0 0.015 -0.08" rpy="0 0 0"/>\n    <axis xyz="0 0 1"/>',
                             '<origin xyz="0 0.015 -0.08" rpy="1.5707963267948966 0 0"/>\n    <axis xyz="0 1 0"/>')
              .replace('<origin xyz="0 0 0.06" rpy="0 0 0"/>', '<origin xyz="0 0.06 0" rpy="-1.5707963267948966 0 0"/>')
              .replace('<origin xyz="0 0 -0.05" rpy="0 0 0"/>', '<origin xyz="0 0 -0.05" rpy="0 0 0.7"/>')
              .replace('<origin xyz="0 0 -0.1" rpy="0 0 0"/>', '<origin xyz="0 0 -0.1" rpy="0 0 -0.7"/>'))
    other = FiveAxisMachine.from_file(_variant(tmp_path, "turned", turned), "workpiece", "tool")
    c, d = commands(trunnion, 30, seed=19)
    np.testing.assert_allclose(other.transforms(c)[:, :3, 3], trunnion.transforms(c)[:, :3, 3], atol=1e-9)
    for frame in ("workpiece", "base"):
        a, b = (FiveAxisPositionModel(m, FiveAxisErrors(m, pitch_deg=30.0, linear="identify", knot_spacing_mm=150.0),
                                      c, d, frame=frame) for m in (trunnion, other))
        x = np.random.default_rng(20).normal(size=a.n_params) * np.where([n.endswith("mm") for n in a.names], 0.02, 50)
        assert np.abs(a.positions(x) - a.positions()).max() > 0.01
        np.testing.assert_allclose(b.positions(x), a.positions(x), atol=1e-9)


def test_the_sense_of_the_errors_is_tool_relative_to_workpiece(trunnion, swivel):
    """docs/five_axis.md, "Sense": +E_X0C moves the tool +x as seen from the workpiece (the table's C axis line sits
    at −x); +E_C0C on the table's C is the table turned back by that angle (commanded C − ε); +E_X0B on the head's
    B moves the tool +x."""
    c = np.zeros((1, 5))
    c[0, 2] = 100.0
    em = FiveAxisErrors(trunnion, motions=False)
    model = FiveAxisPositionModel(trunnion, em, c)
    x = np.zeros(model.n_params)
    x[model.names.index("E_X0C_mm")] = 0.01
    np.testing.assert_allclose(model.positions(x) - model.positions(), [[0.01, 0, 0]], atol=1e-12)
    c2 = np.array([[50.0, -40.0, 100.0, -30.0, 70.0]])
    model = FiveAxisPositionModel(trunnion, em, c2)
    x = np.zeros(model.n_params)
    x[model.names.index("E_C0C_urad")] = 100.0
    back = c2 - [[0, 0, 0, 0, np.degrees(100e-6)]]
    np.testing.assert_allclose(model.positions(x), trunnion.tool_points(back), atol=1e-10)
    model = FiveAxisPositionModel(swivel, FiveAxisErrors(swivel, motions=False), np.zeros((1, 5)))
    x = np.zeros(model.n_params)
    x[model.names.index("E_X0B_mm")] = 0.01
    np.testing.assert_allclose(model.positions(x) - model.positions(), [[0.01, 0, 0]], atol=1e-12)
