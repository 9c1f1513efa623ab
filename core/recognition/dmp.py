"""Dynamic Movement Primitives: the action parameterisation of the paper's Experiment 2.

A discrete DMP per joint (Ijspeert et al., 2013) with a shared canonical system, written in
normalised time ``u = t / τ`` (τ the duration of the movement):

    s(u)  = exp(-α_s u)                                      canonical phase, 1 → ~0.01
    y'(u) = z
    z'(u) = α_z (β_z (g - y) - z) + f(s),   f(s) = s · Σ_i ψ_i(s) w_i / Σ_i ψ_i(s)
    ψ_i(s) = exp(-h_i (s - c_i)²)

The forcing term is *not* scaled by (g - y0): a touch starts and ends at rest in the same pose, so
g = y0 and the classical scaling would switch the forcing term off. The weights are therefore in
joint units (degrees, for the rig).

The paper fits a teaching trajectory per joint with 25 basis functions by least squares, keeps
the 3 dominant weights per joint and lets the action x (dx = 6) offset them: w = w_teach + x.
Here each action component is scaled so that a unit of x moves the joint trajectory by a stated
amount (``offset_deg_per_unit``) at the peak of that weight's effect; the map from x to the
trajectory is affine, so a trajectory costs one (T, B) matrix product once the basis responses
are known.

Everything here is pure numerics: trajectories are arrays, times are numbers given by the caller.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import scipy.linalg

from core.errors import InvalidInputError
from core.validation import FloatArray, IntArray, as_float_array, store_read_only

_CANONICAL_END_PHASE = 0.01
"""Phase value s reaches at the end of the movement (u = 1): α_s = -ln(0.01)."""


@dataclass(frozen=True)
class DMPGains:
    """Gains of the transformation and canonical systems.

    Attributes:
        alpha_z: Spring-damper gain α_z.
        beta_z: Spring gain β_z; α_z / 4 makes the system critically damped.
        alpha_s: Canonical decay α_s; the default makes s fall to 0.01 at the end.
        width_factor: Basis widths h_i = width_factor / (c_{i+1} - c_i)², neighbouring bases
            overlap more as this gets smaller.
        substeps: Integration sub-steps per output sample (exact discretisation of the linear
            system, forcing term taken at the sub-step midpoint).
    """

    alpha_z: float = 25.0
    beta_z: float = 6.25
    alpha_s: float = float(-np.log(_CANONICAL_END_PHASE))
    width_factor: float = 1.0
    substeps: int = 8

    def __post_init__(self) -> None:
        for name in ("alpha_z", "beta_z", "alpha_s", "width_factor"):
            value = float(getattr(self, name))
            if not np.isfinite(value) or value <= 0:
                raise InvalidInputError(f"DMPGains.{name}: must be positive, received {value}.")
        if int(self.substeps) < 1:
            raise InvalidInputError(f"DMPGains.substeps: must be >= 1, received {self.substeps}.")


@dataclass(frozen=True)
class DMP:
    """A fitted DMP for J joints.

    Attributes:
        start: y0 per joint. Shape (J,).
        goal: g per joint. Shape (J,).
        weights: Forcing-term weights w. Shape (J, B).
        duration_s: τ, the duration of the teaching movement in seconds.
        dt_s: Sample period of the teaching trajectory in seconds.
        centres: Basis centres c_i in phase s. Shape (B,).
        widths: Basis widths h_i. Shape (B,).
        gains: The system gains.
    """

    start: FloatArray
    goal: FloatArray
    weights: FloatArray
    duration_s: float
    dt_s: float
    centres: FloatArray
    widths: FloatArray
    gains: DMPGains = field(default_factory=DMPGains)

    def __post_init__(self) -> None:
        start = as_float_array(self.start, "start", (None,))
        n_joints = start.shape[0]
        goal = as_float_array(self.goal, "goal", (n_joints,))
        weights = as_float_array(self.weights, "weights", (n_joints, None))
        n_basis = weights.shape[1]
        centres = as_float_array(self.centres, "centres", (n_basis,))
        widths = as_float_array(self.widths, "widths", (n_basis,))
        if n_joints < 1 or n_basis < 2:
            raise InvalidInputError(
                f"DMP: needs at least 1 joint and 2 basis functions, received weights of shape "
                f"{weights.shape}."
            )
        _require_positive_number(self.duration_s, "duration_s")
        _require_positive_number(self.dt_s, "dt_s")
        store_read_only(
            self, start=start, goal=goal, weights=weights, centres=centres, widths=widths
        )
        object.__setattr__(self, "duration_s", float(self.duration_s))
        object.__setattr__(self, "dt_s", float(self.dt_s))

    @property
    def n_joints(self) -> int:
        """J."""
        return int(self.start.shape[0])

    @property
    def n_basis(self) -> int:
        """B."""
        return int(self.weights.shape[1])

    @property
    def n_samples(self) -> int:
        """Number of samples of the teaching trajectory (duration / dt + 1)."""
        return round(self.duration_s / self.dt_s) + 1


@dataclass(frozen=True)
class BasisResponses:
    """The DMP's trajectory as an affine function of start, goal and weights, on a time grid.

    For joint j: ``y_j(t) = from_start * start_j + from_goal * goal_j + from_weights @ w_j``.

    Attributes:
        times_s: Sample times. Shape (T,).
        from_start: Response to a unit start (goal 0, no forcing). Shape (T,).
        from_goal: Response to a unit goal (start 0, no forcing). Shape (T,).
        from_weights: Response to each unit weight (start and goal 0). Shape (T, B).
    """

    times_s: FloatArray
    from_start: FloatArray
    from_goal: FloatArray
    from_weights: FloatArray


@dataclass(frozen=True)
class DMPActionSpace:
    """The paper's action parameterisation: x offsets the dominant weights of each joint.

    The action is laid out joint by joint: ``x[j * k + m]`` offsets ``weights[j, dominant[j, m]]``
    by ``x[j * k + m] * offset_scale[j, m]`` (k dominant weights per joint, dx = J · k).

    Attributes:
        dmp: The fitted teaching DMP (x = 0 reproduces it).
        dominant: Indices of the dominant weights, ascending per joint. Shape (J, k).
        offset_scale: Weight offset per unit of action. Shape (J, k).
        offset_deg_per_unit: Peak trajectory change caused by one unit of one action component.
        responses: Basis responses on the teaching time grid (reused for every trajectory
            generated on that grid).
    """

    dmp: DMP
    dominant: IntArray
    offset_scale: FloatArray
    offset_deg_per_unit: float
    responses: BasisResponses

    @property
    def action_dim(self) -> int:
        """dx = J · k."""
        return int(self.dominant.size)


def _require_positive_number(value: float, name: str) -> None:
    number = float(value)
    if not np.isfinite(number) or number <= 0:
        raise InvalidInputError(f"{name}: must be a positive finite number, received {value}.")


def canonical_phase(normalised_time: FloatArray, gains: DMPGains) -> FloatArray:
    """s(u) = exp(-α_s u). Shape as ``normalised_time``."""
    return np.asarray(np.exp(-gains.alpha_s * normalised_time), dtype=np.float64)


def basis_centres(n_basis: int, gains: DMPGains) -> tuple[FloatArray, FloatArray]:
    """Centres (evenly spaced in time) and widths of ``n_basis`` Gaussian bases in phase s.

    Returns:
        ``(centres, widths)``, each of shape (n_basis,).
    """
    if n_basis < 2:
        raise InvalidInputError(f"n_basis: at least 2 basis functions, received {n_basis}.")
    centres = canonical_phase(np.linspace(0.0, 1.0, n_basis), gains)
    spacing = np.abs(np.diff(centres))
    spacing = np.append(spacing, spacing[-1])
    widths = gains.width_factor / spacing**2
    return centres, np.asarray(widths, dtype=np.float64)


def _forcing_features(phase: FloatArray, centres: FloatArray, widths: FloatArray) -> FloatArray:
    """Φ[t, i] = s_t ψ_i(s_t) / Σ_k ψ_k(s_t): f(s_t) = Φ[t] @ w. Shape (T, B)."""
    psi = np.exp(-widths[None, :] * (phase[:, None] - centres[None, :]) ** 2)
    total = psi.sum(axis=1, keepdims=True)
    total = np.maximum(total, 1e-300)
    return np.asarray(psi * phase[:, None] / total, dtype=np.float64)


def fit_dmp(
    trajectory: npt.ArrayLike,
    dt_s: float,
    n_basis: int = 25,
    gains: DMPGains | None = None,
    regularization: float = 1e-8,
) -> DMP:
    """Fit one DMP per joint to a teaching trajectory (least squares on the forcing term).

    Args:
        trajectory: Joint positions sampled every ``dt_s``, the first sample at t = 0.
            Shape (T, J), T >= 3 * n_basis so every basis sees data.
        dt_s: Sample period in seconds.
        n_basis: Number of basis functions per joint (the paper: 25).
        gains: System gains; defaults to :class:`DMPGains`.
        regularization: Ridge term, relative to the mean diagonal of ΦᵀΦ.

    Returns:
        The fitted :class:`DMP`; start and goal are the first and last samples.

    Raises:
        InvalidInputError: Wrong shape, too few samples, non-finite values or a bad ``dt_s``.
    """
    gains = gains or DMPGains()
    _require_positive_number(dt_s, "dt_s")
    if int(n_basis) != n_basis or n_basis < 2:
        raise InvalidInputError(f"n_basis: must be an integer >= 2, received {n_basis}.")
    demo = as_float_array(trajectory, "trajectory", (None, None))
    n_samples, n_joints = demo.shape
    if n_joints < 1:
        raise InvalidInputError("trajectory: expected shape (T, J) with J >= 1, received J = 0.")
    if n_samples < 3 * n_basis:
        raise InvalidInputError(
            f"trajectory: expected at least {3 * n_basis} samples (3 per basis function) for "
            f"n_basis = {n_basis}, received {n_samples}."
        )
    _require_positive_number(regularization + 1.0, "regularization + 1")
    duration = (n_samples - 1) * float(dt_s)
    centres, widths = basis_centres(int(n_basis), gains)

    # Derivatives in normalised time u = t / τ: dy/du = τ dy/dt.
    step_u = float(dt_s) / duration
    velocity = np.gradient(demo, step_u, axis=0, edge_order=2)
    acceleration = np.gradient(velocity, step_u, axis=0, edge_order=2)
    start, goal = demo[0], demo[-1]
    target = acceleration - gains.alpha_z * (gains.beta_z * (goal[None, :] - demo) - velocity)

    phase = canonical_phase(np.linspace(0.0, 1.0, n_samples), gains)
    features = _forcing_features(phase, centres, widths)
    gram = features.T @ features
    ridge = regularization * float(np.mean(np.diag(gram)))
    weights = scipy.linalg.solve(
        gram + ridge * np.eye(int(n_basis)), features.T @ target, assume_a="pos"
    )
    return DMP(
        start=start.copy(),
        goal=goal.copy(),
        weights=np.asarray(weights.T, dtype=np.float64),
        duration_s=duration,
        dt_s=float(dt_s),
        centres=centres,
        widths=widths,
        gains=gains,
    )


def _sample_times(dmp: DMP, dt_s: float | None, duration_s: float | None) -> FloatArray:
    dt = dmp.dt_s if dt_s is None else float(dt_s)
    duration = dmp.duration_s if duration_s is None else float(duration_s)
    _require_positive_number(dt, "dt_s")
    _require_positive_number(duration, "duration_s")
    n_samples = round(duration / dt) + 1
    if n_samples < 2:
        raise InvalidInputError(
            f"duration_s / dt_s: the trajectory needs at least 2 samples, received "
            f"duration {duration} s at dt {dt} s."
        )
    return np.arange(n_samples, dtype=np.float64) * dt


def basis_responses(
    dmp: DMP, dt_s: float | None = None, duration_s: float | None = None
) -> BasisResponses:
    """The trajectory's affine dependence on start, goal and weights, sampled every ``dt_s``.

    The linear system is integrated with its exact discretisation; the forcing input is taken at
    the midpoint of each of ``gains.substeps`` sub-steps per sample.

    Args:
        dmp: The DMP.
        dt_s: Output sample period; defaults to the teaching one.
        duration_s: Movement duration τ (time scaling); defaults to the teaching one.

    Returns:
        :class:`BasisResponses` on ``T = round(duration / dt) + 1`` samples.
    """
    gains = dmp.gains
    times = _sample_times(dmp, dt_s, duration_s)
    duration = dmp.duration_s if duration_s is None else float(duration_s)
    n_out = times.shape[0]
    substeps = int(gains.substeps)
    # State (y, z) in normalised time u = t / τ; columns: unit start, unit goal, unit weights.
    system = np.array([[0.0, 1.0], [-gains.alpha_z * gains.beta_z, -gains.alpha_z]])
    h = (float(times[1] - times[0]) / duration) / substeps
    transition = scipy.linalg.expm(system * h)
    # Exact input gain of a constant input over one sub-step: A⁻¹ (e^{Ah} - I) (0, 1)ᵀ.
    input_gain = np.linalg.solve(system, transition - np.eye(2))[:, 1]
    midpoints = (np.arange((n_out - 1) * substeps) + 0.5) * h
    features = _forcing_features(canonical_phase(midpoints, gains), dmp.centres, dmp.widths)
    n_columns = 2 + dmp.n_basis
    forcing = np.empty((features.shape[0], n_columns))
    forcing[:, 0] = 0.0
    forcing[:, 1] = gains.alpha_z * gains.beta_z  # a unit goal enters as α_z β_z g
    forcing[:, 2:] = features
    # One output interval at once: x_{k+1} = Aᵈⁿ x_k + Σ_m Aᵈ^(n-1-m) b f_m.
    interval = np.linalg.matrix_power(transition, substeps)
    gathered = np.empty((2, substeps))
    power = np.eye(2)
    for m in range(substeps - 1, -1, -1):
        gathered[:, m] = power @ input_gain
        power = transition @ power
    state = np.zeros((2, n_columns))
    state[0, 0] = 1.0  # unit start, z0 = 0
    result = np.empty((n_out, n_columns))
    result[0] = state[0]
    blocks = forcing.reshape(n_out - 1, substeps, n_columns)
    for k in range(n_out - 1):
        state = interval @ state + gathered @ blocks[k]
        result[k + 1] = state[0]
    return BasisResponses(
        times_s=times,
        from_start=np.ascontiguousarray(result[:, 0]),
        from_goal=np.ascontiguousarray(result[:, 1]),
        from_weights=np.ascontiguousarray(result[:, 2:]),
    )


def rollout(
    dmp: DMP,
    weights: npt.ArrayLike | None = None,
    dt_s: float | None = None,
    duration_s: float | None = None,
    responses: BasisResponses | None = None,
) -> FloatArray:
    """Generate the joint trajectories of a DMP.

    Args:
        dmp: The DMP (start, goal, gains, bases).
        weights: Forcing weights; defaults to ``dmp.weights``. Shape (J, B).
        dt_s: Output sample period; defaults to the teaching one.
        duration_s: Movement duration; defaults to the teaching one.
        responses: Precomputed :func:`basis_responses` for the same grid (saves the
            integration when many trajectories are generated).

    Returns:
        Joint positions, shape (T, J).
    """
    w = (
        dmp.weights
        if weights is None
        else as_float_array(weights, "weights", (dmp.n_joints, dmp.n_basis))
    )
    basis = responses if responses is not None else basis_responses(dmp, dt_s, duration_s)
    trajectory = (
        basis.from_start[:, None] * dmp.start[None, :]
        + basis.from_goal[:, None] * dmp.goal[None, :]
        + basis.from_weights @ w.T
    )
    return np.asarray(trajectory, dtype=np.float64)


def action_space(dmp: DMP, n_dominant: int = 3, offset_deg_per_unit: float = 1.0) -> DMPActionSpace:
    """Pick the dominant weights of each joint and scale the action offsets.

    A weight's contribution is ``|w_i| · max_t |response_i(t)|`` (how far it moves the
    trajectory); the ``n_dominant`` largest per joint are the ones the action offsets.

    Args:
        dmp: The teaching DMP.
        n_dominant: k, dominant weights per joint (the paper: 3, so dx = 6 for two joints).
        offset_deg_per_unit: Peak change of the joint trajectory caused by one unit of one action
            component.

    Returns:
        The :class:`DMPActionSpace`.
    """
    if int(n_dominant) != n_dominant or not 1 <= n_dominant <= dmp.n_basis:
        raise InvalidInputError(
            f"n_dominant: must be an integer in 1..{dmp.n_basis}, received {n_dominant}."
        )
    _require_positive_number(offset_deg_per_unit, "offset_deg_per_unit")
    responses = basis_responses(dmp)
    peak = np.max(np.abs(responses.from_weights), axis=0)  # (B,)
    contribution = np.abs(dmp.weights) * peak[None, :]
    order = np.argsort(-contribution, axis=1, kind="stable")[:, : int(n_dominant)]
    dominant = np.sort(order, axis=1).astype(np.int64)
    scale = float(offset_deg_per_unit) / peak[dominant]
    dominant.flags.writeable = False
    scale.flags.writeable = False
    return DMPActionSpace(
        dmp=dmp,
        dominant=dominant,
        offset_scale=np.asarray(scale, dtype=np.float64),
        offset_deg_per_unit=float(offset_deg_per_unit),
        responses=responses,
    )


def weights_for_action(space: DMPActionSpace, action: npt.ArrayLike) -> FloatArray:
    """w = w_teach + offsets(x) (paper, Exp. 2). Returns shape (J, B).

    Args:
        space: The action space.
        action: x. Shape (dx,) with dx = J · k.
    """
    x = as_float_array(action, "action", (space.action_dim,))
    weights = space.dmp.weights.copy()
    offsets = x.reshape(space.dominant.shape) * space.offset_scale
    rows = np.arange(space.dominant.shape[0])[:, None]
    weights[rows, space.dominant] += offsets
    return weights


def trajectory_for_action(
    space: DMPActionSpace,
    action: npt.ArrayLike,
    dt_s: float | None = None,
    duration_s: float | None = None,
    responses: BasisResponses | None = None,
) -> FloatArray:
    """The joint trajectory of action x. Returns shape (T, J).

    Args:
        space: The action space.
        action: x. Shape (dx,).
        dt_s: Output sample period; defaults to the teaching one.
        duration_s: Movement duration; defaults to the teaching one.
        responses: Precomputed :func:`basis_responses` for the output grid (the teaching grid's
            are used when neither ``dt_s`` nor ``duration_s`` is given).
    """
    if responses is None and dt_s is None and duration_s is None:
        responses = space.responses
    return rollout(
        space.dmp,
        weights_for_action(space, action),
        dt_s=dt_s,
        duration_s=duration_s,
        responses=responses,
    )
