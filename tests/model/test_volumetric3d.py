"""The 21 error motions of a three-axis machine (olti_drake.model.volumetric3d): conventions,
analytic Jacobians, topology, observability by campaign layout, identification of a truth
outside the basis (test-only least squares), compensation tables and commands."""

from __future__ import annotations

import numpy as np
import pytest

from olti_drake.io.volumetric_io import write_tables
from olti_drake.threads import single_thread_blas
from olti_drake.model.volumetric3d import (ALL_MOTIONS, AXES, SQUARENESS, MachineConfig, VolumetricModel,
                                           _rigid_columns, _rotations, axis_tables, chain_state, command_jacobian,
                                           compensate, error_grid, motion_names, motion_role, motion_unit,
                                           observability, synthetic_truth, tool_positions)

ONE_TOOL = ((0.0, 0.0, 100.0),)
TWO_TOOLS = ((0.0, 0.0, 100.0), (60.0, 40.0, 150.0))
THREE_TOOLS = ((0.0, 0.0, 100.0), (80.0, 0.0, 100.0), (0.0, 80.0, 140.0))
STATIONS = [[-300, -200, 0], [700, -250, 50], [600, 600, 300], [-200, 500, 400], [200, 150, 900]]
TABLE_XY = dict(tool_chain=("Z",), work_chain=("Y", "X"))   # table carries X (on Y), column carries Z
TABLE_YX = dict(tool_chain=("Z",), work_chain=("X", "Y"))   # table carries Y (on X)


def campaign(config, n=600, seed=0):
    """n seeded random commands in the travel box, each visited with every tool: (commands, tools)."""
    lo = [config.travel_mm[a][0] for a in AXES]
    hi = [config.travel_mm[a][1] for a in AXES]
    c = np.random.default_rng(seed).uniform(lo, hi, (n, 3))
    k = len(config.tools)
    return np.tile(c, (k, 1)), np.repeat(np.arange(k), n)


def random_params(model, seed, mm=0.005, urad=10.0):
    rng = np.random.default_rng(seed)
    linear = np.array([n.endswith("_mm") or (n[2] in "XYZ" and "[" in n) for n in model.parameter_names()])
    return rng.standard_normal(model.n_params) * np.where(linear, mm, urad)


# ------------------------------------------------------------------ names, conventions
def test_parameter_names_follow_iso_and_the_stated_gauge():
    cfg = MachineConfig(knot_spacing_mm=50.0)    # X 400 mm: 8 intervals, 11 B-splines
    model = VolumetricModel(cfg)
    names = model.parameter_names()
    assert names[-3:] == ("E_C0Y_urad", "E_B0Z_urad", "E_A0Z_urad")
    assert len(names) == len(set(names)) == model.n_params
    # positioning and angular motions: 0 at the travel start (index 0 fixed); straightness: both ends
    assert "E_XX[0]" not in names and "E_XX[1]" in names and "E_XX[10]" in names
    assert "E_AX[0]" not in names and "E_AX[10]" in names
    assert "E_YX[0]" not in names and "E_YX[10]" not in names and "E_YX[9]" in names
    assert sum(n.startswith("E_XX[") for n in names) == 10
    assert sum(n.startswith("E_ZY[") for n in names) == cfg.n_basis("Y") - 2
    assert model.n_params == sum(len(model.free[m]) for m in ALL_MOTIONS) + 3


def test_roles_and_units_per_axis():
    roles = {"E_XX": "positioning", "E_YX": "straightness", "E_AX": "roll", "E_BX": "pitch", "E_CX": "yaw",
             "E_YY": "positioning", "E_BY": "roll", "E_AY": "pitch", "E_CY": "yaw",
             "E_ZZ": "positioning", "E_XZ": "straightness", "E_CZ": "roll", "E_AZ": "tilt", "E_BZ": "tilt"}
    assert {n: motion_role(n) for n in roles} == roles
    assert [motion_unit(n) for n in motion_names("Y")] == ["mm"] * 3 + ["urad"] * 3
    assert all(motion_unit(s) == "urad" for s in SQUARENESS)


def test_nominal_machine_puts_the_tool_at_command_plus_offset():
    cfg = MachineConfig(tool_offsets_mm=TWO_TOOLS)
    model = VolumetricModel(cfg)
    c, t = campaign(cfg, 50)
    np.testing.assert_allclose(model.positions(c, t, model.zeros()), c + cfg.tools[t], atol=1e-12)


