"""Position model of serial robots in 3D (olti_drake.model.serial): error maps per joint, the
sparse Jacobian against finite differences, the gauge (null space) of distance and tracker
campaigns, and a Gauss-Newton recovery of a truth drawn from the model family."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse as sp

import olti_drake
from olti_drake.model.errormap import OutsideGridError
from olti_drake.model.chain import load_serial_chain
from olti_drake.model.serial import (DistanceMeasurement, JointMap, PointMeasurement,
                                     RootPositionMeasurement, build_position_model, find_gauge,
                                     grid_every, synthetic_campaign, synthetic_truth)

UR5 = Path(olti_drake.__file__).parent / "models" / "ur5.urdf"
TOOL = (40.0, -25.0, 60.0)
RANGES = np.array([[-100.0, 80.0], [-170.0, -10.0], [-120.0, 120.0], [-90.0, 90.0], [-60.0, 150.0],
                   [-180.0, 180.0]])


@pytest.fixture(scope="module")
def chain():
    return load_serial_chain(UR5, "tool0")


@pytest.fixture(scope="module")
def truth(chain):
    return synthetic_truth(chain, seed=3, tool_offset_mm=TOOL)


@pytest.fixture(scope="module")
def campaign(truth):
    return synthetic_campaign(truth, 300, seed=4, ranges_deg=RANGES)


def build(chain, campaign, kind="errormap", directions=True, step=30.0, tool=TOOL):
    dirs = campaign.dirs if directions else None
    return build_position_model(chain, campaign.commands, dirs, kind=kind, grid_step_deg=step,
                                tool_offset_mm=tool)


def problem(kind, model, campaign, truth, directions=True):
    """A measurement problem of ``kind`` on the campaign, starting at the true stations/frame."""
    if kind == "distance":
        return DistanceMeasurement(model, campaign.distance_commands,
                                   campaign.distance_dirs if directions else None, campaign.station,
                                   campaign.displacement_mm, truth.stations_mm, truth.dead_paths_mm)
    dirs = campaign.dirs if directions else None
    if kind == "point":
        return PointMeasurement(model, campaign.commands, dirs, campaign.points_mm, truth.frame)
    return RootPositionMeasurement(model, campaign.commands, dirs, truth.positions(campaign.commands, dirs))


def random_vector(prob, seed, scale=1.0):
    """Non-zero values for every parameter kind: location errors ~0.3 mm / 0.05 deg, maps and
    offsets ~0.05 deg, tool, stations and frame moved by a few mm / deg from the start."""
    rng = np.random.default_rng(seed)
    x = prob.start_vector().copy()
    for i, name in enumerate(prob.names):
        if name.endswith("_mm"):
            x[i] += rng.normal(0, 0.3 if not name.startswith(("P", "frame", "d0")) else 3.0) * scale
        else:
            x[i] += rng.normal(0, 0.05 if not name.startswith("frame") else 1.0) * scale
    return x


# ----------------------------------------------------------------------- maps
def test_grid_every_covers_the_range_on_multiples_of_the_step():
    np.testing.assert_allclose(grid_every(15, -37.0, 50.0), np.arange(-45.0, 61.0, 15.0))
    np.testing.assert_allclose(grid_every(15, -45.0, 45.0), np.arange(-45.0, 46.0, 15.0))
    np.testing.assert_allclose(grid_every(15, 30.0, 30.0), [30.0])
    np.testing.assert_allclose(grid_every(15, 31.0, 31.0), [30.0, 45.0])
    np.testing.assert_allclose(grid_every(1.0, -0.5, 0.5), [-1.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="grid step"):
        grid_every(0.0, 0.0, 10.0)
    with pytest.raises(ValueError, match="grid range"):
        grid_every(15.0, 10.0, -10.0)


def test_one_directional_map_has_a_single_branch():
    m = JointMap.zeros("J3", [0.0, 10.0, 20.0], bidirectional=False).with_values([0.1, 0.3, -0.2])
    assert m.names() == ("J3_forward_deg[0]", "J3_forward_deg[1]", "J3_forward_deg[2]")
    np.testing.assert_allclose(m([5.0, 15.0], [1.0, -1.0]), [0.2, 0.05])
    np.testing.assert_allclose(m([5.0, 15.0], None), [0.2, 0.05])
    assert "reverse_deg" not in m.to_dict() and m.to_dict()["forward_deg"] == [0.1, 0.3, -0.2]
    row, at = m.level_row()
    assert at == 0.0 and row @ m.values == pytest.approx(0.1)
    two = JointMap.zeros("J3", [-10.0, 10.0]).with_values([0.0, 0.2, 0.4, 0.6])
    row, at = two.level_row()
    assert row @ two.values == pytest.approx((0.1 + 0.5) / 2)  # (Δθ(0,+1) + Δθ(0,−1))/2


# ----------------------------------------------------------------- the model
@pytest.mark.parametrize("kind", ["dh", "errormap"])
def test_zero_errors_give_the_chains_nominal_fk(chain, campaign, kind):
    model = build(chain, campaign, kind)
    p = model.positions(campaign.commands, campaign.dirs)
    np.testing.assert_allclose(p, chain.positions(campaign.commands, chain.nominal_parameters(TOOL)),
                               atol=1e-12)


def test_a_constant_map_is_a_joint_offset(chain, campaign):
    """The map level plays the joint's zero offset (000: θ20 absorbed in the J2 map)."""
    em = build(chain, campaign, "errormap")
    dh = build(chain, campaign, "dh")
    x_em, x_dh = em.start_vector(), dh.start_vector()
    for j, joint in enumerate(chain.joint_names[:5]):
        x_dh[dh.names.index(f"{joint}_offset_deg")] = 0.01 * (j + 1)
        x_em[[i for i, n in enumerate(em.names) if n.startswith(f"{joint}_forward_deg")
              or n.startswith(f"{joint}_reverse_deg")]] = 0.01 * (j + 1)
    np.testing.assert_allclose(em.positions(campaign.commands, campaign.dirs, x_em),
                               dh.positions(campaign.commands, campaign.dirs, x_dh), atol=1e-10)
    assert not any(n.endswith("_offset_deg") for n in em.names)


