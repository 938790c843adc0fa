"""Pictures of the campaign diagrams: Graphviz SVGs and plain wiring files (``olti diagrams``).

For each shipped scenario (simulated, emulated, hardware station) the campaign
Diagram is built exactly as ``olti simulate`` builds it, then

- ``NAME.svg``: ``Diagram.GetGraphvizString()`` rendered by Graphviz ``dot``;
- ``NAME.wiring.txt``: every connection, one sorted line
  ``src_system.port -> dst_system.port``; systems inside a sub-diagram are
  ``station/error_map_joint``, a sub-diagram's exported ports appear as
  ``station.joint_command -> station/error_map_joint.command``.

The hardware station is built on transports that are never opened
(:func:`olti_drake.hardware.station.AddHardwareStation` with no ports), so no
serial device is needed; the emulated one starts the emulator and closes it.
``tests/report/test_diagrams.py`` keeps the committed wiring files equal to the code.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from contextlib import contextmanager

from olti_drake.errors import InputError
from olti_drake.io.resources import shipped

#: The shipped scenarios (installed with the package; the top-level diagrams/ in a source checkout).
DIAGRAMS_DIR = shipped("diagrams")
#: Output name -> scenario file in ``diagrams/``.
SCENARIOS = {"paper000_scara": "paper000_scara.yaml",
             "paper000_emulated": "paper000_emulated.yaml",
             "paper000_hardware": "paper000_hardware.yaml",
             "six_axis": "six_axis.yaml"}
_ADDRESS = re.compile(r"@[0-9a-fA-F]{8,}")   # unnamed systems: drake/geometry/SceneGraph@0000...
_SOURCE_ID = re.compile(r"\bSource_\d+_")    # SceneGraph ports carry a process-wide source id


def _clean(name: str) -> str:
    """A system or port name without process-dependent parts (addresses, source ids)."""
    return _SOURCE_ID.sub("Source_", _ADDRESS.sub("", name))


def unopened_hardware_station(builder, setup, name: str = "station"):
    """The hardware station on transports that are never opened: for pictures and wiring only."""
    from olti_drake.hardware.station import AddHardwareStation

    return AddHardwareStation(builder, setup, (None, None), None, name)


@contextmanager
def campaign_diagram(scenario_path, extend=None):
    """Build the scenario's campaign Diagram (the hardware one unopened); close its station on exit."""
    from olti_drake.hardware.station import AddStation
    from olti_drake.sim.campaign import build_campaign_diagram, prepare
    from olti_drake.sim.scenario import Hardware, load_scenario
    from olti_drake.sim.serial_station import build_serial_diagram, prepare_serial
    from olti_drake.sim.serial_scenario import load_serial_scenario, scenario_kind

    if scenario_kind(scenario_path) == "serial":  # a six-axis scenario: the N-joint diagram (sim/serial_station.py)
        yield build_serial_diagram(prepare_serial(load_serial_scenario(scenario_path)))[0]
        return
    setup = prepare(load_scenario(scenario_path))
    factory = unopened_hardware_station if isinstance(setup.scenario.station, Hardware) else AddStation
    diagram, _, _ = build_campaign_diagram(setup, station_factory=factory, extend=extend)
    try:
        yield diagram
    finally:
        close = getattr(diagram.station, "close", None)
        if close is not None:
            close()


def wiring_lines(diagram, prefix: str = "") -> list:
    """Sorted ``src.port -> dst.port`` lines of ``diagram`` and, recursively, of its sub-diagrams."""
    from pydrake.systems.framework import Diagram

    def sys_name(system):
        return prefix + _clean(system.get_name())

    lines = []
    for (dst, i), (src, o) in diagram.connection_map().items():
        lines.append(f"{sys_name(src)}.{_clean(src.get_output_port(o).get_name())} -> "
                     f"{sys_name(dst)}.{_clean(dst.get_input_port(i).get_name())}")
    for system in diagram.GetSystems():
        if not isinstance(system, Diagram):
            continue
        inner = sys_name(system) + "/"
        for k in range(system.num_input_ports()):
            port = system.get_input_port(k)
            for dst, i in system.GetInputPortLocators(port.get_index()):
                lines.append(f"{sys_name(system)}.{port.get_name()} -> "
                             f"{inner}{_clean(dst.get_name())}.{_clean(dst.get_input_port(i).get_name())}")
        for k in range(system.num_output_ports()):
            port = system.get_output_port(k)
            src, o = system.get_output_port_locator(port.get_index())
            lines.append(f"{inner}{_clean(src.get_name())}.{_clean(src.get_output_port(o).get_name())} -> "
                         f"{sys_name(system)}.{port.get_name()}")
        lines.extend(wiring_lines(system, inner))
    return sorted(lines)


def graphviz_source(diagram, max_depth=None) -> str:
    """``GetGraphvizString`` made stable: process-dependent names cleaned, each block of edges sorted.

    (Drake lists the edges in the order of its connection map, keyed by memory addresses.)
    """
    out, edges = [], []
    for line in _clean(diagram.GetGraphvizString(max_depth=max_depth)).splitlines():
        if " -> " in line:
            edges.append(line)
            continue
        out += sorted(edges) + [line]
        edges = []
    return "\n".join(out + sorted(edges)) + "\n"


def find_dot() -> str:
    dot = shutil.which("dot")
    if dot is None:
        raise InputError("graphviz 'dot' not found; install Debian package graphviz")
    return dot


def render_svg(dot_source: str, dot: str = None) -> str:
    """The SVG text of a Graphviz source (``dot -Tsvg``)."""
    run = subprocess.run([dot or find_dot(), "-Tsvg"], input=dot_source, capture_output=True, text=True,
                         timeout=60)
    if run.returncode != 0:
        raise RuntimeError(f"dot -Tsvg failed: {run.stderr.strip()}")
    return run.stdout


def write_pictures(out_dir=None, names=None, max_depth=None) -> list:
    """Write ``NAME.svg`` and ``NAME.wiring.txt`` of each shipped scenario; returns the paths written."""
    dot = find_dot()  # before any work: one line if it is missing
    out_dir = DIAGRAMS_DIR if out_dir is None else out_dir
    from olti_drake.io.outputs import make_dir, write_text

    make_dir(out_dir)
    written = []
    for name in names or SCENARIOS:
        with campaign_diagram(DIAGRAMS_DIR / SCENARIOS[name]) as diagram:
            source = graphviz_source(diagram, max_depth)
            wiring = wiring_lines(diagram)
        svg_path, wiring_path = (os.path.join(out_dir, f"{name}{ext}") for ext in (".svg", ".wiring.txt"))
        write_text(svg_path, render_svg(source, dot))
        write_text(wiring_path, f"# {name}: campaign diagram wiring of diagrams/{SCENARIOS[name]} "
                                f"(olti diagrams; src.port -> dst.port)\n" + "\n".join(wiring) + "\n")
        written += [svg_path, wiring_path]
    return written


def read_wiring(path) -> list:
    """The connection lines of a wiring file (comments dropped)."""
    with open(path, encoding="utf-8") as f:
        return [line.strip() for line in f if line.strip() and not line.startswith("#")]