def _single(model, name, value):
    """Parameters with every free coefficient of ``name`` (or the squareness) set to ``value``."""
    x = model.zeros()
    x[model.slices[name]] = value
    return x


@pytest.mark.parametrize("name, direction", [("E_C0Y", (-1, 0, 0)), ("E_B0Z", (1, 0, 0)),
                                             ("E_A0Z", (0, -1, 0))])
def test_squareness_signs(name, direction):
    """Positive squareness = the axis line rotated about the named direction, right-hand rule:
    E_C0Y > 0 moves +Y toward −X (angle X–Y above 90°), E_B0Z > 0 moves +Z toward +X,
    E_A0Z > 0 moves +Z toward −Y."""
    model = VolumetricModel(MachineConfig())
    axis = AXES.index(name[-1])
    lo = np.zeros((1, 3))
    hi = lo.copy()
    hi[0, axis] = 200.0
    x = _single(model, name, 50.0)  # 50 µrad
    d = (model.positions(hi, 0, x) - model.positions(lo, 0, x))[0] - hi[0]
    eps = 50e-6
    expected = 200.0 * (np.sin(eps) * np.array(direction) + (np.cos(eps) - 1.0) * np.eye(3)[axis])
    np.testing.assert_allclose(d, expected, atol=1e-12)


def test_angular_motion_signs_and_abbe_arm():
    """E_AZ > 0 rotates the spindle about +x: a tool offset L along +z moves by −L·E_AZ along y."""
    cfg = MachineConfig(tool_offsets_mm=((0.0, 0.0, 150.0),))
    model = VolumetricModel(cfg)
    x = _single(model, "E_AZ", 20.0)                     # every coefficient 20 µrad: E_AZ = 20 beyond 1st knot
    c = np.array([[100.0, 100.0, 250.0]])                 # at the travel end all B-splines but the last vanish
    d = model.positions(c, 0, x)[0] - c[0] - cfg.tools[0]
    np.testing.assert_allclose(d, [0.0, -150.0 * np.sin(20e-6), 150.0 * (np.cos(20e-6) - 1)], atol=1e-12)


def test_rotations_are_exact_not_first_order():
    """A roll of X rotates everything it carries about the X carriage: lengths are kept to 1e-12 mm."""
    cfg = MachineConfig(tool_offsets_mm=TWO_TOOLS)
    model = VolumetricModel(cfg)
    x = _single(model, "E_AX", 500.0)                    # 500 µrad: first-order error ≈ ε²/2·arm ≈ 5e-5 mm
    c, t = campaign(cfg, 40)
    arm = model.positions(c, t, x) - c * [1, 0, 0]
    nominal = c * [0, 1, 1] + cfg.tools[t]
    np.testing.assert_allclose(np.linalg.norm(arm, axis=1), np.linalg.norm(nominal, axis=1), atol=1e-12)
    first_order = nominal + np.cross(model.motions(x).evaluate("X", c[:, 0])[:, 3:] * 1e-6, nominal)
    assert np.abs(arm - first_order).max() > 1e-6    # the exact model differs from the first-order one


# ------------------------------------------------------------------ Jacobians
@pytest.mark.parametrize("topology, offsets", [({}, False), (TABLE_XY, False), (TABLE_YX, True)])
def test_parameter_jacobian_matches_finite_differences(topology, offsets):
    cfg = MachineConfig(tool_offsets_mm=THREE_TOOLS, **topology)
    model = VolumetricModel(cfg, identify_tool_offsets=offsets)
    assert (model.parameter_names()[-1] == "tool2_z_mm") == offsets
    c, t = campaign(cfg, 30)
    x = random_params(model, 1)
    p, J = model.jacobian(c, t, x)
    np.testing.assert_allclose(p, model.positions(c, t, x), atol=1e-12)
    step = 1e-3
    fd = np.empty_like(J)
    for i in range(model.n_params):
        d = np.zeros(model.n_params)
        d[i] = step
        fd[:, :, i] = (model.positions(c, t, x + d) - model.positions(c, t, x - d)) / (2 * step)
    np.testing.assert_allclose(J, fd, atol=1e-9)


