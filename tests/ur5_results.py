"""A UR5 tracker campaign identified as ``dh`` and ``errormap`` and compensated with one export option: the
fixture of the tests of the files robots load (tests/io: the UR kinematics YAML, the D-H table). Units: mm, deg."""

import os

import numpy as np

from olti_drake.io.resources import PACKAGE_DIR
from olti_drake.io.serial_io import write_serial_campaign
from olti_drake.model.chain import load_serial_chain
from olti_drake.model.serial import synthetic_campaign, synthetic_truth

UR5 = os.path.join(PACKAGE_DIR, "models", "ur5.urdf")


def identified_ur5(d, seed: int, n_points: int, target_seed: int, n_targets: int, export: str, suffix: str):
    """``d``/points.csv: ``n_points`` tracker points of a seeded truth (tool offset 40, −25, 60 mm; 2 µm noise);
    targets.csv: ``n_targets`` true tool points with their nominal poses; for each model, ``d``/<model>.json, the
    compensated <model>.csv and ``export`` (an ``olti compensate`` option) written to <model><suffix>."""
    from olti_drake.cli.verbs import main

    chain = load_serial_chain(UR5, "tool0")
    truth = synthetic_truth(chain, seed=seed, tool_offset_mm=(40.0, -25.0, 60.0))
    camp = synthetic_campaign(truth, n_points, seed=seed, noise_mm=0.002)
    write_serial_campaign(d / "points.csv", camp.commands, camp.dirs, points_mm=camp.points_mm)
    poses = synthetic_campaign(truth, n_targets, seed=target_seed)
    cols = np.column_stack([truth.positions(poses.commands, poses.dirs), poses.commands, poses.dirs])
    header = "x_mm,y_mm,z_mm," + ",".join(f"theta{i}_deg" for i in range(1, 7)) + "," + \
        ",".join(f"dir{i}" for i in range(1, 7))
    np.savetxt(d / "targets.csv", cols, delimiter=",", header=header, comments="", fmt="%.9g")
    for model in ("dh", "errormap"):
        assert main(["identify", str(d / "points.csv"), "--robot", "ur5", "--tool-frame", "tool0", "--tool-offset-mm",
                     "40,-25,60", "--model", model, "--out", str(d / f"{model}.json")]) == 0
        assert main(["compensate", str(d / f"{model}.json"), str(d / "targets.csv"), "--out", str(d / f"{model}.csv"),
                     export, str(d / f"{model}{suffix}")]) == 0
    return d
