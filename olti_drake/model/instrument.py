"""The open-loop tracking interferometer: where its beam is aimed and what it reads (000 §2, §5; 001 Eq. 1).

Units: mm and degrees at the API.

* The reading -- :func:`displacement_model`, the identification model of Eq. (5)/(10) of 000:
  d = ‖p − P_j‖ − d0_j, with its analytic Jacobians; :func:`simulate_readings`, what the instrument reports
  in simulation: the beam leaves the laser head at ``origin`` along ``beam_angle``; a cat's eye returns the
  optical length of the beam up to the point nearest its centre, (P − o)·u, i.e. the true distance times
  the cosine of the aiming error ("cosine error", 000 §5); the beam is lost when it misses the centre by
  more than the acceptance (1 mm in 000 §5); noise from the budget (000 Table 2); counter resolution λ/64.
* The steering -- open-loop beam steering and the reflector search (000 Section 2). The interferometer
  sits on J4; its beam's world direction angle is θ1 + θ2 + θ4 + θ40 (actual angles), θ40 being the beam's
  offset in the J4 frame. J4 is relative to link 2, so the J4 command is the wanted world angle minus
  θ1* + θ2* and θ40. The beam passes through the J4 axis (000 Remark 2), so J4 does not move the beam's
  origin, the end effector p. The machine tool's rotary-table steering (001 Eq. 1) is here too.
"""


from dataclasses import dataclass
from typing import Callable, NamedTuple, Optional

import numpy as np
from scipy.optimize import least_squares

from olti_drake.model.budget import Budget
from olti_drake.model.scara import DEG, forward_kinematics, inverse_kinematics


@dataclass
class InterferometerOptions:
    """Switchable terms of the simulated interferometer (YAML-loadable).

    ``beam_direction_noise`` is off by default: 000 Table 2's u31/u32 are the
    beam-direction effect of the J1/J2 deviations and of the reflector estimate
    error, which the simulator already models physically; switching it on adds
    them again as random aiming noise.
    """

    wavelength_nm: float = 632.8
    resolution_divisor: float = 64.0
    acceptance_mm: float = 1.0
    noise: bool = True
    quantization: bool = True
    cosine_error: bool = True
    beam_loss: bool = True
    beam_direction_noise: bool = False

    @property
    def resolution_mm(self) -> float:
        """Counter resolution λ/divisor, mm (λ/64 ≈ 9.9 nm for HeNe)."""
        return self.wavelength_nm * 1e-6 / self.resolution_divisor

    def validate(self, where: str = "interferometer") -> "InterferometerOptions":
        for key in ("wavelength_nm", "resolution_divisor", "acceptance_mm"):
            v = getattr(self, key)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{where}.{key} must be finite and > 0, got {v!r}")
        return self


def displacement_model(p_mm, reflector_mm, dead_path_mm):
    """Predicted reading d = ‖p − P‖ − d0 and its Jacobians (Eq. (5)/(10) of 000).

    Args:
        p_mm: (N, 2) end-effector positions, mm.
        reflector_mm: (N, 2) reflector position of each reading, mm.
        dead_path_mm: (N,) dead path of each reading's reflector, mm.

    Returns:
        d (N,), dd/dp (N, 2) = u, dd/dP (N, 2) = −u, with u the unit vector
        from P to p (dd/dd0 = −1).
    """
    diff = np.asarray(p_mm, dtype=float) - np.asarray(reflector_mm, dtype=float)
    dist = np.hypot(diff[:, 0], diff[:, 1])
    if np.any(dist == 0):
        raise ValueError(f"end effector coincides with its reflector at reading {np.flatnonzero(dist == 0)[0]}")
    u = diff / dist[:, None]
    return dist - np.asarray(dead_path_mm, dtype=float), u, -u


def beam_geometry(origin_mm, beam_angle_deg, reflector_mm):
    """Optical length to the cat's eye and the beam's miss of its centre, mm.

    Returns (along, miss): along = (P − o)·u (the length the interferometer
    sees, the cosine error included), miss = |(P − o) × u| (lateral distance of
    the reflector centre from the beam line), for u = (cos a, sin a).
    """
    rel = np.asarray(reflector_mm, dtype=float) - np.asarray(origin_mm, dtype=float)
    a = np.radians(beam_angle_deg)
    c, s = np.cos(a), np.sin(a)
    return rel[..., 0] * c + rel[..., 1] * s, np.abs(rel[..., 1] * c - rel[..., 0] * s)


