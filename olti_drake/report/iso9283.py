"""Pose accuracy and pose repeatability of a robot in the manner of ISO 9283 (issue 26, item 4).

ISO 9283:1998 ("Manipulating industrial robots -- Performance criteria and related test methods") measures a
robot at the poses P1 … P5 of a test cube (clause 6.2) visited in ``n`` cycles (30 in the standard), each pose
approached in the order P1 → P5 → P4 → P3 → P2 → P1, and states per pose (clause 7.2):

========  ==================================================  ==================================================
symbol    ISO 9283 term                                        computed here (mm, deg)
========  ==================================================  ==================================================
AP_P      position accuracy (7.2.1)                            sqrt((x̄ − x_c)² + (ȳ − y_c)² + (z̄ − z_c)²)
AP_x, …   its components                                       x̄ − x_c, ȳ − y_c, z̄ − z_c
AP_a, …   orientation accuracy (7.2.1)                         ā − a_c, b̄ − b_c, c̄ − c_c
RP_l      position repeatability (7.2.2)                       l̄ + 3 S_l, l_j = ‖P_j − P̄‖, S_l with n − 1
RP_a, …   orientation repeatability (7.2.2)                    ±3 S_a (and b, c), S with n − 1
========  ==================================================  ==================================================

x_c … c_c is the commanded pose (what the controller was told: the nominal kinematics of the joint commands, or
the program's Cartesian targets); x_j … c_j the attained pose of cycle j (a laser tracker's point, in the
robot's base frame -- the frame fitted by the identification); the bar the mean over the cycles. Orientation
angles a, b, c about x, y, z (deg); their means and spreads are taken on the differences to the command,
wrapped to (−180, 180], so that a pose at ±180° is not averaged to 0.

The test cube (6.2): the cube of side L inside the working space; the measuring plane is the diagonal plane
through two opposite edges (here: the bottom edge along x at (y, z) = (−L/2, −L/2) and the top edge at
(+L/2, +L/2), the standard's C1–C2–C7–C8); P1 is the cube's centre and P2 … P5 lie on the plane's diagonals at
10 % of the diagonal's length from its corners (:func:`iso_cube_poses`).

Verdicts: each characteristic against a tolerance the user states (:func:`verdicts`): pass when its value
(AP_P, RP_l; the largest |AP_a|, RP_a over a, b, c) is at most the tolerance. Units: mm and degrees.
"""

from dataclasses import dataclass
from typing import Dict, Optional, Sequence

import numpy as np

from olti_drake.errors import InputError

#: The order in which a cycle visits the test cube's poses (ISO 9283 clause 7.2.1).
CYCLE_ORDER = (1, 5, 4, 3, 2)
#: Cycles the standard asks for (clause 7.2.1); fewer are stated in the result as below it.
STANDARD_CYCLES = 30
#: The characteristics a tolerance may be given for, with their unit.
CHARACTERISTICS = {"AP_P": "mm", "RP_l": "mm", "AP_abc": "deg", "RP_abc": "deg"}


def iso_cube_poses(centre_mm, side_mm: float) -> np.ndarray:
    """P1 … P5 (5, 3) mm of the ISO 9283 test cube of side ``side_mm`` centred at ``centre_mm`` (module doc:
    the diagonal plane C1–C2–C7–C8; P2 … P5 at 10 % of the plane's diagonal from its corners C1, C2, C7, C8)."""
    c = np.asarray(centre_mm, float)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise InputError(f"test cube: centre_mm must be 3 finite numbers (mm), got {centre_mm!r}")
    if not (np.isfinite(side_mm) and side_mm > 0):
        raise InputError(f"test cube: side_mm must be > 0 (mm), got {side_mm!r}")
    h = 0.5 * float(side_mm)
    corners = np.array([[-h, -h, -h], [h, -h, -h], [h, h, h], [-h, h, h]])  # C1, C2, C7, C8
    # Each Pk sits on the diagonal from its corner to the opposite corner, a tenth of the way along.
    opposite = corners[[2, 3, 0, 1]]
    return c + np.vstack([np.zeros(3), corners + 0.1 * (opposite - corners)])


@dataclass
class PoseCharacteristics:
    """The ISO 9283 characteristics of one pose (mm, deg): ``AP_P`` and ``AP_xyz`` (3,), ``RP_l``; with
    orientation ``AP_abc`` (3,) and ``RP_abc`` (3,), else None; ``cycles`` n."""

    pose: int
    cycles: int
    AP_P: float
    AP_xyz: np.ndarray
    RP_l: float
    AP_abc: Optional[np.ndarray] = None
    RP_abc: Optional[np.ndarray] = None

    def to_dict(self) -> dict:
        out = {"pose": self.pose, "cycles": self.cycles, "AP_P_mm": self.AP_P,
               "AP_xyz_mm": self.AP_xyz.tolist(), "RP_l_mm": self.RP_l}
        if self.AP_abc is not None:
            out.update(AP_abc_deg=self.AP_abc.tolist(), RP_abc_deg=self.RP_abc.tolist())
        return out