@pytest.mark.parametrize("truth", [False, True])
def test_command_jacobian_matches_finite_differences(truth):
    cfg = MachineConfig(tool_offsets_mm=TWO_TOOLS)
    model = VolumetricModel(cfg)
    motions = synthetic_truth(cfg, 4) if truth else model.motions(random_params(model, 2))
    c, t = campaign(cfg, 30)
    c = np.clip(c, 1.0, 249.0)
    J = command_jacobian(cfg, motions, chain_state(cfg, motions, c, t))
    for k in range(3):
        d = np.zeros(3)
        d[k] = 1e-3
        fd = (tool_positions(cfg, motions, c + d, t) - tool_positions(cfg, motions, c - d, t)) / 2e-3
        np.testing.assert_allclose(J[:, :, k], fd, atol=1e-9)


def test_topology_changes_the_abbe_arms():
    """The yaw of Y rotates what Y carries: on a serial X–Y–Z machine not X's travel, on a table
    carrying Y on top of X (chain Y, X, Z from the workpiece) X's travel too."""
    serial, table = MachineConfig(), MachineConfig(**TABLE_YX)
    assert serial.chain == ("X", "Y", "Z") and table.chain == ("Y", "X", "Z")
    assert MachineConfig(**TABLE_XY).chain == ("X", "Y", "Z")
    c = np.array([[300.0, 300.0, 0.0]])
    shift = {}
    for name, cfg in (("serial", serial), ("table", table)):
        model = VolumetricModel(cfg)
        x = _single(model, "E_CY", 30.0)
        shift[name] = model.positions(c, 0, x)[0] - c[0] - cfg.tools[0]
    np.testing.assert_allclose(shift["serial"], 0.0, atol=1e-12)    # tool along z, nothing else carried
    np.testing.assert_allclose(shift["table"][1], 300.0 * 30e-6, rtol=1e-6)


@pytest.mark.parametrize("kwargs, message", [
    (dict(tool_chain=("X", "Y"), work_chain=("Y",)), "X, Y and Z once each"),
    (dict(travel_mm={"X": (0, 100), "Y": (50, 50), "Z": (0, 1)}), "travel_mm['Y']"),
    (dict(travel_mm={"X": (0, 100), "Y": ("a", 3), "Z": (0, 1)}), "travel_mm['Y']"),
    (dict(travel_mm={"X": (0, 100), "Y": (0, 3)}), "travel_mm['Z']"),
    (dict(knot_spacing_mm=0.0), "knot_spacing_mm"),
    (dict(tool_offsets_mm=((0, 0),)), "tool_offsets_mm"),
])
def test_bad_configuration_is_one_line(kwargs, message):
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")) as err:
        MachineConfig(**kwargs)
    assert "\n" not in str(err.value)


def test_bad_commands_name_row_and_axis():
    model = VolumetricModel(MachineConfig(tool_offsets_mm=TWO_TOOLS))
    c = np.array([[10.0, 10.0, 10.0], [10.0, 301.0, 10.0]])
    with pytest.raises(ValueError, match=r"row 1: y = 301 mm is outside the Y travel"):
        model.positions(c, 0, model.zeros())
    with pytest.raises(ValueError, match=r"tool: indices must be integers in 0..1"):
        model.positions(c[:1], 2, model.zeros())
    with pytest.raises(ValueError, match=r"params: expected"):
        model.positions(c[:1], 0, np.zeros(3))
    with pytest.raises(ValueError, match=r"targets: row 0: \[nan, 1.0, 2.0\] mm is not finite"):
        compensate(model.motions(model.zeros()), model.config, [[np.nan, 1.0, 2.0]], 0)


# ------------------------------------------------------------------ observability
ONE_TOOL_BLIND = {"E_CY", "E_CZ", "E_AZ", "E_BZ", "E_XZ", "E_YZ", "E_A0Z", "E_B0Z"}


@pytest.mark.parametrize("stations", [None, STATIONS])
def test_one_tool_cannot_separate_the_spindle_angles(stations):
    """One tool offset along z: the angular motions of Z act only at that point (E_AZ reads as
    straightness E_YZ, E_BZ as E_XZ, their slopes as squareness); E_CZ (roll about the tool line)
    and E_CY (yaw of Y: everything Y carries lies along z) act on no reading."""
    cfg = MachineConfig(tool_offsets_mm=ONE_TOOL)
    obs = observability(VolumetricModel(cfg), *campaign(cfg), stations_mm=stations)
    assert set(obs.inseparable) == ONE_TOOL_BLIND
    assert obs.trades_with["E_AZ"] == ("E_YZ", "E_A0Z")
    assert obs.trades_with["E_BZ"] == ("E_XZ", "E_B0Z")
    assert obs.trades_with["E_CZ"] == () and obs.trades_with["E_CY"] == ()
    assert "E_CY: not separable, no reading depends on it" in obs.describe()