def quantize(x_mm, step_mm):
    """Counter quantization: round to the nearest multiple of ``step_mm``."""
    return np.round(np.asarray(x_mm) / step_mm) * step_mm


def simulate_readings(origin_mm, beam_angle_deg, reflector_mm, dead_path_mm,
                      options: InterferometerOptions, budget: Budget, rng: np.random.Generator):
    """Simulated readings of an open-loop steered interferometer (000 §2, §5).

    Args:
        origin_mm: (N, 2) actual laser head positions (beam origin), mm.
        beam_angle_deg: (N,) actual world beam direction, deg.
        reflector_mm: (N, 2) true reflector centres, mm.
        dead_path_mm: (N,) counter zero of each reading's reflector, mm.
        options: which terms are on, resolution, acceptance.
        budget: standard deviations of the white-noise terms (``pose``,
            ``reading``, ``beam_direction`` contributors, root-sum-squared).
        rng: random generator; four normals are drawn per reading whatever the
            switches, so switching one term does not change the others.

    Returns:
        (reading_mm (N,), valid (N,) bool, miss_mm (N,)).
    """
    origin = np.atleast_2d(np.asarray(origin_mm, dtype=float))
    angle = np.atleast_1d(np.asarray(beam_angle_deg, dtype=float))
    z = rng.standard_normal((len(origin), 4))
    if options.noise:
        origin = origin + budget.combined("pose") * z[:, :2]
        if options.beam_direction_noise:
            angle = angle + np.degrees(budget.combined("beam_direction")) * z[:, 2]
    along, miss = beam_geometry(origin, angle, reflector_mm)
    length = along if options.cosine_error else np.hypot(along, miss)
    reading = length - np.asarray(dead_path_mm, dtype=float)
    if options.noise:
        reading = reading + budget.combined("reading") * z[:, 3]
    if options.quantization:
        reading = quantize(reading, options.resolution_mm)
    valid = ~(options.beam_loss & (miss > options.acceptance_mm))
    return reading, valid, miss


# ------------------------------------------------------------- open-loop beam steering (000 Section 2)
#: Beam origin and reflector closer than this (mm) have no beam direction.
COINCIDENT_TOL_MM = 1e-9


def wrap_deg(angle_deg):
    """Angle(s) in deg wrapped to (-180, 180] deg (beam angles of Eq. (1)/(2) of 000)."""
    return -((180.0 - np.asarray(angle_deg, dtype=float)) % 360.0 - 180.0)


def _xy(a, name: str) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.shape[-1:] != (2,) or a.ndim > 2:
        raise ValueError(f"{name} must have shape (2,) or (N, 2), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains a non-finite value")
    return a


def _bearing_deg(p_mm, reflector_mm, name: str):
    """World angle (deg) of the line p -> P (Eq. 1 of 000) and the offset P - p (mm)."""
    d = reflector_mm - p_mm
    rho = np.hypot(d[..., 0], d[..., 1])
    if np.any(rho < COINCIDENT_TOL_MM):
        k = int(np.flatnonzero(np.ravel(rho < COINCIDENT_TOL_MM))[0])
        raise ValueError(f"{name}: row {k} coincides with the beam origin (end-effector position)")
    return np.arctan2(d[..., 1], d[..., 0]) / DEG, d


def beam_command_deg(theta1_cmd_deg, theta2_cmd_deg, reflector_est_mm, L1_mm, L2_mm,
                     theta40_deg=0.0):
    """J4 joint command θ4* (deg, wrapped to (-180, 180]) aiming the beam at P (Eq. (1) of 000).

    p* = forward kinematics of the *commanded* θ1*, θ2* (deg) with the *nominal*
    link lengths L1, L2 (mm); Eq. (1) of 000 gives the world beam angle
    atan2(P_y - p*_y, P_x - p*_x); the command is that angle minus θ1* + θ2*
    (J4 is relative to link 2) minus the beam offset ``theta40_deg`` (deg).

    Args:
        theta1_cmd_deg, theta2_cmd_deg: scalar or (N,) commands, deg.
        reflector_est_mm: (2,) or (N, 2) reflector estimate(s) P, mm (one per row).
        L1_mm, L2_mm: nominal link lengths, mm.
        theta40_deg: beam offset in the J4 frame, deg.

    Returns:
        θ4* in deg, broadcast shape of the inputs (scalar for scalar inputs).
    """
    t1 = np.asarray(theta1_cmd_deg, dtype=float)
    t2 = np.asarray(theta2_cmd_deg, dtype=float)
    P = _xy(reflector_est_mm, "reflector_est_mm")
    p_cmd, _ = forward_kinematics(t1, t2, L1_mm, L2_mm)
    world, _ = _bearing_deg(p_cmd, P, "reflector_est_mm")
    return wrap_deg(world - t1 - t2 - theta40_deg)[()]


