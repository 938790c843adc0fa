"""Assemble and run the campaign diagram by hand (what ``olti simulate`` does).

``olti_drake.sim.campaign.build_campaign_diagram`` wires this diagram for the CLI;
here every system and connection is spelled out, as a starting point for your
own diagrams (a hardware station in place of the simulated one, other
recorders, ...)::

    python examples/simulate_paper_campaign.py [scenario.yaml] [--out DIR] [--meshcat]

Units: files are mm/deg; Drake ports are SI (rad, m).
"""

import argparse
import sys

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from olti_drake.sim.campaign import AddSimulatedStation, Campaign, prepare, write_campaign
from olti_drake.sim.scenario import load_scenario
from olti_drake.sim.systems import BeamSteering, CampaignRecorder, PlanSequencer


def build(setup, meshcat=None):
    """The campaign diagram; returns (diagram, sequencer, recorder, visualizer or None)."""
    s, r = setup.scenario, setup.scenario.robot
    builder = DiagramBuilder()
    # The station: error-mapped joints -> SCARA in SceneGraph -> interferometer.
    station = AddSimulatedStation(builder, setup)
    # Moves to the next plan row every period_s (the plan once per reflector).
    sequencer = builder.AddSystem(PlanSequencer(
        setup.plan.theta1_deg, setup.plan.theta2_deg, setup.plan.measure,
        len(setup.reflectors_mm), s.period_s))
    # Aims J4 at the *estimated* reflector with the *nominal* link lengths (open loop).
    steering = builder.AddSystem(BeamSteering(
        r.nominal_L1_mm, r.nominal_L2_mm, setup.reflectors_estimate_mm, setup.theta40_estimate_deg))
    # Reads half a period after each move, once the command has settled.
    recorder = builder.AddSystem(CampaignRecorder(s.period_s))

    # Command path: plan row (θ1*, θ2*) + reflector index -> θ4* -> robot.
    builder.Connect(sequencer.GetOutputPort("arm_command"), steering.GetInputPort("arm_command"))
    builder.Connect(sequencer.GetOutputPort("reflector"), steering.GetInputPort("reflector"))
    builder.Connect(steering.GetOutputPort("joint_command"), station.GetInputPort("joint_command"))
    # The interferometer needs to know which reflector (and counter zero) is in use.
    builder.Connect(sequencer.GetOutputPort("reflector"), station.GetInputPort("reflector"))
    # The recorder logs the command, not the actual pose: only the command is known on a real robot.
    builder.Connect(steering.GetOutputPort("joint_command"), recorder.GetInputPort("joint_command"))
    for port in ("direction", "displacement", "valid"):
        builder.Connect(station.GetOutputPort(port), recorder.GetInputPort(port))
    for port in ("reflector", "measure", "row"):
        builder.Connect(sequencer.GetOutputPort(port), recorder.GetInputPort(port))

    visualizer = None
    if meshcat is not None:
        from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams
        # One frame per plan row is enough; the default 64 Hz would draw ~76k frames.
        visualizer = MeshcatVisualizer.AddToBuilder(
            builder, station.GetOutputPort("query_object"), meshcat,
            MeshcatVisualizerParams(publish_period=s.period_s))
    return builder.Build(), sequencer, recorder, visualizer


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default=None, help="scenario YAML (default: paper 000)")
    parser.add_argument("--out", default="example_out", help="output directory (default: example_out)")
    parser.add_argument("--meshcat", action="store_true", help="record the run in Meshcat")
    args = parser.parse_args(argv)

    scenario = load_scenario(args.scenario)
    setup = prepare(scenario)  # reflector estimates (Eq. 2 search) and counter zeros
    meshcat = None
    if args.meshcat:
        from pydrake.geometry import Meshcat
        meshcat = Meshcat()  # a local web server; no browser needed
    diagram, sequencer, recorder, visualizer = build(setup, meshcat)

    if visualizer is not None:
        visualizer.StartRecording()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(sequencer.duration_s)  # every row of every run, and its reading
    campaign = Campaign.from_recorder(setup, recorder, simulator.get_context())  # readings: in the Context

    source = args.scenario or "embedded default (paper 000 experiment)"
    paths = write_campaign(campaign, args.out, comments=[
        f"examples/simulate_paper_campaign.py; scenario: {source}; seed {scenario.seed}"])
    valid = int(np.sum(campaign.columns["valid"] > 0))
    print(f"{campaign.n_readings} readings ({valid} valid) in {sequencer.duration_s:g} s simulated")
    print(f"wrote {paths[0]} and {paths[1]}")

    if visualizer is not None:
        visualizer.PublishRecording()  # replay it with the slider in the browser
        print(f"meshcat: {meshcat.web_url()}")
        if sys.stdin.isatty():
            input("press Enter to quit (the Meshcat server stops with the script) ")
    return 0


if __name__ == "__main__":
    sys.exit(main())
