"""The six-axis campaign in Meshcat (issue 14 item 3): the arm, the stations, the beam and the 3D error vectors."""

import numpy as np
import pytest

from olti_drake.sim import serial_station as ss
from olti_drake.sim.serial_scenario import load_serial_scenario
from olti_drake.sim.serial_view import add_serial_view, start_meshcat
from tests.sim.test_six_axis import EXACT, SIX_AXIS


@pytest.fixture(scope="module")
def run():
    from pydrake.systems.analysis import Simulator

    setup = ss.prepare_serial(load_serial_scenario(SIX_AXIS, None, EXACT))
    meshcat = start_meshcat()
    added = {}

    def extend(builder, s, station, seq):
        added.update(add_serial_view(builder, meshcat, s, station, seq, error_scale=1000.0))

    diagram, rec, seq = ss.build_serial_diagram(setup, extend=extend)
    rows = 40
    results = []
    for _ in range(2):  # two Simulators on one diagram: each has its own error vectors
        sim = Simulator(diagram)
        sim.AdvanceTo(rows * setup.scenario.period_s)
        results.append(sim.get_context())
    return setup, meshcat, added, results, rows


def test_error_vectors_are_the_magnified_3d_errors_of_the_measured_rows(run):
    setup, meshcat, added, (ctx, ctx2), rows = run
    view = added["campaign_view"]
    measured = int(setup.measure[:rows].sum())
    assert view.Count(ctx) == measured == view.Count(ctx2) > 0
    seg = np.concatenate([view.GetSegments(ctx, "forward"), view.GetSegments(ctx, "reverse")])
    # every start is a commanded tool point of a measured row (nominal model), every end c + 1000 (a - c)
    cmd = setup.commands_deg[:rows][setup.measure[:rows]]
    dirs = setup.dirs[:rows][setup.measure[:rows]]
    nominal = setup.chain.positions(cmd, setup.chain.nominal_parameters(setup.tool_offset_mm)) / 1e3
    actual = setup.truth.positions(cmd, dirs) / 1e3
    for c, a in zip(nominal, actual):
        k = np.argmin(np.linalg.norm(seg[:, 0] - c, axis=1))
        assert np.allclose(seg[k, 0], c, atol=1e-12)
        assert np.allclose(seg[k, 1], c + 1000.0 * (a - c), atol=1e-9)
    # the truth moves the tool by tenths of a millimetre: magnified, the vectors are tens of centimetres
    assert 0.01 < np.median(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)) < 5.0


def test_meshcat_shows_the_arm_the_stations_and_the_beam(run):
    setup, meshcat, added, _, _ = run
    assert meshcat.HasPath("six_axis/beam") and meshcat.HasPath("six_axis/stations/0")
    assert meshcat.HasPath(f"six_axis/stations/{len(setup.stations_mm) - 1}")
    assert meshcat.HasPath("visualizer")
    assert added["view_plant"].num_positions() >= setup.n_joints
