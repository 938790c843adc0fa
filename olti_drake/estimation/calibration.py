"""The distance measurement both papers share: start values of a station (interferometer) from known points.

Paper 000 Eq. (5)/(10) (a SCARA reflector P_j with dead path d0_j) and paper 001 Eq. (3) (a machine-tool
station P_j with dead path L0_j) read the same thing: d = ‖p − P_j‖ − d0_j, mm. :func:`station_fit` gives
(P_j, d0_j) from points p taken as known (nominal kinematics, or commands) -- the start of both programs.
"""

import numpy as np


def station_fit(points_mm, readings_mm, start_mm=None):
    """(P, L0) of one station from known points p (K, 2) and readings d = ‖p − P‖ − L0 (K,), mm.

    Without a start: the linearized multilateration ‖p‖² − 2p·P + ‖P‖² =
    (d + L0)² is linear in (P, L0, ‖P‖² − L0²); then Gauss-Newton on Eq. (3)
    of 001 (Eq. (5) of 000 for a SCARA reflector).
    """
    p, d = np.asarray(points_mm, dtype=float), np.asarray(readings_mm, dtype=float)
    if np.linalg.matrix_rank(p - p.mean(axis=0), tol=1e-9 * max(1.0, np.abs(p).max())) < 2:
        raise ValueError("the points lie on one line: distances cannot tell the two sides of it apart")
    if start_mm is None:
        A = np.column_stack([-2 * p, -2 * d, np.ones(len(d))])
        sol, *_ = np.linalg.lstsq(A, d ** 2 - np.sum(p ** 2, axis=1), rcond=None)
        P, L0 = sol[:2], sol[2]
    else:
        P = np.asarray(start_mm, dtype=float)
        L0 = np.mean(np.hypot(*(p - P).T) - d)
    for _ in range(20):
        diff = p - P
        dist = np.hypot(*diff.T)
        J = np.column_stack([-diff / dist[:, None], -np.ones(len(d))])
        step = np.linalg.lstsq(J, -(dist - L0 - d), rcond=None)[0]
        P, L0 = P + step[:2], L0 + step[2]
        if np.max(np.abs(step)) < 1e-12:
            break
    return P, L0