# --------------------------------------------------------------------------
# Reflector search, Eq. (2) of 000 (Remark 1)
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class SearchResult:
    """Solution of Eq. (2) of 000: reflectors (Nt, 2) mm, θ40 deg, rms residual mdeg."""

    reflectors_mm: np.ndarray
    theta40_deg: float
    residual_rms_mdeg: float
    iterations: int


class SearchData(NamedTuple):
    """Search records ready for :func:`fit_reflectors` (deg, deg, deg, index)."""

    theta1_cmd_deg: np.ndarray
    theta2_cmd_deg: np.ndarray
    theta4_found_deg: np.ndarray
    reflector_index: np.ndarray


def search_residuals(params, theta1_cmd_deg, theta2_cmd_deg, theta4_found_deg,
                     reflector_index, L1_mm, L2_mm):
    """Residuals of Eq. (2) of 000 and their analytic Jacobian.

    params = [P_0x, P_0y, P_1x, P_1y, ..., θ40] (mm..., deg). For search k aimed
    at reflector j = reflector_index[k]:

        r_k = wrap(θ1*(k) + θ2*(k) + θ4(k) + θ40 - φ_k),  φ_k = atan2(P_jy - p*_y(k), P_jx - p*_x(k))

    in deg, with p*(k) the nominal forward kinematics of the commands. With
    d = P_j - p*(k), ρ² = |d|²:  ∂r/∂P_jx = +d_y/ρ² /DEG,  ∂r/∂P_jy = -d_x/ρ² /DEG
    (deg/mm), ∂r/∂θ40 = 1.

    Returns:
        r: (K,) deg; J: (K, 2 Nt + 1) in deg/mm and deg/deg.
    """
    x = np.asarray(params, dtype=float)
    j = np.asarray(reflector_index, dtype=int)
    t1 = np.asarray(theta1_cmd_deg, dtype=float)
    t2 = np.asarray(theta2_cmd_deg, dtype=float)
    p_cmd, _ = forward_kinematics(t1, t2, L1_mm, L2_mm)
    P = x[:-1].reshape(-1, 2)
    phi, d = _bearing_deg(p_cmd, P[j], "reflectors")
    r = wrap_deg(t1 + t2 + np.asarray(theta4_found_deg, dtype=float) + x[-1] - phi)
    rho2 = np.sum(d**2, axis=1)
    rows = np.arange(j.size)
    J = np.zeros((j.size, x.size))
    J[rows, 2 * j] = d[:, 1] / rho2 / DEG
    J[rows, 2 * j + 1] = -d[:, 0] / rho2 / DEG
    J[:, -1] = 1.0
    return r, J


def _ray_intersections(p_cmd, ray_deg, j, n_t):
    """Least-squares intersection of each reflector's search lines (θ40 = 0), mm."""
    n = np.stack([-np.sin(ray_deg * DEG), np.cos(ray_deg * DEG)], axis=1)  # line normals
    out = np.empty((n_t, 2))
    for r in range(n_t):
        nk, pk = n[j == r], p_cmd[j == r]
        A = nk.T @ nk
        b = nk.T @ np.sum(nk * pk, axis=1)
        w = np.linalg.eigvalsh(A)
        if w[0] <= 1e-10 * w[1]:
            raise ValueError(f"reflector_index: the search rays of reflector {r} are all "
                             f"parallel; search it from other positions")
        out[r] = np.linalg.solve(A, b)
    return out