def test_parameter_names_and_dropped(chain, campaign):
    model = build(chain, campaign, "errormap")
    assert model.names[:2] == ("shoulder_pan_joint_dx_mm", "shoulder_pan_joint_dy_mm")
    assert {"tool_x_mm", "tool_y_mm", "tool_z_mm", "elbow_joint_forward_deg[0]",
            "elbow_joint_reverse_deg[8]", "wrist_3_joint_forward_deg[12]"} <= set(model.names)
    assert len(set(model.names)) == model.n_params
    dropped = dict(model.dropped)
    assert dropped["shoulder_pan_joint_drz_deg"] == "trades with shoulder_pan_joint_offset_deg"
    assert "wrist_3_joint_dz_mm" in dropped and "shoulder_pan_joint_dx_mm" not in dropped
    on_axis = build(chain, campaign, "errormap", tool=(0.0, 0.0, 60.0))
    assert "no reading depends on it" in dict(on_axis.dropped)["wrist_3_joint error map"]
    assert not any(n.startswith("wrist_3_joint_forward") for n in on_axis.names)
    x = random_vector(RootPositionMeasurement(model, campaign.commands, campaign.dirs,
                                              np.zeros((len(campaign.commands), 3))), 1)
    again = model.with_vector(x)
    np.testing.assert_array_equal(again.start_vector(), x)


