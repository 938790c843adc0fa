"""The named gauges of paper 001's self-calibrating multilateration (§2.3): what distances cannot see, fixed
explicitly as linear constraints A x = b on the parameters.

Distances (001 Eq. 3) do not change when the targets and the stations move together rigidly: D translations
and D(D − 1)/2 rotations (3 in 2D; 001's six constraints in 3D). Each gauge below fixes them through the target
coordinates (the first D N_i parameters, :class:`olti_drake.model.free_points.FreePoints`), from the nominal
target positions c_i (the commands plus the tool offsets), and says so in a sentence (result.json's ``gauge``):

* ``best-fit``: Σ (p_i − c_i) = 0 (no mean translation) and Σ (c_i − c̄) × (p_i − c_i) = 0 (no mean rotation
  about the centroid; in 2D its z component): the frame best fits the commands;
* ``first-two`` (2D): target 0 at its command, target 1 on the line of the command direction from 0 to 1;
* ``first-three`` (3D): target 0 at its nominal position, target 1 on that line, and the first target off
  that line in the plane of the three nominal positions.

:func:`free_points_gauge` returns a :class:`NamedGauge`, the ``gauge`` object
:class:`olti_drake.estimation.calibration.Calibration` takes (``A``, ``b``, ``sentence``).

The volumetric machine (:class:`olti_drake.model.volumetric3d.VolumetricPositionModel`, the 21 ISO 230-1 motions)
sees the same rigid motion of the whole (machine + stations) through 001 Eq. (3); its representation fixes it, by
the named conditions of :data:`VOLUMETRIC_GAUGE_CONDITIONS` (the B-spline coefficients they fix are no unknowns):
:func:`volumetric_gauge` is that gauge, with no constraint row left. Units: mm, µrad.

The SCARA of paper 000 (:func:`scara_gauge`): its distances (Eq. 5 / 10) do not see a rotation of the arm and the
reflectors together about J1. The D-H model (Eq. 4) has no J1 offset, so there is nothing to fix; the error map
(Eq. 6-9) has one -- its J1 map's constant part -- fixed by the mean of both approach directions of the J1 map at
θ1* = 0 (or the grid's end nearest it) being zero (deg); known reflector positions (held by bounds in the program)
fix it themselves. Without a constraint to add, the gauge has no rows and says why.
"""

from dataclasses import dataclass

import numpy as np

from olti_drake.errors import InputError

#: The gauges of each dimension; ``GAUGES`` is every name.
GAUGES_BY_DIM = {2: ("best-fit", "first-two"), 3: ("best-fit", "first-three")}
GAUGES = ("best-fit", "first-two", "first-three")


@dataclass(frozen=True, eq=False)
class NamedGauge:
    """A named gauge: ``A`` (k, n) x = ``b`` (k,) mm over a problem's n parameters, ``sentence`` saying what it
    fixes, ``kind`` its name (one of :data:`GAUGES`; the SCARA's: :func:`scara_gauge`, whose b is in deg; the
    volumetric machine's ``representation``: :func:`volumetric_gauge`, no rows), ``conditions`` what it stands for."""

    kind: str
    A: np.ndarray
    b: np.ndarray
    sentence: str
    #: The named conditions the gauge stands for (a gauge fixed in a model's representation: every one).
    conditions: tuple = ()


