"""The Meshcat live view of a campaign: scene tree, error vectors, and a headless-browser render."""

import shutil
import subprocess

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from olti_drake.hardware.station import AddStation
from olti_drake.sim.campaign import build_campaign_diagram, prepare
from olti_drake.report.diagram_pictures import DIAGRAMS_DIR
from olti_drake.sim.meshcat_view import campaign_view, start_meshcat
from olti_drake.sim.scenario import load_scenario

ROWS = 40  # simulated seconds = plan rows (period 1 s)


def _run(meshcat, scenario, rows=ROWS, scale=500.0):
    setup = prepare(load_scenario(DIAGRAMS_DIR / scenario))
    systems = {}
    diagram, rec, _ = build_campaign_diagram(setup, AddStation, extend=campaign_view(meshcat, error_scale=scale,
                                                                                     systems=systems))
    simulator = Simulator(diagram)
    try:
        simulator.AdvanceTo(rows * setup.scenario.period_s)
    finally:
        if hasattr(diagram.station, "close"):
            diagram.station.close()
    return setup, systems, rec, simulator.get_context()


@pytest.fixture(scope="module")
def simulated():
    meshcat = start_meshcat()
    setup, systems, rec, context = _run(meshcat, "paper000_scara.yaml")
    return meshcat, setup, systems, rec, context


def test_scene_has_arm_beam_reflectors_and_error_vectors(simulated):
    meshcat, setup, systems, rec, context = simulated
    for path in ("/drake/visualizer/scara", "/drake/campaign/beam", "/drake/campaign/reflector_in_use",
                 "/drake/campaign/errors/forward/000"):
        assert meshcat.HasPath(path), path
    for j in range(len(setup.reflectors_mm)):
        assert meshcat.HasPath(f"/drake/visualizer/reflectors/reflector_{j}")
    assert not meshcat.HasPath("/drake/campaign/errors/predicted/000")
    # One error vector per measured row, as the recorder keeps them.
    assert systems["error_vectors"].Count(context) == len(rec.GetReadings(context)) > 10


def test_error_vectors_are_magnified_errors(simulated):
    _, setup, systems, _, context = simulated
    seg = systems["error_vectors"].GetSegments(context, "forward")
    lengths_mm = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1) * 1e3
    # The true robot is off by tens of µm at the flange (L1, L2 -30/+4 µm, mdeg joint errors): x500 -> mm to dm.
    assert 1.0 < np.median(lengths_mm) < 300.0
    assert np.allclose(seg[:, 0, 2], seg[:, 1, 2])  # flat, at the flange height


def test_predicted_vectors_and_scale():
    meshcat = start_meshcat()
    setup = prepare(load_scenario(DIAGRAMS_DIR / "paper000_scara.yaml"))
    systems = {}
    diagram, _, _ = build_campaign_diagram(setup, extend=campaign_view(
        meshcat, error_scale=1000.0, predict=lambda t1, t2, d1, d2: (0.0, 0.0), systems=systems))
    simulator = Simulator(diagram)
    simulator.AdvanceTo(6)
    assert meshcat.HasPath("/drake/campaign/errors/predicted/000")
    seg = systems["error_vectors"].GetSegments(simulator.get_context(), "predicted")
    # A prediction at the origin: the vector points from the command toward it, 1000 times too long.
    assert np.allclose(seg[:, 1, :2], -999.0 * seg[:, 0, :2])


def test_emulated_station_gets_a_view_plant():
    meshcat = start_meshcat()
    _, systems, rec, context = _run(meshcat, "paper000_emulated.yaml", rows=8)
    assert systems["plant"].to_pose.get_name() == "view_plant"
    assert meshcat.HasPath("/drake/visualizer/scara") and meshcat.HasPath("/drake/campaign/beam")
    assert systems["error_vectors"].Count(context) == len(rec.GetReadings(context)) > 0


def test_no_view_no_systems_and_the_view_changes_no_reading(simulated):
    setup = prepare(load_scenario(DIAGRAMS_DIR / "paper000_scara.yaml"))
    diagram, rec, _ = build_campaign_diagram(setup)
    assert sorted(s.get_name() for s in diagram.GetSystems()) == [
        "beam_steering", "campaign_recorder", "plan_sequencer", "station"]
    simulator = Simulator(diagram)
    simulator.AdvanceTo(ROWS * setup.scenario.period_s)
    np.testing.assert_array_equal(np.array(rec.GetReadings(simulator.get_context()), dtype=float),
                                  np.array(simulated[3].GetReadings(simulated[4]), dtype=float))


#: Headless Chromium with software WebGL (SwiftShader through ANGLE); Debian package chromium. Every host but
#: localhost is unresolvable: Meshcat serves its page and JavaScript itself, no network is needed.
CHROMIUM_FLAGS = ("--headless=new", "--no-sandbox", "--disable-gpu", "--use-gl=angle", "--use-angle=swiftshader",
                  "--window-size=1024,768", "--virtual-time-budget=5000", "--hide-scrollbars",
                  "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE localhost")


@pytest.mark.skipif(shutil.which("chromium") is None, reason="chromium not installed (Debian package chromium)")
def test_headless_chromium_renders_the_scene(simulated, tmp_path):
    import matplotlib.image as mpimg

    meshcat = simulated[0]
    png = tmp_path / "meshcat.png"
    run = subprocess.run(["chromium", *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'profile'}",
                          f"--screenshot={png}", meshcat.web_url()], capture_output=True, text=True, timeout=120)
    assert png.is_file(), run.stderr[-2000:]
    img = mpimg.imread(png)[..., :3]
    R, G, B = img[..., 0], img[..., 1], img[..., 2]
    distinct = len(np.unique((img * 255).astype(np.uint8).reshape(-1, 3), axis=0))
    red = int(np.sum((R > 0.6) & (G < 0.3) & (B < 0.3)))                          # beam, reflectors, vectors
    orange = int(np.sum((R > 0.8) & (G > 0.5) & (G < 0.85) & (B < 0.4)))           # the arm's links
    print(f"screenshot: {distinct} colours, {red} red px, {orange} orange px")
    # A page without WebGL is one flat colour plus the controls bar; the scene has shading and our colours.
    assert distinct > 200, distinct
    assert red > 100, red
    assert orange > 500, orange
