"""CNC exports of an identified five-axis model (issue 25, item 6; docs/cnc_exports.md): every format written,
read back by its parser and re-simulated against the model's tool points on 10⁴ random commands -- ≤ 1 µm
where the format holds the model, else the stated residual equals the measured one; refusals in one line."""

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.io import cnc
from olti_drake.io.cnc_kin import nominal_kinematics, random_commands, residual
from olti_drake.model.five_axis import FiveAxisMachine
from olti_drake.model.five_axis_errors import COMPONENTS, FiveAxisErrors
from olti_drake.model.five_axis_truth import synthetic_truth

MODELS = "olti_drake/models/"


def _machine(name):
    return FiveAxisMachine.from_file(MODELS + name + ".urdf", "workpiece", "tool")


@pytest.fixture(scope="module")
def trunnion():
    return _machine("trunnion_ac")


@pytest.fixture(scope="module")
def swivel():
    return _machine("swivel_head_bc")


def truth_vector(em, truth):
    """The error model's x at a truth: its location errors, its error motions at the grid nodes."""
    x = em.zeros()
    for name, v in truth.location.items():
        if name in em.names:
            x[em.names.index(name)] = v
    for (L, c), jm in em.maps.items():
        g = jm.emap.grid_deg
        branches = (1, -1) if em.bidirectional else (1,)
        x[em.slices[jm.joint]] = np.concatenate([truth.motion_values(L, g, s)[:, COMPONENTS.index(c)]
                                                 for s in branches])
    return x


def located(machine, seed=1):
    em = FiveAxisErrors(machine, motions=False)
    return em, truth_vector(em, synthetic_truth(machine, seed, motions=False))


def with_motions(machine, seed=2):
    em = FiveAxisErrors(machine, pitch_deg=15.0, bidirectional=True)
    return em, truth_vector(em, synthetic_truth(machine, seed))


def _measured(fmt, machine, em, x, report):
    path = report.paths[0] if fmt != "heidenhain" else str(__import__("pathlib").Path(report.paths[0]).parent)
    return residual(cnc.LOADERS[fmt](path, machine, em), machine, em, x)


def test_nominal_kinematics_is_the_model_file(trunnion, swivel):
    for m in (trunnion, swivel):
        c, _ = random_commands(m, 500, seed=3)
        assert np.abs(nominal_kinematics(m).points(c) - m.tool_points(c)).max() < 1e-9


@pytest.mark.parametrize("fmt", ["sinumerik", "heidenhain", "csv"])
def test_round_trip_where_the_format_holds_the_location_errors(fmt, trunnion, swivel, tmp_path):
    for m in (trunnion, swivel):
        em, x = located(m)
        rep = cnc.export(fmt, m, em, x, tmp_path / m.path.split("/")[-1])
        meas = _measured(fmt, m, em, x, rep)
        assert rep.cannot_hold == ()
        assert rep.max_um <= 1.0 and meas["max_um"] <= 1.0, (fmt, m.path, rep.describe())


@pytest.mark.parametrize("fmt", ["heidenhain", "csv"])
def test_round_trip_of_the_bidirectional_error_motions(fmt, trunnion, swivel, tmp_path):
    for m in (trunnion, swivel):
        em, x = with_motions(m)
        rep = cnc.export(fmt, m, em, x, tmp_path / m.path.split("/")[-1])
        meas = _measured(fmt, m, em, x, rep)
        assert rep.cannot_hold == ()
        assert meas["raw_max_um"] <= 1.0 and rep.residual["raw_max_um"] <= 1.0, rep.describe()


@pytest.mark.parametrize("fmt,machine_name,motions", [("fanuc", "trunnion_ac", False), ("fanuc", "swivel_head_bc", False),
                                                       ("linuxcnc", "trunnion_ac", False),
                                                       ("sinumerik", "trunnion_ac", True)])
def test_stated_residual_is_the_measured_one(fmt, machine_name, motions, tmp_path):
    m = _machine(machine_name)
    em, x = with_motions(m) if motions else located(m)
    rep = cnc.export(fmt, m, em, x, tmp_path)
    meas = _measured(fmt, m, em, x, rep)
    for key in ("max_um", "rms_um", "raw_max_um", "raw_rms_um"):
        assert meas[key] == pytest.approx(rep.residual[key], rel=0.01), (key, rep.describe())
    assert rep.max_um > 5.0  # (what the format cannot hold is tens of µm here, and named:)
    kinds = " ".join(rep.cannot_hold)
    if motions:
        assert "E_CC" in kinds and "angle-dependent" in kinds
    else:
        assert "E_A0C_urad" in kinds and "E_B0C_urad" in kinds
    # another draw of 10⁴ commands states the same RMS
    again = residual(cnc.LOADERS[fmt](rep.paths[0], m, em), m, em, x, seed=11)
    assert again["rms_um"] == pytest.approx(rep.rms_um, rel=0.05)


