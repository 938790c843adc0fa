"""``python -m olti_drake.cli.emulator``: the device emulator as a program (docs/emulator.md).

Parses the command line and starts :class:`olti_drake.hardware.emulator.Emulator` on two
pseudo-terminals until Ctrl-C. The program lives in ``cli/`` so that ``hardware/`` never imports
the command-line layer.
"""

import argparse
import logging
import signal
import sys
import time

import olti_drake.cli.args as cliargs
from olti_drake.hardware.emulator import DEFAULT_ENCODER_RESOLUTION, Emulator, Faults


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m olti_drake.cli.emulator",
        description="Emulate the robot controller and the interferometer counter of a scenario on two "
                    "pseudo-terminals (docs/emulator.md).")
    p.add_argument("scenario", nargs="?", help="scenario YAML (default: the paper-000 scenario); a 3D machine-tool "
                                               "scenario (heads_mm) emulates its X, Y, Z controller and pan/tilt "
                                               "heads, a five-axis one (machine_model) its controller and heads")
    p.add_argument("--robot", metavar="NAME|MODEL",
                   help="emulate an N-joint serial robot and its tracer heads instead of the SCARA: a robot name "
                        "(ur5) or a URDF/SDFormat file (with --tool-frame); protocol version 2")
    p.add_argument("--tool-frame", help="--robot MODEL: the tool frame of the model file")
    p.add_argument("--truth-seed", type=cliargs.seed, default=0,
                   help="--robot: seed of the synthetic robot and head errors (default 0)")
    p.add_argument("--speed", choices=("fast", "realistic"), default="fast",
                   help="fast: moves complete at once; realistic: distance/speed + settle time")
    p.add_argument("--seed", type=cliargs.seed, default=None, help="noise and fault seed (default: the scenario's)")
    p.add_argument("--link", metavar="PREFIX", help="make symlinks PREFIX-robot and PREFIX-counter")
    p.add_argument("--reflector", type=int, default=0, help="reflector position set up at start (0-based)")
    g = p.add_argument_group("faults (probabilities per frame, 0..1)")
    g.add_argument("--latency", type=float, default=0.0, metavar="S", help="delay before every reply, s")
    g.add_argument("--drop", type=float, default=0.0, metavar="P", help="lose a request or a reply")
    g.add_argument("--garble", type=float, default=0.0, metavar="P", help="change one byte of a reply")
    g.add_argument("--nak-crc", type=float, default=0.0, metavar="P",
                   help="take a request as corrupted: NAK,CRC, not executed")
    g.add_argument("--bad-crc", type=float, default=0.0, metavar="P", help="send a reply with a wrong checksum")
    g.add_argument("--partial", type=float, default=0.0, metavar="P", help="write only half of a reply")
    g.add_argument("--partial-delay", type=float, default=None, metavar="S",
                   help="send the rest of a cut reply after S seconds (default: never)")
    g.add_argument("--beam-loss", type=float, default=0.0, metavar="P", help="a READ reports no beam")
    g.add_argument("--alarm-at", type=int, default=None, metavar="N", help="the N-th MOVJ raises an alarm")
    g.add_argument("--disconnect-after", type=int, default=None, metavar="N",
                   help="close both lines after N requests")
    p.add_argument("--latch-beam-loss", action="store_true",
                   help="after a READ without beam, every READ is invalid until ZERO (a real counter)")
    p.add_argument("--exact-encoder", action="store_true", help="POSJ encoder = commanded (no quantization)")
    p.add_argument("-v", "--verbose", action="count", default=0, help="log faults (-v) and every frame (-vv)")
    a = p.parse_args(argv)
    logging.basicConfig(level=(logging.WARNING, logging.INFO, logging.DEBUG)[min(a.verbose, 2)],
                        format="%(asctime)s %(threadName)s %(message)s", stream=sys.stderr)
    faults = Faults(latency_s=a.latency, drop=a.drop, garble=a.garble, nak_crc=a.nak_crc, bad_crc=a.bad_crc,
                    partial=a.partial, partial_delay_s=a.partial_delay, beam_loss=a.beam_loss,
                    alarm_at=a.alarm_at, disconnect_after=a.disconnect_after)
    signals = []  # Ctrl-C or kill PID: stop cleanly (close the lines, remove the links), exit 0
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, frame: signals.append(signum))
    try:
        emu = _emulator(a, faults)
        emu.start()
    except (ValueError, OSError) as e:  # InputError is a ValueError
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:
        for role, line in emu._lines.items():
            print(f"{role:8s}{line.path}" + (f"  ({line.link})" if line.link else ""), flush=True)
        where = f"truth seed {emu.truth_seed}" if hasattr(emu, "truth_seed") else f"reflector {emu.reflector}"
        print(f"speed {emu.speed}, seed {emu.seed}, {where}; Ctrl-C stops", flush=True)
        while not signals and not emu.disconnected.is_set():
            time.sleep(0.1)
        if emu.disconnected.is_set():
            print(f"disconnected after {emu.requests} requests (--disconnect-after)", flush=True)
    finally:
        emu.stop()
    return 0


