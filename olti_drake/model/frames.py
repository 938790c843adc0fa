"""Rigid frames of the package, written once: the rotations of a tracker set-up, their Jacobians, the rigid fit.

A tracker reads a point p of the robot or machine in its own frame, m = R p + t (mm). Two angle conventions of
R are in use, each the natural one of its result document (formats.md):

* **rotation vector**, µrad in the five-axis documents (``rotation_vector_urad``): R(w) = exp([w]×). One µrad at a
  1 m lever moves a point one µm, so a frame's u in µrad is of the order of the readings' u in µm.
  :func:`rotation_matrix`, :func:`left_jacobian`, :func:`rotation_vector`.
* **fixed angles**, deg in the serial robot's documents (``tracker_frame.rotation_deg``): R = Rx(rx)·Ry(ry)·Rz(rz),
  the chain's location-error convention. :func:`xyz_rotation`, :func:`xyz_angles`, :data:`XYZ_CONVENTION`.

Either way the Jacobian of the turned point q = R p by the three angles a is ∂q/∂a = −[q]× A(a), A the world axes
each angle turns about per unit (:func:`turn_rows`): the left Jacobian of SO(3) for a rotation vector, the
fixed axes u_x, Ry-turned u_y, Rx·Ry-turned u_z for the fixed angles. The Kabsch fit (:func:`rigid_fit`) starts
every tracker frame and compares a CNC file's machine with the identified one.
"""

import numpy as np

from olti_drake.errors import InputError

DEG = np.pi / 180.0
URAD = 1e-6  # rad per µrad
#: The fixed-angle convention as result documents state it (``tracker_frame.convention``).
XYZ_CONVENTION = "tracker point = R p + t, R = Rx(rx) Ry(ry) Rz(rz)"


def skew(v) -> np.ndarray:
    """[v]× of (..., 3) vectors: (..., 3, 3)."""
    v = np.asarray(v, float)
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def _series(theta):
    """(sin θ/θ, (1 − cos θ)/θ², (θ − sin θ)/θ³), exact below θ = 1e-4 rad by their Taylor series."""
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    t2 = theta * theta
    a = np.where(small, 1 - t2 / 6, np.sin(t) / t)
    b = np.where(small, 0.5 - t2 / 24, (1 - np.cos(t)) / t ** 2)
    c = np.where(small, 1 / 6 - t2 / 120, (t - np.sin(t)) / t ** 3)
    return a, b, c


# ------------------------------------------------------------------------------------- rotation vector
def rotation_matrix(w_rad) -> np.ndarray:
    """R = exp([w]×) of rotation vectors w (..., 3) rad (Rodrigues): (..., 3, 3)."""
    w = np.asarray(w_rad, float)
    a, b, _ = _series(np.linalg.norm(w, axis=-1))
    K = skew(w)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def left_jacobian(w_rad) -> np.ndarray:
    """J_l(w) (..., 3, 3) of SO(3): exp([w + δ]×) = exp([J_l(w) δ]×) exp([w]×) to first order, so
    ∂(R(w) p)/∂w = −[R(w) p]× J_l(w)."""
    w = np.asarray(w_rad, float)
    _, b, c = _series(np.linalg.norm(w, axis=-1))
    K = skew(w)
    return np.eye(3) + b[..., None, None] * K + c[..., None, None] * (K @ K)


def rotation_vector(R) -> np.ndarray:
    """w (3,) rad with exp([w]×) = R (|w| ≤ π; the log map, robust near π)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(R, float)).as_rotvec()


# ---------------------------------------------------------------------------------------- fixed angles
def _about(axis, angle_rad: float) -> np.ndarray:
    k = skew(axis)
    return np.eye(3) + np.sin(angle_rad) * k + (1.0 - np.cos(angle_rad)) * (k @ k)


def xyz_rotation(angles_deg):
    """R = Rx·Ry·Rz of the angles (3,) deg, and the world axes (3, 3; columns u_rx, u_ry, u_rz) about which each
    angle turns R·p: ∂(R p)/∂a_k = u_k × R p per rad."""
    rx, ry, rz = (_about(e, a * DEG) for e, a in zip(np.eye(3), np.asarray(angles_deg, float)))
    return rx @ ry @ rz, np.column_stack([np.array([1.0, 0.0, 0.0]), rx[:, 1], (rx @ ry)[:, 2]])


def xyz_angles(R) -> np.ndarray:
    """The angles (3,) deg of R = Rx·Ry·Rz (ry within ±90°)."""
    R = np.asarray(R, float)
    b = np.arcsin(np.clip(R[0, 2], -1.0, 1.0))
    return np.degrees([np.arctan2(-R[1, 2], R[2, 2]), b, np.arctan2(-R[0, 1], R[0, 0])])


def into_frame(points_mm, frame) -> np.ndarray:
    """Points (M, 3) mm in a tracker frame (6: t mm, fixed angles deg): m = R p + t."""
    frame = np.asarray(frame, float).reshape(6)
    return np.atleast_2d(np.asarray(points_mm, float)) @ xyz_rotation(frame[3:])[0].T + frame[:3]


def out_of_frame(points_mm, frame) -> np.ndarray:
    """Points (M, 3) mm read in a tracker frame (6: t mm, fixed angles deg) back in the robot's: p = Rᵀ (m − t)."""
    frame = np.asarray(frame, float).reshape(6)
    return (np.atleast_2d(np.asarray(points_mm, float)) - frame[:3]) @ xyz_rotation(frame[3:])[0]


# ------------------------------------------------------------------------------------------- shared
def turn_rows(q, axes, per_unit: float) -> np.ndarray:
    """∂q/∂a (..., 3, 3) of turned points q = R p (..., 3) mm by three angles a whose unit turns about
    ``axes`` (..., 3, 3; columns) by ``per_unit`` rad: −[q]× A · per_unit (mm per angle unit)."""
    return -skew(q) @ np.asarray(axes, float) * per_unit


def rigid_fit(p_mm, q_mm):
    """(R, t) minimizing Σ‖R p_k + t − q_k‖² over rotations R (Kabsch; det R = +1), mm.

    The closed-form start of every tracker frame (q = tracker points, p = the start model's points).
    Refuses (InputError) points on one line: the rotation about it is unknown."""
    p, q = np.asarray(p_mm, float), np.asarray(q_mm, float)
    pc, qc = p.mean(axis=0), q.mean(axis=0)
    u, s, vt = np.linalg.svd((p - pc).T @ (q - qc))
    if len(p) < 3 or s[1] <= 1e-9 * max(s[0], 1e-300):
        raise InputError(f"rigid fit: the {len(p)} points lie on one line (or fewer than 3): the rotation about "
                         f"it is unknown")
    d = np.sign(np.linalg.det(vt.T @ u.T))
    R = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return R, qc - R @ pc