def fit_reflectors(theta1_cmd_deg, theta2_cmd_deg, theta4_found_deg, reflector_index,
                   L1_mm, L2_mm) -> SearchResult:
    """Reflector positions P_j (mm) and beam offset θ40 (deg) from J4 searches (Eq. (2) of 000).

    Solves min Σ_k r_k² over all P_j and one shared θ40, r_k as in
    :func:`search_residuals`, by Levenberg-Marquardt with the analytic
    Jacobian. Eq. (2) as printed has atan((P_x - p_x)/(P_y - p_y)) and
    θ4 = atan - θ40; we follow the geometry of Eq. (1) instead (atan2 of
    (P_y - p_y, P_x - p_x)) and the full beam angle θ1* + θ2* + θ4 + θ40, since
    J4 is relative to link 2.

    Start (no user input): with θ40 = 0 each search is a line through p*(k)
    with direction θ1* + θ2* + θ4(k); each P_j starts at the least-squares
    intersection of its lines (a 2×2 linear problem).

    Identifiability: every reflector needs ≥ 2 search poses with non-parallel
    rays, and the number of poses must exceed the 2 Nt + 1 unknowns.

    Args:
        theta1_cmd_deg, theta2_cmd_deg: (K,) commanded J1, J2 at the searches, deg.
        theta4_found_deg: (K,) J4 angle found by the search, deg.
        reflector_index: (K,) reflector j = 0 .. Nt-1 of each search.
        L1_mm, L2_mm: nominal link lengths, mm.
    """
    t1, t2, t4 = (np.asarray(a, dtype=float).ravel()
                  for a in (theta1_cmd_deg, theta2_cmd_deg, theta4_found_deg))
    j_raw = np.asarray(reflector_index).ravel()
    if not (t1.size == t2.size == t4.size == j_raw.size) or t1.size == 0:
        raise ValueError("theta1_cmd_deg, theta2_cmd_deg, theta4_found_deg and reflector_index "
                         "must be non-empty and of equal length")
    if not np.all(np.isfinite(np.concatenate([t1, t2, t4]))):
        raise ValueError("theta1_cmd_deg/theta2_cmd_deg/theta4_found_deg contain a non-finite value")
    j = j_raw.astype(int)
    if np.any(j != j_raw) or np.any(j < 0):
        raise ValueError("reflector_index must hold non-negative integers")
    n_t = int(j.max()) + 1
    counts = np.bincount(j, minlength=n_t)
    if np.any(counts < 2):
        r = int(np.flatnonzero(counts < 2)[0])
        raise ValueError(f"reflector_index: reflector {r} has {counts[r]} search pose(s); "
                         f"it needs at least 2")
    if j.size <= 2 * n_t + 1:
        raise ValueError(f"reflector_index: {j.size} search poses for {n_t} reflectors; "
                         f"need more than 2*Nt+1 = {2 * n_t + 1}")
    p_cmd, _ = forward_kinematics(t1, t2, L1_mm, L2_mm)
    x0 = np.append(_ray_intersections(p_cmd, t1 + t2 + t4, j, n_t).ravel(), 0.0)
    args = (t1, t2, t4, j, L1_mm, L2_mm)
    sol = least_squares(lambda x: search_residuals(x, *args)[0], x0,
                        jac=lambda x: search_residuals(x, *args)[1],
                        method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, x_scale="jac")
    r, J = search_residuals(sol.x, *args)
    if np.linalg.matrix_rank(J) < J.shape[1]:
        raise ValueError("reflector_index: reflectors and theta40 are not identifiable from "
                         "these search poses (rank-deficient Eq. (2))")
    return SearchResult(reflectors_mm=sol.x[:-1].reshape(n_t, 2),
                        theta40_deg=float(sol.x[-1]),
                        residual_rms_mdeg=float(np.sqrt(np.mean(r**2)) * 1e3),
                        iterations=int(sol.nfev))


def rigid_robot_pose(L1_mm, L2_mm, theta40_deg=0.0, joint_offsets_deg=(0.0, 0.0, 0.0)):
    """An ``actual_pose`` callback for :func:`simulate_search`: constant joint offsets.

    Actual θ_n = θ_n* + offset_n (deg, n = 1, 2, 4); p = Eq. (3) of 000 with
    L1, L2 (mm); beam world angle = θ1 + θ2 + θ4 + θ40 (deg, Eq. (1) geometry).
    """
    o1, o2, o4 = (float(v) for v in joint_offsets_deg)

    def actual_pose(t1_cmd, t2_cmd, t4_cmd):
        t1 = np.asarray(t1_cmd, dtype=float) + o1
        t2 = np.asarray(t2_cmd, dtype=float) + o2
        p, _ = forward_kinematics(t1, t2, L1_mm, L2_mm)
        return p, t1 + t2 + np.asarray(t4_cmd, dtype=float) + o4 + theta40_deg

    return actual_pose