def test_input_errors_are_named(chain, campaign):
    model = build(chain, campaign, "errormap")
    with pytest.raises(ValueError, match="approach directions"):
        model.positions(campaign.commands)
    with pytest.raises(OutsideGridError, match="elbow_joint"):
        model.positions(np.array([[0.0, -90.0, 150.0, 0.0, 0.0, 0.0]]), np.ones((1, 6)))
    with pytest.raises(ValueError, match="grid for 'J9'"):
        build_position_model(chain, campaign.commands, campaign.dirs, grids={"J9": [0.0, 1.0]})
    with pytest.raises(ValueError, match="4 joint columns"):
        model.positions(np.zeros((2, 4)), np.ones((2, 4)))
    user = build_position_model(chain, campaign.commands, campaign.dirs,
                                grids={"elbow_joint": [-120.0, 0.0, 120.0]}, tool_offset_mm=TOOL)
    assert "elbow_joint_reverse_deg[2]" in user.names and "elbow_joint_reverse_deg[3]" not in user.names


# ------------------------------------------------------- Jacobian vs differences
CASES = [("distance", "errormap", True), ("point", "errormap", True), ("root", "errormap", True),
         ("distance", "errormap", False), ("point", "errormap", False), ("distance", "dh", True),
         ("point", "dh", False)]


@pytest.mark.parametrize("measure,kind,directions", CASES)
def test_sparse_jacobian_equals_central_differences(chain, campaign, truth, measure, kind, directions):
    small = synthetic_campaign(truth, 25, seed=8, ranges_deg=RANGES, directions="random" if directions else False)
    model = build(chain, campaign if directions else synthetic_campaign(truth, 300, 4, ranges_deg=RANGES,
                                                                        directions=False), kind, directions)
    prob = problem(measure, model, small, truth, directions)
    x = random_vector(prob, 5)
    r, jac = prob.residuals(x)
    assert sp.issparse(jac) and jac.shape == (len(r), len(prob.names))
    fd = np.empty(jac.shape)
    for i in range(len(x)):
        h = np.zeros_like(x)
        h[i] = 1e-5
        fd[:, i] = (prob.residuals(x + h)[0] - prob.residuals(x - h)[0]) / 2e-5
    dense = jac.toarray()
    err = np.abs(dense - fd) / (np.abs(fd).max(axis=0) + 1e-9)
    worst = int(np.argmax(err.max(axis=0)))
    assert err.max() < 1e-6, prob.names[worst]
    # every parameter kind is exercised: some column of each kind is non-zero
    kinds = {"_dx_mm", "tool_x_mm", "_deg[" if kind == "errormap" else "_offset_deg"}
    if kind == "errormap" and directions:
        kinds.add("_reverse_deg[")
    kinds |= {"distance": {"P", "d0_"}, "point": {"frame_rx_deg", "frame_y_mm"}, "root": set()}[measure]
    for k in kinds:
        cols = [i for i, n in enumerate(prob.names) if k in n or n.startswith(k) and k in ("P", "d0_")]
        assert cols and np.abs(dense[:, cols]).max() > 0, k
    # map columns are sparse: each reading touches at most 2 nodes per joint per residual row
    if kind == "errormap":
        maps = [i for i, n in enumerate(prob.names) if "_deg[" in n]
        per_row = np.diff(jac[:, maps].tocsr().indptr)
        assert per_row.max() <= 2 * len(model.maps)


def test_distance_residual_is_eq10_in_3d(chain, campaign, truth):
    model = build(chain, campaign, "errormap")
    prob = problem("distance", model, campaign, truth)
    x = random_vector(prob, 2)
    r, _ = prob.residuals(x)
    p = np.tile(model.positions(campaign.commands, campaign.dirs, x[:model.n_params]), (4, 1))
    P = x[model.n_params:model.n_params + 12].reshape(4, 3)[campaign.station]
    d0 = x[model.n_params + 12:][campaign.station]
    np.testing.assert_allclose(r, np.linalg.norm(p - P, axis=1) - d0 - campaign.displacement_mm, atol=1e-10)
    assert prob.names[model.n_params:model.n_params + 4] == ("P0_x_mm", "P0_y_mm", "P0_z_mm", "P1_x_mm")
    assert prob.names[-1] == "d0_3_mm"