#: The conditions that fix the volumetric machine's gauge (the frame), each by name; the B-spline coefficients
#: they fix are no unknowns (docs/machine_3d.md).
VOLUMETRIC_GAUGE_CONDITIONS = (
    "E_XX, E_YY, E_ZZ = 0 at the travel start (origin: tool 0's point at the travel start)",
    "tool 0's offset as given (the origin's translation)",
    "E_AX, E_BX, E_CX, E_AY, E_BY, E_CY, E_AZ, E_BZ, E_CZ = 0 at the travel start (orientation)",
    "E_YX, E_ZX = 0 at both ends of the X travel (x along X's reference straight line)",
    "E_XY, E_ZY, E_XZ, E_YZ = 0 at both ends of their travel (reference straight lines through the end points)",
    "no squareness of X (X defines x) and none of Y about x or y (Y's line in the xy plane: E_C0Y only)",
)
#: What the volumetric gauge fixes, in one sentence (result.json's ``gauge``).
VOLUMETRIC_GAUGE = ("the rigid motion of the whole (3 translations, 3 rotations) is fixed in the representation: "
                    "origin at tool 0's point at the travel start, x along X's reference straight line, y in the "
                    "plane of X's and Y's lines (the named conditions in gauge_conditions); the stations are "
                    "estimated in that frame")


def volumetric_gauge(n_params: int) -> NamedGauge:
    """The gauge of the volumetric machine over a problem's ``n_params`` parameters: the rigid motion of the whole
    (3 translations, 3 rotations) fixed in the representation by :data:`VOLUMETRIC_GAUGE_CONDITIONS`, so no
    constraint row is left (``A`` (0, n_params), ``b`` (0,))."""
    return NamedGauge("representation", np.zeros((0, int(n_params))), np.zeros(0), VOLUMETRIC_GAUGE,
                      VOLUMETRIC_GAUGE_CONDITIONS)


def check_gauge_kind(kind: str, dim: int) -> None:
    """Refuse (one line) a gauge name that is not one of the gauges of a ``dim``-dimensional campaign."""
    if kind not in GAUGES_BY_DIM[dim]:
        raise InputError(f"gauge must be one of {', '.join(GAUGES_BY_DIM[dim])} for a {dim}D "
                         f"campaign, got {kind!r}")


def free_points_gauge(kind: str, nominal_mm, n_params: int) -> NamedGauge:
    """The gauge ``kind`` over ``n_params`` parameters whose first D N_i are the targets p_i (D consecutive
    coordinates each), from the nominal target positions ``nominal_mm`` (N_i, D) mm: D translations and
    D(D − 1)/2 rotations fixed (001 §2.3)."""
    c = np.asarray(nominal_mm, dtype=float)
    check_gauge_kind(kind, c.shape[1])
    A, b, sentence = gauge_rows(kind, c, n_params)
    return NamedGauge(kind, A, b, sentence)


