"""The hardware station (olti_drake/hardware.py): the campaign diagram driving the device emulator
through its pseudo-terminals gives the simulated campaign, and identifies the same robot."""

import dataclasses
import os

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.hardware.station import AddStation
from olti_drake.sim.campaign import prepare, run_campaign
from olti_drake.model.instrument import InterferometerOptions
from olti_drake.sim.scenario import Emulated, ExactEstimate, Hardware, Scenario, Simulated, as_plain, load_scenario

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DIAGRAMS = os.path.join(ROOT, "diagrams")
SAME = ("reflector", "theta1_deg", "theta2_deg", "dir1", "dir2", "theta4_deg", "valid", "plan_row")


def _quiet(station) -> Scenario:
    s = Scenario(reflector_estimate=ExactEstimate(), station=station,
                 interferometer=InterferometerOptions(noise=False, quantization=False, cosine_error=False,
                                                      beam_loss=False))
    return s.validate()


def test_noise_free_emulated_campaign_equals_the_simulated_one():
    sim = run_campaign(prepare(_quiet(Simulated())))
    emu = run_campaign(prepare(_quiet(Emulated(speed="fast"))), station_factory=AddStation)
    assert emu.n_readings == sim.n_readings == 1056
    for k in SAME:
        assert np.array_equal(emu.columns[k], sim.columns[k]), k
    assert np.all(emu.columns["valid"] == 1)
    # The counter zeros differ (the emulated one is zeroed at the first row of each reflector's run,
    # the simulated one at its first measured pose): compare readings within a reflector's run.
    for j in range(3):
        m = emu.columns["reflector"] == j
        de, ds = emu.columns["displacement_mm"][m], sim.columns["displacement_mm"][m]
        np.testing.assert_allclose(de - de[0], ds - ds[0], rtol=0, atol=1e-5)


@pytest.fixture(scope="module")
def paper_pair():
    from olti_drake.estimation.identification import identify
    from olti_drake.report.validation import campaign_data

    out = {}
    for name, station in (("sim", Simulated()), ("emu", Emulated())):
        campaign = run_campaign(prepare(Scenario(station=station)), station_factory=AddStation)
        out[name] = (campaign, identify(campaign_data(campaign)))
    return out


def test_emulated_paper_campaign_identifies_the_same_robot(paper_pair):
    (sim, rs), (emu, re) = paper_pair["sim"], paper_pair["emu"]
    for k in ("reflector", "theta1_deg", "theta2_deg", "dir1", "dir2", "plan_row"):
        assert np.array_equal(emu.columns[k], sim.columns[k]), k
    assert np.sum(emu.columns["valid"]) > 0.95 * emu.n_readings
    ok = emu.columns["valid"] == 1
    assert np.all(np.isfinite(emu.columns["displacement_mm"][ok]))
    assert np.all(np.isnan(emu.columns["displacement_mm"][~ok]))  # a lost beam is no reading
    for name in ("L1_mm", "L2_mm"):
        u = rs.uncertainty(name)  # independent noise draws: about 1.5 u apart at seed 0
        assert abs(re.value(name) - rs.value(name)) < 3 * u, (name, re.value(name), rs.value(name), u)


def test_shipped_station_diagrams_load():
    base = as_plain(load_scenario(os.path.join(DIAGRAMS, "paper000_scara.yaml")))
    emu = load_scenario(os.path.join(DIAGRAMS, "paper000_emulated.yaml"))
    hw = load_scenario(os.path.join(DIAGRAMS, "paper000_hardware.yaml"))
    assert emu.station == Emulated(speed="fast")
    assert hw.station == Hardware(robot_port="/dev/ttyUSB0", counter_port="/dev/ttyUSB1")
    for s, differs in ((emu, {"station"}), (hw, {"station", "reflector_estimate"})):
        plain = as_plain(s)
        assert {k for k in plain if plain[k] != base[k]} == differs
    assert isinstance(load_scenario(os.path.join(DIAGRAMS, "paper000_scara.yaml")).station, Simulated)


def test_hardware_station_on_a_missing_port_names_it():
    port = "/dev/olti-no-such-port-0"
    s = dataclasses.replace(_quiet(Simulated()), station=Hardware(robot_port=port, counter_port=port + "1"))
    with pytest.raises(InputError) as e:
        run_campaign(prepare(s), station_factory=AddStation)
    msg = str(e.value)
    assert port in msg and "robot" in msg and "\n" not in msg


def test_station_errors_name_the_command():
    from pydrake.systems.analysis import Simulator

    from olti_drake.sim.campaign import build_campaign_diagram
    from olti_drake.hardware.station import StationError

    diagram, rec, seq = build_campaign_diagram(prepare(_quiet(Emulated())), AddStation)
    try:
        diagram.station.emulator.raise_alarm()
        with pytest.raises(StationError, match=r"controller alarm EMU_INJECTED at the move to \(-142\.000000, .*clears at most 0"):
            simulator = Simulator(diagram)
            simulator.AdvanceTo(seq.duration_s)
    finally:
        diagram.station.close()
    assert not rec.GetReadings(simulator.get_context())