@pytest.mark.parametrize("stations", [None, STATIONS])
def test_two_tools_leave_one_spindle_rotation(stations):
    """Two tool points: the last axis' rotation about the line through them moves both alike (a
    translation, read as straightness of Z): one function of z stays inseparable; every motion of
    X and Y and the X–Y squareness are separated."""
    cfg = MachineConfig(tool_offsets_mm=TWO_TOOLS)
    model = VolumetricModel(cfg)
    obs = observability(model, *campaign(cfg), stations_mm=stations)
    assert obs.null_dimension == len(model.free["E_AZ"])
    assert set(obs.inseparable) == {"E_XZ", "E_YZ", "E_AZ", "E_BZ", "E_CZ", "E_B0Z", "E_A0Z"}
    assert all(obs.separable[n] for n in motion_names("X") + motion_names("Y") + ("E_ZZ", "E_C0Y"))


def test_two_tools_on_the_spindle_axis_miss_the_rolls():
    """Two tool lengths along z: the tilts of Z are separated (two Abbe arms), the rotations about z
    (roll of Z, yaw of Y) still act on no reading."""
    cfg = MachineConfig(tool_offsets_mm=((0.0, 0.0, 100.0), (0.0, 0.0, 200.0)))
    obs = observability(VolumetricModel(cfg), *campaign(cfg))
    assert obs.inseparable == ("E_CY", "E_CZ") and obs.trades_with["E_CZ"] == ()


@pytest.mark.parametrize("topology", [{}, TABLE_XY, TABLE_YX])
@pytest.mark.parametrize("stations", [None, STATIONS])
def test_three_tools_separate_all_21(topology, stations):
    cfg = MachineConfig(tool_offsets_mm=THREE_TOOLS, **topology)
    obs = observability(VolumetricModel(cfg), *campaign(cfg), stations_mm=stations)
    assert obs.null_dimension == 0 and not obs.inseparable, obs.describe()
    assert "all 21 error motions separable" in obs.describe()


@pytest.mark.parametrize("stations", [None, STATIONS])
def test_identified_tool_offsets_are_separable_with_three_tools(stations):
    cfg = MachineConfig(tool_offsets_mm=THREE_TOOLS)
    obs = observability(VolumetricModel(cfg, identify_tool_offsets=True), *campaign(cfg), stations_mm=stations)
    assert not obs.inseparable and obs.separable["tool1"] and obs.separable["tool2"]
    assert obs.describe().startswith("all 21 error motions and 2 tool offsets separable")


def test_a_planar_campaign_cannot_see_z():
    """Every command at one z: Z's motions are seen at one position only (nothing to separate)."""
    cfg = MachineConfig(tool_offsets_mm=THREE_TOOLS)
    c, t = campaign(cfg, 300)
    c[:, 2] = 120.0
    obs = observability(VolumetricModel(cfg), c, t)
    assert set(motion_names("Z")) <= set(obs.inseparable)
    assert all(obs.separable[n] for n in motion_names("X") + motion_names("Y"))


# ------------------------------------------------------------------ identification (test-only fit)
def fit_targets(model, commands, tools, measured, iterations=8):
    """Gauss–Newton on 3D targets measured in an unknown frame: measured ≈ R(ω) p(θ) + τ."""
    x, w, tau = model.zeros(), np.zeros(3), np.zeros(3)
    for _ in range(iterations):
        p, J = model.jacobian(commands, tools, x)
        R = _rotations(w[None])[0][0]
        pred = p @ R.T + tau
        A = np.hstack([np.einsum("ij,mjp->mip", R, J).reshape(-1, model.n_params), _rigid_columns(pred)])
        with single_thread_blas():
            d = np.linalg.lstsq(A, (measured - pred).ravel(), rcond=None)[0]
        x += d[:model.n_params]
        tau += d[model.n_params:model.n_params + 3]
        w += d[model.n_params + 3:]
        if np.abs(d).max() < 1e-12:
            break
    return x