# --------------------------------------------------------------------- gauge
def nullity(jac) -> int:
    dense = jac.toarray() if sp.issparse(jac) else jac
    norms = np.linalg.norm(dense, axis=0)
    s = np.linalg.svd(dense / np.where(norms > 0, norms, 1.0), compute_uv=False)
    return int(np.sum(s < 1e-9 * s[0])) + max(0, dense.shape[1] - dense.shape[0])


@pytest.mark.parametrize("measure,kind,expected", [
    ("distance", "errormap", 7), ("point", "errormap", 7), ("root", "errormap", 1),
    ("distance", "dh", 6), ("point", "dh", 6), ("root", "dh", 0)])
def test_gauge_fixes_exactly_what_the_readings_cannot_see(chain, campaign, truth, measure, kind, expected):
    """Stated: distances and tracker points cannot see a rigid motion of the robot together with
    the stations / tracker frame (6); with error maps, also the zero of the last joint when the
    tool point is off its axis (it trades with tool_x, tool_y)."""
    prob = problem(measure, build(chain, campaign, kind), campaign, truth)
    gauge = find_gauge(prob)
    assert gauge.null_dimension == expected == len(gauge.constraints)
    _, jac = prob.residuals(random_vector(prob, 7))
    assert nullity(jac) == expected  # on the campaign itself, not only on the probe
    assert nullity(np.vstack([jac.toarray(), gauge.A])) == 0
    names = gauge.names
    if measure != "root":
        assert names[:4] == ("gauge: shoulder_pan_joint_dx_mm", "gauge: shoulder_pan_joint_dy_mm",
                             "gauge: shoulder_pan_joint_drx_deg", "gauge: shoulder_pan_joint_dry_deg")
        assert "gauge: shoulder_lift_joint_dy_mm" in names  # the height along J1 (J1 dz was dropped for it)
        assert "rigid motion" in gauge.sentence
        texts = [c.text for c in gauge.constraints]
        assert texts[0].startswith("shoulder_pan_joint_dx_mm = 0 fixes the translation along x of a rigid motion")
        assert "shoulder_pan_joint_drx_deg = 0 (rotation about x through the origin)" in gauge.sentence
        assert "(shoulder_pan_joint map at 0 deg, mean of +1 and -1) = 0 (rotation about z through the origin)" \
            in gauge.sentence or kind == "dh"
        assert "shoulder_lift_joint_dy_mm = 0 (translation along z)" in gauge.sentence
    if kind == "errormap":
        assert names[-1] == "gauge: (wrist_3_joint map at 0 deg, mean of +1 and -1)"
        assert "the zero of wrist_3_joint, which trades with tool_" in gauge.constraints[-1].text
        assert "; the zero of wrist_3_joint, which trades with tool_" in gauge.sentence or measure == "root"
    np.testing.assert_allclose(gauge.A @ prob.start_vector(), gauge.b, atol=1e-12)


def test_gauge_with_one_station_one_directional_and_tool_on_the_last_axis(chain, truth):
    one = synthetic_truth(truth.chain, seed=9, tool_offset_mm=(0.0, 0.0, 60.0), n_stations=1)
    camp = synthetic_campaign(one, 150, seed=10, ranges_deg=RANGES, directions=False)
    model = build(chain, camp, "errormap", directions=False, tool=(0.0, 0.0, 60.0))
    prob = problem("distance", model, camp, one, directions=False)
    gauge = find_gauge(prob)
    assert gauge.null_dimension == 6
    assert "gauge: (shoulder_pan_joint map at 0 deg)" in gauge.names
    _, jac = prob.residuals(random_vector(prob, 11))
    assert nullity(jac) == 6 and nullity(np.vstack([jac.toarray(), gauge.A])) == 0


# -------------------------------------------------------- Gauss-Newton recovery
def gauss_newton(prob, x, A, b, iterations=30):
    """Test-only constrained Gauss-Newton: steps in the null space of the gauge rows."""
    x = x - np.linalg.lstsq(A, A @ x - b, rcond=None)[0]
    Z = scipy.linalg.null_space(A)
    for _ in range(iterations):
        r, jac = prob.residuals(x)
        JZ = jac @ Z
        scale = np.linalg.norm(JZ, axis=0)
        step = np.linalg.lstsq(JZ / scale, -r, rcond=None)[0] / scale
        x = x + Z @ step
        if np.abs(step).max() < 1e-13:
            break
    return x