def gauge_rows(kind: str, c, n: int):
    """(A, b, sentence) of the gauge over n parameters whose first D N_i are the targets, from the nominal
    target positions c (N_i, D) mm: D translations and D(D − 1)/2 rotations fixed."""
    n_i, D = c.shape
    if kind == "best-fit":
        rel = c - c.mean(axis=0)
        # Σ (p_i − c_i) = 0 (no mean translation); Σ rel_i × (p_i − c_i) = 0 (no mean rotation about the
        # centroid): in 2D the z component only, in 3D all three.
        rot = [(0, 1)] if D == 2 else [(1, 2), (2, 0), (0, 1)]
        A = np.zeros((D + len(rot), n))
        for k in range(D):
            A[k, k:D * n_i:D] = 1.0
        for r, (a, e) in enumerate(rot):  # (rel × d)_axis = rel_a d_e − rel_e d_a
            A[D + r, a:D * n_i:D], A[D + r, e:D * n_i:D] = -rel[:, e], rel[:, a]
        b = A[:, :D * n_i] @ c.ravel()
        if D == 2:
            return A, b, ("two translations and the rotation fixed by linear constraints: the estimated targets "
                          "have no mean translation and no mean rotation (about the command centroid) from their "
                          "command positions -- the frame best fits the commands")
        return A, b, ("three translations and three rotations fixed by linear constraints: the estimated targets "
                      "have no mean translation and no mean rotation (about the centroid of their nominal "
                      "positions, the commands plus the tool offsets) from their nominal positions -- the frame "
                      "best fits the commands")
    if D == 2:
        A = np.zeros((3, n))
        e = c[1] - c[0]
        A[0, 0], A[1, 1] = 1.0, 1.0
        A[2, 2], A[2, 3] = -e[1], e[0]  # target 1 on the line through p*_0 along p*_1 − p*_0
        b = np.array([c[0, 0], c[0, 1], -e[1] * c[0, 0] + e[0] * c[0, 1]])
        return A, b, ("origin fixed at target 0's command position and the X direction along the command "
                      "direction from target 0 to target 1 (target 1 constrained to that line)")
    # The third target: the first whose command is off the line of targets 0 and 1 (a grid's first few
    # lie on one line).
    e1 = c[1] - c[0]
    normals = np.cross(e1, c - c[0])
    off = np.flatnonzero(np.linalg.norm(normals, axis=1) > 1e-6 * np.linalg.norm(e1) * np.ptp(c, axis=0).max())
    if not off.size or not np.linalg.norm(e1):
        raise InputError("gauge first-three: every target command lies on the line of targets 0 and 1; use best-fit")
    k = int(off[0])
    normal = normals[k]
    across = np.linalg.svd(e1[None])[2][1:]  # two directions across e1: target 1 stays on the line
    A = np.zeros((6, n))
    A[0:3, 0:3] = np.eye(3)
    A[3:5, 3:6] = across
    A[5, 3 * k:3 * k + 3] = normal  # target k stays in the plane of the three commands
    b = np.concatenate([c[0], across @ c[0], [normal @ c[0]]])
    return A, b, (f"origin fixed at target 0's nominal position, the X direction along the command direction "
                  f"from target 0 to target 1 (target 1 constrained to that line) and the XY plane through the "
                  f"nominal positions of targets 0, 1 and {k} (target {k} constrained to it)")


def scara_gauge(robot, n_params: int, fixed_reflectors: bool = False) -> NamedGauge:
    """The gauge of the SCARA of 000 over ``n_params`` parameters whose first are ``robot``'s
    (:meth:`olti_drake.model.scara.ScaraModel.parameter_names`: L1, L2, then θ20 or the J1 map's forward and reverse
    nodes, ...): ``kind`` ``"J1"`` -- one row, (Δθ1(a, +1) + Δθ1(a, −1))/2 = 0 deg at a = 0 deg clipped to the J1
    grid (000 Eq. 7-9 weights) -- or, with no row (nothing to add to the program), ``"none"`` (the D-H model) or
    ``"fixed reflectors"`` (an error map whose reflectors are known)."""
    none = (np.zeros((0, n_params)), np.zeros(0))
    if not robot.is_errormap:
        return NamedGauge("none", *none, "none needed: the D-H model has no J1 offset, so X lies along the arm at "
                                         "theta1* = 0 (formats.md frame)")
    if fixed_reflectors:
        return NamedGauge("fixed reflectors", *none,
                          "fixed by the known reflector positions (no free rotation about J1)")
    m = robot.map1
    at = float(np.clip(0.0, m.grid_deg[0], m.grid_deg[-1]))
    A = np.zeros((1, n_params))
    if not getattr(robot, "bidirectional", True):  # one branch: its (forward) value at a is the gauge
        A[0, 2:2 + m.n_nodes] = m.weights([at], [1.0]).toarray()[0, :m.n_nodes]
        return NamedGauge("J1", A, np.zeros(1), f"rotation about J1 fixed by the constraint dtheta1({at:g} deg) = 0: "
                                                f"X lies along the arm at theta1* = {at:g} deg (one-directional map)")
    A[0, 2:2 + 2 * m.n_nodes] = m.weights([at, at], [1.0, -1.0]).toarray().sum(axis=0) / 2
    return NamedGauge("J1", A, np.zeros(1), f"rotation about J1 fixed by the constraint (dtheta1({at:g} deg, +1) + "
                                            f"dtheta1({at:g} deg, -1))/2 = 0: X lies along the arm at theta1* = "
                                            f"{at:g} deg, mean of both approach directions")
