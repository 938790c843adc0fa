"""``olti tracker-emulator``: the emScon laser-tracker emulator as a program (docs/tracker.md).

Parses nothing itself (verbs.py does), starts :class:`olti_drake.hardware.tracker_emulator.TrackerEmulator`
on 127.0.0.1 -- a reflector at rest (``--reflector-mm``) or carried by the simulated robot of a six-axis
scenario whose station is a ``!Tracker`` (``--scenario``: the N-joint robot emulator is started too, its
controller on a pseudo-terminal) -- prints where they listen and serves until Ctrl-C or SIGTERM.
"""

import signal
import sys
import threading


def tracker_emulator(args) -> int:
    if (args.reflector_mm is None) == (args.scenario is None):
        raise ValueError("olti tracker-emulator: give --reflector-mm x,y,z (a reflector at rest) or --scenario "
                         "SCENARIO.yaml (a robot carrying it), one of them")
    stoppers, lines = [], []
    if args.scenario is not None:
        robot, tracker = _scenario_emulators(args)
        robot.start()
        stoppers.append(robot.stop)
        lines.append(f"robot   {robot.robot_port}")
    else:
        from olti_drake.hardware.tracker_emulator import TrackerEmulator

        tracker = TrackerEmulator(args.reflector_mm[0], seed=args.seed or 0, port=args.port)
    try:
        tracker.start()
    except OSError as e:
        for stop in stoppers:
            stop()
        raise ValueError(f"olti tracker-emulator: cannot listen on 127.0.0.1:{args.port}: {e.strerror or e}") from None
    stoppers.append(tracker.stop)
    done = threading.Event()
    old = {s: signal.signal(s, lambda *_: done.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        for line in lines + [f"tracker 127.0.0.1:{tracker.port}  (emScon; seed {tracker.seed}; Ctrl-C stops)"]:
            print(line, flush=True)
        while not done.wait(0.2):
            pass
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        for stop in reversed(stoppers):
            stop()
    print(f"served {tracker.measurements} measurements ({tracker.refused} refused, {tracker.bad_packets} bad "
          f"packets)", file=sys.stderr)
    return 0


def _scenario_emulators(args):
    """The robot and tracker emulators of a six-axis ``!Tracker`` scenario (one-line errors otherwise)."""
    from olti_drake.hardware.runner import load_run_scenario
    from olti_drake.hardware.tracker_station import prepare_tracker, tracker_emulators_for
    from olti_drake.sim.serial_scenario import Tracker

    scenario = load_run_scenario(args.scenario)
    if not isinstance(getattr(scenario, "station", None), Tracker):
        raise ValueError(f"scenario {args.scenario}: olti tracker-emulator takes a six-axis scenario whose station "
                         f"is !Tracker (docs/tracker.md)")
    if args.seed is not None:
        scenario.seed = args.seed
    return tracker_emulators_for(prepare_tracker(scenario), port=args.port)