@pytest.mark.parametrize("measure,kind,directions", [("distance", "errormap", True),
                                                     ("point", "errormap", False),
                                                     ("distance", "dh", False)])
def test_gauss_newton_recovers_a_truth_from_the_model_family(chain, truth, measure, kind, directions):
    camp = synthetic_campaign(truth, 300, seed=12, ranges_deg=RANGES, directions="random" if directions else False)
    model = build(chain, camp, kind, directions)
    prob = problem(measure, model, camp, truth, directions)
    gauge = find_gauge(prob)
    x_true = random_vector(prob, 13)
    x_true -= np.linalg.lstsq(gauge.A, gauge.A @ x_true - gauge.b, rcond=None)[0]  # obey the gauge
    readings = prob.predict(x_true)
    if measure == "distance":
        prob.displacement = readings
    else:
        prob.points = readings
    start = prob.start_vector()  # nominal robot, stations/frame off the truth by a few mm / deg
    assert np.abs(start - x_true).max() > 1.0
    x = gauss_newton(prob, start, gauge.A, gauge.b)
    assert np.abs(prob.residuals(x)[0]).max() < 1e-8
    worst = int(np.argmax(np.abs(x - x_true)))
    assert np.abs(x - x_true).max() < 1e-6, prob.names[worst]


# ------------------------------------------------------------- synthetic truth
def test_synthetic_truth_is_seeded_and_off_the_model_family(chain, truth):
    again = synthetic_truth(chain, seed=3, tool_offset_mm=TOOL)
    np.testing.assert_array_equal(again.chain_params, truth.chain_params)
    a = synthetic_campaign(truth, 50, seed=1, noise_mm=0.001)
    b = synthetic_campaign(truth, 50, seed=1, noise_mm=0.001)
    np.testing.assert_array_equal(a.displacement_mm, b.displacement_mm)
    np.testing.assert_array_equal(a.points_mm, b.points_mm)
    assert not np.array_equal(synthetic_truth(chain, seed=4).chain_params, truth.chain_params)
    # backlash: the same command approached from both sides differs by the backlash
    th = np.zeros((1, 6))
    diff = truth.actual_angles(th, np.ones((1, 6))) - truth.actual_angles(th, -np.ones((1, 6)))
    np.testing.assert_allclose(diff[0], [d.backlash_mdeg * 1e-3 for d in truth.deviations])
    assert np.all(diff > 0)
    # harmonics: between grid nodes the truth is not piecewise linear (not in the model family)
    dev = truth.deviations[0]
    mid = dev(np.array([7.5]), 1.0)[0] - (dev(np.array([0.0]), 1.0)[0] + dev(np.array([15.0]), 1.0)[0]) / 2
    assert abs(mid) > 1e-6
    # the noise-free readings are Eq. (10) of the truth
    clean = synthetic_campaign(truth, 50, seed=1)
    p = np.tile(truth.positions(clean.commands, clean.dirs), (4, 1))
    np.testing.assert_allclose(clean.displacement_mm, np.linalg.norm(p - truth.stations_mm[clean.station], axis=1)
                               - truth.dead_paths_mm[clean.station], atol=1e-9)
    assert 0 < np.std(a.displacement_mm - clean.displacement_mm) < 0.01


@pytest.mark.parametrize("path,frame,tool,height", [
    (UR5.parent / "scara.sdf", "link2", (225.0, 0.0, 0.0), "tool_z_mm"),
    (Path(__file__).resolve().parents[1] / "data" / "arm7_floating.urdf", "tcp", (30.0, -20.0, 50.0), "j2_dy_mm")])