def _emulator(a, faults):
    """The SCARA emulator of a scenario, or with ``--robot`` the N-joint one (ValueError: one line)."""
    common = dict(speed=a.speed, faults=faults, link=a.link, latch_beam_loss=a.latch_beam_loss)
    if a.robot is None and a.scenario is not None:
        from olti_drake.sim.serial_scenario import scenario_kind

        machine = {"machine3d": _machine3d_emulator, "machine5": _machine5_emulator}.get(scenario_kind(a.scenario))
        if machine is not None:  # (a machine tool: its axes' controller and a head per station)
            return machine(a, common)
    if a.robot is None:
        if a.tool_frame is not None:
            raise ValueError("--tool-frame needs --robot")
        return Emulator(a.scenario, seed=a.seed, reflector=a.reflector,
                        encoder_resolution=(0, 0, 0, 0) if a.exact_encoder else DEFAULT_ENCODER_RESOLUTION, **common)
    from olti_drake.hardware.serial_emulator import DEFAULT_JOINT_RESOLUTION, SerialEmulator

    if a.scenario is not None or a.reflector:
        raise ValueError("--robot: a SCARA scenario and --reflector do not apply (the truth is the model file's "
                         "synthetic robot, --truth-seed)")
    return SerialEmulator(a.robot, tool_frame=a.tool_frame, truth_seed=a.truth_seed, seed=a.seed or 0,
                          encoder_resolution=0.0 if a.exact_encoder else DEFAULT_JOINT_RESOLUTION, **common)


def _machine3d_emulator(a, common):
    """The 3D machine emulator of a 3D machine-tool scenario (``heads_mm``): its X, Y, Z controller and a
    pan/tilt head line per head, the truth the scenario's (as ``olti run`` with ``!Emulated`` starts it)."""
    from olti_drake.hardware.machine3d_emulator import DEFAULT_AXIS_RESOLUTION_MM, Machine3DEmulator
    from olti_drake.sim.machine3d_campaign import prepare_machine3d_campaign
    from olti_drake.sim.machine3d_station import load_machine3d_scenario

    if a.tool_frame is not None or a.reflector:
        raise ValueError(f"{a.scenario}: a 3D machine-tool scenario: --tool-frame and --reflector do not apply "
                         f"(the heads are the counters)")
    doc = load_machine3d_scenario(a.scenario)
    setup = prepare_machine3d_campaign(doc, f"scenario {a.scenario}")
    return Machine3DEmulator(setup.machine.scenario, run=setup.run, budget=setup.machine.budget,
                             seed=doc.seed if a.seed is None else a.seed,
                             encoder_resolution=0.0 if a.exact_encoder else DEFAULT_AXIS_RESOLUTION_MM, **common)


def _machine5_emulator(a, common):
    """The five-axis emulator of a five-axis scenario (``machine_model``): its controller (the model file's axes)
    and a pan/tilt head line per station, the truth the scenario's (as ``olti run`` with ``!Emulated`` starts
    it; the R-test nests, which the protocol cannot read, are ignored)."""
    from olti_drake.hardware.machine5_emulator import Machine5Emulator
    from olti_drake.sim.five_axis_station import load_five_axis_scenario, prepare_five_axis

    if a.tool_frame is not None or a.reflector:
        raise ValueError(f"{a.scenario}: a five-axis scenario: --tool-frame and --reflector do not apply (the heads "
                         f"are the counters)")
    doc = load_five_axis_scenario(a.scenario)
    if not (doc.tracking.bed_heads_mm or doc.tracking.table_heads_mm):
        raise ValueError(f"{a.scenario}: no pan/tilt heads (tracking.bed_heads_mm, tracking.table_heads_mm) to "
                         f"emulate; R-test nests are not on the line protocol (docs/protocol.md)")
    run = prepare_five_axis(doc, f"scenario {a.scenario}")
    return Machine5Emulator(run, seed=doc.seed if a.seed is None else a.seed,
                            encoder_resolution=0.0 if a.exact_encoder else None, **common)


if __name__ == "__main__":
    sys.exit(main())