def fit_distances(model, commands, tools, readings, stations0, dead0, iterations=10):
    """Gauss–Newton on readings ‖p_i − P_j‖ − d0_j (001 Eq. (3) in 3D), stations and dead paths unknown."""
    x, P, d0 = model.zeros(), np.array(stations0, float), np.array(dead0, float)
    n = len(P)
    for _ in range(iterations):
        p, J = model.jacobian(commands, tools, x)
        u = p[:, None, :] - P[None]
        dist = np.linalg.norm(u, axis=-1)
        u /= dist[..., None]
        r = (readings - (dist - d0)).ravel()
        A = np.zeros((len(p), n, model.n_params + 4 * n))
        A[:, :, :model.n_params] = np.einsum("mjk,mkp->mjp", u, J)
        for j in range(n):
            A[:, j, model.n_params + 3 * j:model.n_params + 3 * j + 3] = -u[:, j]
            A[:, j, model.n_params + 3 * n + j] = -1.0
        A = A.reshape(-1, A.shape[2])
        scale = np.linalg.norm(A, axis=0)
        with single_thread_blas():
            d = np.linalg.lstsq(A / scale, r, rcond=None)[0] / scale
        x += d[:model.n_params]
        P += d[model.n_params:model.n_params + 3 * n].reshape(n, 3)
        d0 += d[model.n_params + 3 * n:]
        if np.abs(d).max() < 1e-11:
            break
    return x


def motion_errors(model, params, truth):
    """Max |fit − truth| per motion over the travel (mm or µrad), and per squareness."""
    fit = model.motions(params)
    out = {}
    for a in AXES:
        q = np.linspace(*model.config.travel_mm[a], 500)
        diff = np.abs(fit.evaluate(a, q) - truth.evaluate(a, q)).max(axis=0)
        out.update(zip(motion_names(a), diff))
    out.update(zip(SQUARENESS, np.abs(fit.squareness_urad - truth.squareness_urad)))
    return out


def tolerances(truth, config):
    """The tolerance derived from the basis: the largest a-priori spline bound (5/384) h⁴ ‖f⁗‖∞ of
    the motions of the same unit. The fit is a least-squares projection of all 21 motions at once,
    so a motion's error is driven by the worst approximable motion it couples with (angular ones
    through the Abbe arms), not by its own bound; squareness is a slope: µrad."""
    bound = truth.spline_error_bound(config)
    worst = {u: max(b for n, b in bound.items() if motion_unit(n) == u) for u in ("mm", "urad")}
    return {n: worst[motion_unit(n)] for n in ALL_MOTIONS + SQUARENESS}


def truth_campaign(config, seed):
    truth = synthetic_truth(config, seed)
    c, t = campaign(config, 600, seed)
    return truth, c, t, tool_positions(config, truth, c, t)


@pytest.mark.parametrize("seed", [1, 2])
def test_fit_on_targets_recovers_all_21_within_the_basis_bound(seed):
    cfg = MachineConfig(tool_offsets_mm=THREE_TOOLS)
    model = VolumetricModel(cfg)
    truth, c, t, p = truth_campaign(cfg, seed)
    R = _rotations(np.array([[2e-3, -1e-3, 3e-3]]))[0][0]
    x = fit_targets(model, c, t, p @ R.T + [1.0, -2.0, 0.5])     # measured in an unknown frame
    err, tol = motion_errors(model, x, truth), tolerances(truth, cfg)
    assert all(err[n] <= tol[n] for n in err), {n: (err[n], tol[n]) for n in err if err[n] > tol[n]}
    amplitude = {n: np.abs(truth.evaluate(n[3], np.linspace(*cfg.travel_mm[n[3]], 200))[:, motion_names(
        n[3]).index(n)]).max() for n in ALL_MOTIONS}
    assert all(tol[n] < 0.5 * amplitude[n] for n in ALL_MOTIONS)   # the tolerance is not vacuous
    assert np.median([tol[n] / amplitude[n] for n in ALL_MOTIONS]) < 0.1


def test_fit_from_distances_recovers_all_21():
    cfg = MachineConfig(tool_offsets_mm=THREE_TOOLS)
    model = VolumetricModel(cfg)
    truth, c, t, p = truth_campaign(cfg, 5)
    P = np.array(STATIONS, float)
    dead = np.array([0.3, 1.2, -0.4, 2.0, 0.7])
    readings = np.linalg.norm(p[:, None] - P[None], axis=-1) - dead
    rng = np.random.default_rng(0)
    x = fit_distances(model, c, t, readings, P + rng.normal(0, 2.0, P.shape), dead + 1.0)
    err, tol = motion_errors(model, x, truth), tolerances(truth, cfg)
    assert all(err[n] <= tol[n] for n in err), {n: (err[n], tol[n]) for n in err if err[n] > tol[n]}