@pytest.mark.parametrize("kind", ["dh", "errormap"])
def test_gauge_of_other_chains(path, frame, tool, height, kind):
    """The SCARA chain (J1, J2, parallel axes) and the 7-joint arm: the same 6 rigid freedoms,
    plus the last joint's zero with maps (it trades with the tool offset)."""
    chain = load_serial_chain(path, frame)
    truth = synthetic_truth(chain, seed=1, tool_offset_mm=tool)
    camp = synthetic_campaign(truth, 200, seed=2)
    model = build_position_model(chain, camp.commands, camp.dirs, kind=kind, grid_step_deg=30.0,
                                 tool_offset_mm=tool)
    gauge = find_gauge(problem("distance", model, camp, truth))
    first = chain.joint_names[0]
    assert gauge.null_dimension == (6 if kind == "dh" else 7)
    assert gauge.names[:4] == tuple(f"gauge: {first}_{s}" for s in ("dx_mm", "dy_mm", "drx_deg", "dry_deg"))
    assert f"gauge: {height}" in gauge.names
    assert f"{height} = 0 (translation along z)" in gauge.sentence
    if kind == "errormap":
        assert f"gauge: ({chain.joint_names[-1]} map at 0 deg, mean of +1 and -1)" in gauge.names


def test_layout_puts_values_under_result_keys(chain, campaign, truth):
    em = problem("distance", build(chain, campaign, "errormap"), campaign, truth)
    x = random_vector(em, 21)
    out = em.layout(x)
    assert out["shoulder_pan_joint_dx_mm"] == x[0]
    assert out["tool_offset_mm"] == list(x[[em.names.index(f"tool_{c}_mm") for c in "xyz"]])
    j2 = out["error_map"]["elbow_joint"]
    assert j2["reverse_deg"][3] == x[em.names.index("elbow_joint_reverse_deg[3]")]
    assert len(j2["grid_deg"]) == len(j2["forward_deg"])
    assert out["stations_mm"][1] == list(x[em.names.index("P1_x_mm"):em.names.index("P1_x_mm") + 3])
    assert out["dead_paths_mm"][3] == x[-1]
    np.testing.assert_allclose(em.beam_lengths(x) - x[-4:][em.station] - em.displacement,
                               em.residuals(x)[0], atol=1e-9)
    one = problem("point", build(chain, campaign, "dh", directions=False), campaign, truth, directions=False)
    out = one.layout(one.start_vector())
    assert "error_map" not in out and out["shoulder_pan_joint_offset_deg"] == 0.0
    np.testing.assert_allclose(out["tracker_frame"]["rotation_deg"], truth.frame[3:])
    np.testing.assert_allclose(one.beam_lengths(one.start_vector()),
                               np.linalg.norm(one.predict(one.start_vector()), axis=1))


def test_error_maps_fit_the_harmonic_truth_far_better_than_dh(chain, truth):
    """The continuous truth is outside both model families; the maps absorb its joint
    deviations and backlash, the D-H model cannot (000's Fig. 9/10 comparison). What the maps
    leave is their interpolation error between nodes: O(step²) for smooth deviations."""
    ranges = np.tile([-90.0, 90.0], (6, 1))
    camp = synthetic_campaign(truth, 400, seed=14, ranges_deg=ranges)
    rms = {}
    for kind, step in (("dh", 15.0), ("errormap", 15.0), ("errormap", 7.5)):
        prob = problem("distance", build(chain, camp, kind, step=step), camp, truth)
        gauge = find_gauge(prob)
        x = gauss_newton(prob, prob.start_vector(), gauge.A, gauge.b, iterations=8)
        rms[kind, step] = float(np.sqrt(np.mean(prob.residuals(x)[0] ** 2)))
    assert rms["dh", 15.0] > 0.05  # mm: the harmonics and backlash the D-H model cannot follow
    assert rms["errormap", 15.0] < rms["dh", 15.0] / 5
    assert rms["errormap", 7.5] < rms["errormap", 15.0] / 3  # halving the step: ≈ 4× less