def _wrap_deg(a) -> np.ndarray:
    return (np.asarray(a, float) + 180.0) % 360.0 - 180.0


def pose_characteristics(pose, commanded, attained, line=None, source: str = "validation campaign"):
    """Per pose label (ascending) its :class:`PoseCharacteristics` (ISO 9283 clause 7.2, module doc).

    ``pose`` (n,) the pose label of every reading; ``commanded`` and ``attained`` (n, 3) mm, or (n, 6) with the
    orientation angles a, b, c (deg) after the position; ``line`` (n,) the file lines (for messages). Each pose
    needs at least 2 cycles (a repeatability from one is none); the commanded pose must be the same in every
    cycle of a pose (to 1 µm, 1 mdeg)."""
    pose = np.asarray(pose)
    cmd, att = np.asarray(commanded, float), np.asarray(attained, float)
    if cmd.ndim != 2 or cmd.shape[1] not in (3, 6) or att.shape != cmd.shape or len(pose) != len(cmd):
        raise InputError(f"{source}: commanded and attained poses must be (n, 3) or (n, 6) for n labelled rows, "
                         f"got {cmd.shape}, {att.shape}, {len(pose)} labels")
    lines = np.arange(len(pose)) + 2 if line is None else np.asarray(line)
    bad = ~np.all(np.isfinite(cmd) & np.isfinite(att), axis=1)
    if bad.any():
        raise InputError(f"{source}:{int(lines[np.argmax(bad)])}: a pose value is not a finite number")
    out = []
    for label in np.unique(pose):
        sel = pose == label
        n = int(sel.sum())
        if n < 2:
            raise InputError(f"{source}: pose {label}: {n} cycle(s); pose repeatability (ISO 9283 7.2.2) needs at "
                             f"least 2 (the standard: {STANDARD_CYCLES})")
        c = cmd[sel]
        spread = np.ptp(c, axis=0)
        if np.any(spread > 1e-3):  # (mm and deg alike: 1 µm, 1 mdeg)
            k = int(np.argmax(spread > 1e-3))
            raise InputError(f"{source}: pose {label}: its commanded {'xyzabc'[k]} differs between cycles by "
                             f"{spread[k]:.6g} (one pose, one command)")
        out.append(_characteristics(int(label), c[0], att[sel]))
    return out


def _characteristics(label: int, cmd, att) -> PoseCharacteristics:
    n = len(att)
    p = att[:, :3]
    mean = p.mean(axis=0)
    ap = mean - cmd[:3]
    l = np.linalg.norm(p - mean, axis=1)
    rp = float(l.mean() + 3.0 * l.std(ddof=1))
    if att.shape[1] == 3:
        return PoseCharacteristics(label, n, float(np.linalg.norm(ap)), ap, rp)
    d = _wrap_deg(att[:, 3:] - cmd[3:])  # (angles as differences to the command: no mean across ±180°)
    return PoseCharacteristics(label, n, float(np.linalg.norm(ap)), ap, rp, d.mean(axis=0), 3.0 * d.std(axis=0, ddof=1))


def verdicts(characteristics: Sequence[PoseCharacteristics], tolerances: Dict[str, float]) -> list:
    """One line per characteristic with a tolerance (``tolerances``: keys of :data:`CHARACTERISTICS`, mm or deg):
    its worst value over the poses against the tolerance, "PASS" or "FAIL"."""
    unknown = [k for k in tolerances if k not in CHARACTERISTICS]
    if unknown:
        raise InputError(f"ISO 9283 tolerance {unknown[0]!r}: one of {', '.join(CHARACTERISTICS)}")
    lines = []
    for key, tol in tolerances.items():
        if not (np.isfinite(tol) and tol > 0):
            raise InputError(f"ISO 9283 tolerance {key}: a number > 0 ({CHARACTERISTICS[key]}), got {tol!r}")
        values = [_worst(c, key) for c in characteristics]
        if any(v is None for v in values):
            lines.append(f"{key}: not available (the campaign has no orientation)")
            continue
        k = int(np.argmax(values))
        verdict = "PASS" if values[k] <= tol else "FAIL"
        lines.append(f"{key} {verdict}: worst {values[k]:.4g} {CHARACTERISTICS[key]} at P{characteristics[k].pose} "
                     f"(tolerance {tol:g} {CHARACTERISTICS[key]})")
    return lines


def _worst(c: PoseCharacteristics, key: str):
    if key == "AP_P":
        return c.AP_P
    if key == "RP_l":
        return c.RP_l
    values = c.AP_abc if key == "AP_abc" else c.RP_abc
    return None if values is None else float(np.max(np.abs(values)))