def test_fit_identifies_the_tool_offsets_and_needs_them():
    """Reflector mounts known to 0.1 mm only: identified, the motions are recovered as before;
    taken as known, the offset errors corrupt the motions far beyond the basis bound."""
    cfg = MachineConfig(tool_offsets_mm=THREE_TOOLS)
    errors = [[0.0, 0.0, 0.0], [0.08, -0.05, 0.12], [-0.1, 0.07, 0.02]]
    truth = synthetic_truth(cfg, 2, tool_offset_errors_mm=errors)
    c, t = campaign(cfg, 600, 2)
    p = tool_positions(cfg, truth, c, t)
    tol = tolerances(truth, cfg)
    model = VolumetricModel(cfg, identify_tool_offsets=True)
    x = fit_targets(model, c, t, p)
    err = motion_errors(model, x, truth)
    assert all(err[n] <= tol[n] for n in err)
    np.testing.assert_allclose(model.motions(x).tool_offset_errors_mm, errors, atol=tol["E_XX"])
    known = VolumetricModel(cfg)
    err_known = motion_errors(known, fit_targets(known, c, t, p), truth)
    assert max(err_known[n] / tol[n] for n in err_known) > 10


def test_fit_error_shrinks_with_the_knot_spacing():
    """Halving h must cut the fitted-motion error by far more than 2 (spline theory: 16)."""
    coarse = MachineConfig(tool_offsets_mm=THREE_TOOLS, knot_spacing_mm=50.0)
    fine = MachineConfig(tool_offsets_mm=THREE_TOOLS, knot_spacing_mm=25.0)
    truth, c, t, p = truth_campaign(coarse, 3)
    worst = {}
    for name, cfg in (("coarse", coarse), ("fine", fine)):
        model = VolumetricModel(cfg)
        err = motion_errors(model, fit_targets(model, c, t, p), truth)
        worst[name] = max(err[n] for n in ALL_MOTIONS if motion_unit(n) == "urad")
    assert worst["fine"] < worst["coarse"] / 8


def test_two_tool_fit_recovers_what_observability_calls_separable():
    cfg = MachineConfig(tool_offsets_mm=TWO_TOOLS)
    model = VolumetricModel(cfg)
    truth, c, t, p = truth_campaign(cfg, 1)
    obs = observability(model, c, t)
    err, tol = motion_errors(model, fit_targets(model, c, t, p), truth), tolerances(truth, cfg)
    assert all(err[n] <= tol[n] for n in err if obs.separable[n])
    assert any(err[n] > 5 * tol[n] for n in obs.inseparable)  # minimum-norm in the null space: not the truth


def test_synthetic_truth_is_seeded_obeys_the_gauge_and_is_outside_the_basis():
    cfg = MachineConfig()
    a, b, other = synthetic_truth(cfg, 7), synthetic_truth(cfg, 7), synthetic_truth(cfg, 8)
    q = np.linspace(0, 300, 7)
    assert np.array_equal(a.evaluate("Y", q), b.evaluate("Y", q))
    assert not np.allclose(a.evaluate("Y", q), other.evaluate("Y", q))
    for axis in AXES:
        lo, hi = cfg.travel_mm[axis]
        ends = a.evaluate(axis, np.array([lo, hi]))
        np.testing.assert_allclose(ends[0], 0.0, atol=1e-15)
        for r, name in enumerate(motion_names(axis)):
            if motion_role(name) == "straightness":
                assert abs(ends[1, r]) < 1e-15
    model = VolumetricModel(cfg)
    best = motion_errors(model, model.fit_function(a), a)
    assert min(best[n] for n in ALL_MOTIONS) > 0        # not representable exactly