def test_linuxcnc_pins_mean_what_xyzac_trt_kins_computes(trunnion, tmp_path):
    """The loader's machine equals LinuxCNC's own forward kinematics (trtfuncs.c, xyzacKinematicsForward) with
    the written pins, joints = the commands (A, C shifted by the HOME_OFFSET corrections)."""
    em, x = located(trunnion)
    rep = cnc.export_linuxcnc(trunnion, em, x, tmp_path / "xyzac-trt.hal")
    pins = {}
    for line in open(rep.paths[0]):
        if line.startswith("setp"):
            _, name, value = line.split()
            pins[name.split(".")[1]] = float(value)
    home = [float(line.split("=")[1]) for line in open(rep.paths[1]) if line.startswith("HOME_OFFSET")]
    c, _ = random_commands(trunnion, 2000, seed=5)
    J = c[:, :3]
    a, cc = np.radians(c[:, 3] + home[0]), np.radians(c[:, 4] + home[1])
    xr, yr, zr = pins["x-rot-point"], pins["y-rot-point"], pins["z-rot-point"]
    dy, dz = pins["y-offset"], pins["z-offset"]
    pos = np.stack([
        np.cos(cc) * (J[:, 0] - xr) + np.sin(cc) * np.cos(a) * (J[:, 1] - dy - yr)
        + np.sin(cc) * np.sin(a) * (J[:, 2] - dz - zr) + np.sin(cc) * dy + xr,
        -np.sin(cc) * (J[:, 0] - xr) + np.cos(cc) * np.cos(a) * (J[:, 1] - dy - yr)
        + np.cos(cc) * np.sin(a) * (J[:, 2] - dz - zr) + np.cos(cc) * dy + yr,
        -np.sin(a) * (J[:, 1] - dy - yr) + np.cos(a) * (J[:, 2] - dz - zr) + dz + zr], axis=1)
    nominal = nominal_kinematics(trunnion)
    table_to_workpiece = nominal.origin - nominal.work  # (table coordinates: the machine's at A = C = 0)
    kin = cnc.load_linuxcnc(rep.paths[0], trunnion, em)
    assert np.abs(pos + table_to_workpiece - kin.points(c)).max() < 1e-9


def test_nominal_swivel_data_are_the_model_file(trunnion, tmp_path):
    em = FiveAxisErrors(trunnion, motions=False)
    rep = cnc.export_sinumerik(trunnion, em, em.zeros(), tmp_path / "s.mpf")
    values = {}
    for line in open(rep.paths[0]):
        if line.startswith("$TC_CARR"):
            key, value = line.split(";")[0].split("=")
            values[int(key[8:key.index("[")])] = value.strip().strip('"')
    num = lambda ks: [float(values[k]) for k in ks]  # noqa: E731
    assert values[23] == "P" and (values[21], values[22]) == ("A", "C")
    assert num((4, 5, 6)) == pytest.approx([0, 0, -100]) and num((15, 16, 17)) == pytest.approx([0, 15, -80])
    assert num((18, 19, 20)) == pytest.approx([0, -15, 180])  # the closure l4 = -(l2 + l3)
    assert num((7, 8, 9)) == pytest.approx([-1, 0, 0]) and num((10, 11, 12)) == pytest.approx([0, 0, -1])
    assert num(list(range(41, 47)) + list(range(55, 61)) + [64, 65]) == pytest.approx(np.zeros(14), abs=1e-6)
    assert rep.max_um < 1e-3 and rep.residual["raw_max_um"] < 1e-3


def test_refusals_are_one_line(trunnion, swivel, tmp_path):
    em, x = located(swivel)
    with pytest.raises(InputError) as exc:
        cnc.export_linuxcnc(swivel, em, x, tmp_path / "k.hal")
    assert "xyzac-trt-kins" in str(exc.value) and "head B" in str(exc.value) and "\n" not in str(exc.value)
    emt, xt = located(trunnion)
    far = xt.copy()
    far[emt.names.index("E_Y0A_mm")] = -12_000.0  # the A line 12 m away: beyond IS-C's ±9999.9999 mm
    with pytest.raises(InputError) as exc:
        cnc.export_fanuc(trunnion, emt, far, tmp_path / "f.txt", increment="IS-C")
    assert "19701" in str(exc.value) and "field" in str(exc.value) and "\n" not in str(exc.value)
    rep = cnc.export_sinumerik(trunnion, emt, xt, tmp_path / "s.mpf")
    with pytest.raises(InputError) as exc:
        cnc.load_sinumerik(rep.paths[0], swivel)
    assert "type 'P'" in str(exc.value) and "\n" not in str(exc.value)
    rep = cnc.export_csv(trunnion, emt, xt, tmp_path / "v.csv")
    with pytest.raises(InputError) as exc:
        cnc.load_csv(rep.paths[0], trunnion, FiveAxisErrors(trunnion, motions=True))
    assert "missing E_XA" in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(InputError, match="unknown format"):
        cnc.export("okuma", trunnion, emt, xt, tmp_path)
