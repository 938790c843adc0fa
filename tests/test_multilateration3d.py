"""The machine tool in 3D (issue 15 items 1-2): the 3D campaign reader (``z_cmd_mm``, ``tool``), the
simulated 3D campaign on pan/tilt heads, and 3D self-calibrating multilateration (001 Eq. 2-6 in R^3)."""

import numpy as np
import pytest

from olti_drake.estimation.leastsquares import UnidentifiableError
from olti_drake.estimation.multilateration import load_machine_campaign, machine_campaign
from olti_drake.io.csvio import InputError
from olti_drake.model.machine import Machine3DScenario, simulate_machine_campaign_3d, write_machine_campaign


@pytest.fixture(scope="module")
def campaign3d():
    """A small 3D campaign: 60 targets (5 x 4 x 3 grid), 5 heads, seeded."""
    return simulate_machine_campaign_3d(Machine3DScenario(seed=4))


def test_3d_reader_gives_dim_commands_and_tools(tmp_path, campaign3d):
    cols, truth = campaign3d
    path = tmp_path / "c3.csv"
    write_machine_campaign(cols, path)
    data = load_machine_campaign(path)
    assert data.dim == 3 and data.commands_mm.shape == (60, 3) and data.n_stations == 5
    np.testing.assert_allclose(data.commands_mm, truth["commands_mm"], atol=1e-6)
    assert data.tool.tolist() == [0] * 60
    flat = {k: v for k, v in cols.items() if k not in ("z_cmd_mm", "tool")}
    assert machine_campaign(flat).dim == 2  # without z_cmd_mm: the 2D campaign of formats.md


def test_3d_reader_refuses_a_target_whose_rows_disagree_naming_both_lines(tmp_path, campaign3d):
    cols, _ = campaign3d
    path = tmp_path / "c3.csv"
    write_machine_campaign(cols, path)
    lines = path.read_text().splitlines()
    header = [k for k, line in enumerate(lines) if line.startswith("station")][0]
    names = lines[header].split(",")
    # The second reading of target 0 (station 1's row) gets another z command, then another tool.
    row = header + 1 + 60
    for column, value in (("z_cmd_mm", "7.5"), ("tool", "1")):
        bad = list(lines)
        fields = bad[row].split(",")
        fields[names.index(column)] = value
        bad[row] = ",".join(fields)
        (tmp_path / "bad.csv").write_text("\n".join(bad) + "\n")
        with pytest.raises(InputError, match=rf"bad.csv:{row + 1}: target 0 has command .* on line {header + 2}"):
            load_machine_campaign(tmp_path / "bad.csv")


def test_3d_simulation_is_seeded_and_reads_the_volumetric_truth(campaign3d):
    cols, truth = campaign3d
    again, _ = simulate_machine_campaign_3d(Machine3DScenario(seed=4))
    np.testing.assert_array_equal(cols["displacement_mm"], again["displacement_mm"])
    other, _ = simulate_machine_campaign_3d(Machine3DScenario(seed=5))
    assert not np.allclose(cols["displacement_mm"], other["displacement_mm"], equal_nan=True)
    # The reading is the true distance (truth targets and heads) minus the dead path, to the budget's noise.
    T, P, L0 = (np.asarray(truth[k]) for k in ("targets_mm", "stations_mm", "dead_paths_mm"))
    i, j, ok = cols["target"], cols["station"], cols["valid"] == 1
    model = np.linalg.norm(T[i] - P[j], axis=1) - L0[j]
    from olti_drake.model.machine import paper001_budget

    pose = paper001_budget().combined("pose")  # the head's radial error motion moves the beam origin (001 Table 4)
    assert ok.mean() > 0.95 and np.abs(model - cols["displacement_mm"])[ok].max() < 2e-3 + 5 * pose
    # The truth is not the commands: the 21 motions move the tool by micrometres.
    dev = np.asarray(truth["targets_mm"]) - (np.asarray(truth["commands_mm"]) + np.asarray(truth["tool_offsets_mm"])[0])
    assert 1e-3 < np.abs(dev).max() < 0.2