def simulate_search(search_xy_mm, reflectors_true_mm, actual_pose: Optional[Callable],
                    theta40_true_deg, rng, angle_noise_mdeg=None, *, L1_mm, L2_mm,
                    elbow: int = 1, iterations: int = 10) -> SearchData:
    """Simulated manual J4 search of Remark 1 of 000, input for Eq. (2) of 000.

    Each search position (command XY, mm) becomes commands θ1*, θ2* (deg) by
    ``inverse_kinematics`` with the nominal L1, L2 (mm). For every position and
    reflector j, J4 is turned until the true beam hits the true P_j:
    ``actual_pose(θ1*, θ2*, θ4*) -> (p_actual (N, 2) mm, beam_world_angle (N,) deg)``
    describes the true robot *including θ40* and all joint deviations; the
    J4 angle starts at the nominal Eq. (1) answer (θ40 = 0) and is iterated
    θ4 += wrap(atan2(P - p_actual) - beam_world_angle), which converges even
    when the J4 deviation depends on θ4.

    ``actual_pose=None`` means a perfect robot (nominal L1, L2) whose beam offset
    is ``theta40_true_deg``; with a callback, θ40 is the callback's business and
    ``theta40_true_deg`` must be None or 0.

    Operator imprecision: Gaussian noise on θ4 drawn from ``rng`` (Generator or
    seed), std ``angle_noise_mdeg`` (mdeg). Default (None): per search, the angle
    that moves the beam spot by 0.1 mm at the reflector distance ρ, i.e.
    0.1/ρ rad — the beam is found to within about a tenth of a millimetre.

    Returns:
        :class:`SearchData` (θ1*, θ2*, θ4 found in deg, reflector index), rows
        ordered position-major (all reflectors at position 0, then 1, ...).
    """
    xy = _xy(search_xy_mm, "search_xy_mm").reshape(-1, 2)
    P = _xy(reflectors_true_mm, "reflectors_true_mm").reshape(-1, 2)
    rng = np.random.default_rng(rng)
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    if actual_pose is None:
        actual_pose = rigid_robot_pose(L1_mm, L2_mm, 0.0 if theta40_true_deg is None
                                       else theta40_true_deg)
    elif theta40_true_deg is not None and theta40_true_deg != 0:
        raise ValueError("theta40_true_deg: give it only with actual_pose=None "
                         "(a callback's beam angle already includes theta40)")
    t1, t2 = inverse_kinematics(xy[:, 0], xy[:, 1], L1_mm, L2_mm, elbow=elbow)
    n_t = P.shape[0]
    t1, t2 = np.repeat(t1, n_t), np.repeat(t2, n_t)
    j = np.tile(np.arange(n_t), xy.shape[0])
    t4 = beam_command_deg(t1, t2, P[j], L1_mm, L2_mm)
    for _ in range(iterations):
        p_act, beam = actual_pose(t1, t2, t4)
        wanted, d = _bearing_deg(np.asarray(p_act, dtype=float), P[j], "reflectors_true_mm")
        step = wrap_deg(wanted - np.asarray(beam, dtype=float))
        t4 = t4 + step
        if np.max(np.abs(step)) < 1e-12:
            break
    if angle_noise_mdeg is None:
        sigma_deg = 0.1 / np.hypot(d[:, 0], d[:, 1]) / DEG
    else:
        if not angle_noise_mdeg >= 0:
            raise ValueError(f"angle_noise_mdeg must be >= 0, got {angle_noise_mdeg}")
        sigma_deg = np.full(j.size, angle_noise_mdeg * 1e-3)
    t4 = wrap_deg(t4 + sigma_deg * rng.standard_normal(j.size))
    return SearchData(t1, t2, t4, j)


def default_search_positions_mm(L1_mm, L2_mm) -> np.ndarray:
    """Nine search positions (9, 2) mm spread over the workspace (Remark 1 of 000).

    A 3×3 grid in joint space, θ1 ∈ {-120, -40, 40} deg, θ2 ∈ {30, 80, 130} deg
    (inside θ1 ∈ [-140, 60], θ2 ∈ [0, 140]), mapped by Eq. (3) of 000 with
    L1, L2 (mm). θ2 > 0, so ``inverse_kinematics(..., elbow=1)`` returns them.
    """
    t1, t2 = np.meshgrid([-120.0, -40.0, 40.0], [30.0, 80.0, 130.0], indexing="ij")
    return forward_kinematics(t1.ravel(), t2.ravel(), L1_mm, L2_mm)[0]
