"""The committed diagram pictures and wiring files match the diagrams the code builds (olti diagrams)."""

import shutil

import pytest
from olti_calls import olti_sub

from olti_drake.report.diagram_pictures import (DIAGRAMS_DIR, SCENARIOS, campaign_diagram, graphviz_source, read_wiring,
                                         render_svg, wiring_lines)

REGENERATE = "wiring changed: run `olti diagrams` and commit diagrams/*.svg and diagrams/*.wiring.txt"


@pytest.fixture(scope="module")
def built():
    """name -> (wiring lines, graphviz source) of the three shipped scenarios, built once."""
    out = {}
    for name, scenario in SCENARIOS.items():
        with campaign_diagram(DIAGRAMS_DIR / scenario) as diagram:
            out[name] = (wiring_lines(diagram), graphviz_source(diagram), type(diagram.station).__name__)
    return out


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_committed_wiring_matches_the_code(built, name):
    committed = read_wiring(DIAGRAMS_DIR / f"{name}.wiring.txt")
    assert committed == built[name][0], REGENERATE
    assert (DIAGRAMS_DIR / f"{name}.svg").is_file(), REGENERATE


def test_the_three_stations_offer_the_same_ports_to_the_procedure(built):
    # Top-level wiring (sequencer, steering, recorder <-> station) is identical; only the inside differs.
    top = {name: [line for line in lines if "/" not in line] for name, (lines, _, _) in built.items()}
    assert top["paper000_scara"] == top["paper000_emulated"] == top["paper000_hardware"]
    station_ports = {line.split(" -> ")[1] for line in top["paper000_scara"] if " -> station." in line}
    station_ports |= {line.split(" -> ")[0] for line in top["paper000_scara"] if line.startswith("station.")}
    assert station_ports >= {"station.joint_command", "station.reflector", "station.direction",
                             "station.displacement", "station.valid"}
    # The simulated station is a sub-diagram (plant, error map, laser); the others are the serial LeafSystem.
    assert built["paper000_scara"][2] == "Diagram"
    assert built["paper000_emulated"][2] == built["paper000_hardware"][2] == "HardwareStation"
    assert "station/error_map_joint.position -> station/plant.position" in built["paper000_scara"][0]


def test_hardware_diagram_opens_no_port(built):
    # Built from the scenario naming /dev/ttyUSB0 and /dev/ttyUSB1, which this machine need not have.
    assert "station.valid -> campaign_recorder.valid" in built["paper000_hardware"][0]


@pytest.mark.skipif(shutil.which("dot") is None, reason="graphviz 'dot' not installed (Debian package graphviz)")
def test_svg_renders_with_the_system_names(built):
    svg = render_svg(built["paper000_scara"][1])
    assert svg.lstrip().startswith("<?xml") and "<svg" in svg
    for name in ("plan_sequencer", "beam_steering", "campaign_recorder", "station", "error_map_joint",
                 "laser_interferometer", "LaserInterferometer", "query_object"):
        assert name in svg, name
    committed = (DIAGRAMS_DIR / "paper000_hardware.svg").read_text(encoding="utf-8")
    assert "HardwareStation" in committed and "plan_sequencer" in committed


def test_missing_dot_is_one_line(tmp_path):
    run = olti_sub("diagrams", "--out", tmp_path, env={"PATH": str(tmp_path)}, cwd=tmp_path, timeout=60, expect=2)
    assert run.stderr.strip() == "error: graphviz 'dot' not found; install Debian package graphviz"
    assert not list(tmp_path.iterdir())