# ------------------------------------------------------------------ compensation
def test_axis_tables_sample_the_motions_with_iso_names_and_units():
    cfg = MachineConfig()
    truth = synthetic_truth(cfg, 2)
    tables = axis_tables(truth, cfg, 30.0)
    x = tables["X"]
    assert list(x) == ["position_mm", "E_XX_mm", "E_YX_mm", "E_ZX_mm", "E_AX_urad", "E_BX_urad", "E_CX_urad"]
    assert list(tables["Z"])[1:] == ["E_XZ_mm", "E_YZ_mm", "E_ZZ_mm", "E_AZ_urad", "E_BZ_urad", "E_CZ_urad"]
    np.testing.assert_allclose(x["position_mm"][[0, 1, -2, -1]], [0.0, 30.0, 390.0, 400.0])
    np.testing.assert_array_equal(x["E_BX_urad"], truth.evaluate("X", x["position_mm"])[:, 4])
    with pytest.raises(ValueError, match="pitch_mm"):
        axis_tables(truth, cfg, 0.0)


def test_error_grid_is_the_model_minus_command_and_offset():
    cfg = MachineConfig(tool_offsets_mm=TWO_TOOLS)
    truth = synthetic_truth(cfg, 3)
    g = error_grid(truth, cfg, 100.0, tool=1)
    assert len(g["x_cmd_mm"]) == 5 * 4 * 4          # 0..400, 0..300, 0..250 (end included)
    c = np.column_stack([g["x_cmd_mm"], g["y_cmd_mm"], g["z_cmd_mm"]])
    d = tool_positions(cfg, truth, c, 1) - c - cfg.tools[1]
    np.testing.assert_array_equal(np.column_stack([g["dx_mm"], g["dy_mm"], g["dz_mm"]]), d)
    assert np.abs(d).max() > 1e-3


@pytest.mark.parametrize("topology", [{}, TABLE_XY, TABLE_YX])
def test_compensated_commands_hit_the_targets(topology):
    cfg = MachineConfig(tool_offsets_mm=TWO_TOOLS, **topology)
    truth = synthetic_truth(cfg, 6, amplitude_mm=0.02, amplitude_urad=50.0)
    rng = np.random.default_rng(1)
    tools = rng.integers(0, 2, 400)
    wanted = rng.uniform([5, 5, 5], [395, 295, 245], (400, 3)) + cfg.tools[tools]
    q, _ = compensate(truth, cfg, wanted, tools)
    assert np.abs(tool_positions(cfg, truth, q, tools) - wanted).max() < 1e-9
    assert np.abs(q - (wanted - cfg.tools[tools])).max() > 0.01      # the compensation did something


def test_compensation_refuses_a_target_outside_the_travel():
    cfg = MachineConfig()
    truth = synthetic_truth(cfg, 6)
    wanted = np.array([[10.0, 10.0, 110.0], [0.0, 0.0, 100.0]])   # the 2nd needs x, y < 0 (errors at 0 are 0)
    truth_at_start = tool_positions(cfg, truth, [[0.0, 0.0, 0.0]], 0)[0]
    wanted[1] = truth_at_start - [0.01, 0.0, 0.0]
    with pytest.raises(ValueError, match=r"compensated commands: row 1: x = .* outside the X travel"):
        compensate(truth, cfg, wanted, 0)


# ------------------------------------------------------------------ files
def test_document_round_trip_and_refusals():
    import json

    from olti_drake.model.volumetric3d import model_from_document, motions_document

    cfg = MachineConfig(tool_offsets_mm=TWO_TOOLS, **TABLE_XY)
    model = VolumetricModel(cfg)
    x = random_params(model, 9)
    doc = json.loads(json.dumps(motions_document(model, x, pitch_mm=25.0)))
    assert doc["format"] == "olti-volumetric/1"
    assert set(doc["error_motions"]) == set(ALL_MOTIONS) and doc["error_motions"]["E_AX"]["unit"] == "urad"
    assert doc["error_motions"]["E_YX"]["fixed"] == "0 at both travel ends"
    back, y = model_from_document(doc)
    assert back.config.chain == cfg.chain
    np.testing.assert_array_equal(y, x)
    c, t = campaign(cfg, 20)
    np.testing.assert_array_equal(back.positions(c, t, y), model.positions(c, t, x))
    with_tools = VolumetricModel(cfg, identify_tool_offsets=True)
    z = np.concatenate([x, [0.1, -0.2, 0.05]])
    doc_t = json.loads(json.dumps(motions_document(with_tools, z)))
    np.testing.assert_allclose(doc_t["tool_offsets_mm"][1], [60.1, 39.8, 150.05])
    back_t, y_t = model_from_document(doc_t)
    assert back_t.identify_tool_offsets and back_t.parameter_names()[-3:] == ("tool1_x_mm", "tool1_y_mm",
                                                                                "tool1_z_mm")
    np.testing.assert_array_equal(back_t.positions(c, t, y_t), with_tools.positions(c, t, z))
    doc["error_motions"]["E_YX"]["coefficients"][0] = 1.0
    with pytest.raises(ValueError, match=r"error_motions.E_YX.coefficients: must be 0 at \[0, 10\]"):
        model_from_document(doc, "r.json")
    del doc["squareness_urad"]["E_B0Z"]
    doc["error_motions"]["E_YX"]["coefficients"][0] = 0.0
    with pytest.raises(ValueError, match=r"r.json: squareness_urad.E_B0Z: missing"):
        model_from_document(doc, "r.json")
    with pytest.raises(ValueError, match=r"r.json: format"):
        model_from_document({"format": "olti-volumetric/0"}, "r.json")


def test_write_tables_csv(tmp_path):
    cfg = MachineConfig(tool_offsets_mm=TWO_TOOLS)
    truth = synthetic_truth(cfg, 2)
    paths = write_tables(tmp_path, truth, cfg, 50.0, grid_pitch_mm=100.0)
    assert sorted(p.rsplit("/", 1)[1] for p in paths) == ["axis_X.csv", "axis_Y.csv", "axis_Z.csv",
                                                          "grid_tool0.csv", "grid_tool1.csv"]
    lines = [ln for ln in open(tmp_path / "axis_Y.csv").read().splitlines() if not ln.startswith("#")]
    assert lines[0] == "position_mm,E_XY_mm,E_YY_mm,E_ZY_mm,E_AY_urad,E_BY_urad,E_CY_urad"
    data = np.loadtxt(tmp_path / "axis_Y.csv", delimiter=",", comments="#", skiprows=2)
    np.testing.assert_allclose(data[:, 0], np.arange(0, 301, 50))
    np.testing.assert_allclose(data[:, 1:], truth.evaluate("Y", data[:, 0]), atol=1e-6)
    grid = np.loadtxt(tmp_path / "grid_tool1.csv", delimiter=",", comments="#", skiprows=2)
    assert grid.shape == (5 * 4 * 4, 6)


@pytest.mark.parametrize("stations", [None, STATIONS])
def test_holding_the_one_tool_blind_angles_makes_the_rest_separable(stations):
    """held=: the motions taken out of the unknowns are not reported, the rest is checked without them;
    holding the four angular motions one tool cannot see leaves its straightness and squareness of Z
    separable (they then carry the tilt's effect at the tool point)."""
    cfg = MachineConfig(tool_offsets_mm=ONE_TOOL)
    held = ("E_CY", "E_CZ", "E_AZ", "E_BZ")
    obs = observability(VolumetricModel(cfg), *campaign(cfg), stations_mm=stations, held=held)
    assert not obs.inseparable and obs.null_dimension == 0 and obs.held == held
    assert not set(held) & set(obs.separable)
    assert obs.describe().startswith("all 17 error motions separable") and "E_AZ, E_BZ held at 0" in obs.describe()
    partly = observability(VolumetricModel(cfg), *campaign(cfg), stations_mm=stations, held=("E_CY", "E_CZ"))
    assert set(partly.inseparable) == ONE_TOOL_BLIND - {"E_CY", "E_CZ"}


def test_predict_positions_refuses_or_holds_the_motions_outside_the_travel():
    from olti_drake.model.volumetric3d import predict_positions

    cfg = MachineConfig(tool_offsets_mm=THREE_TOOLS)
    truth = synthetic_truth(cfg, 2)
    c = np.array([[100.0, 50.0, 30.0], [400.0, 300.0, 250.0], [430.0, 300.0, 250.0]])
    with pytest.raises(ValueError, match=r"line 9: x = 430 mm is outside the X travel"):
        predict_positions(cfg, truth, c, [0, 1, 2], lines=[7, 8, 9])
    p = predict_positions(cfg, truth, c, [0, 1, 2], outside="clamp")
    assert np.allclose(p[:2], tool_positions(cfg, truth, c[:2], [0, 1]), atol=1e-12)
    # beyond the end X's motions stop changing: X is the first link, so the point moves by exactly 30 mm along x
    before = predict_positions(cfg, truth, [[400.0, 300.0, 250.0]], [2])
    assert np.allclose(p[2] - before[0], [30.0, 0.0, 0.0], atol=1e-12)
