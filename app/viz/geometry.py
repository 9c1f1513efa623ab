"""Pure geometry of the live 3D view (:mod:`app.viz.view`), unit-tested without a server.

Where the latent points go in 3D, the outline of a Gaussian belief (interval, ellipse, ellipsoid),
the learned GP response over (s, x) as a surface mesh, the finger's pose for two joint angles, the
joint trajectories as plot lines and the layout of the scene, with the colours and panel sizes
the view draws them in. numpy and the core only: nothing here imports viser.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from core.gp import predict
from core.types import ManifoldModel
from core.validation import as_float_array

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

#: Object colours (RGB 0–255), Tableau 10: distinct, colour-blind friendly, print well.
PALETTE: tuple[tuple[int, int, int], ...] = (
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
)
BELIEF_COLOR = (20, 20, 20)
HIGHLIGHT_COLOR = (255, 196, 0)

#: Sizes of the side panels (scene units): response surface box, trajectory plot.
RESPONSE_SIZE = 3.0
RESPONSE_HEIGHT = 1.5
PLAN_WIDTH = 3.0
PLAN_HEIGHT = 1.5


def object_color(index: int) -> tuple[int, int, int]:
    """The colour of object ``index`` (cycles through :data:`PALETTE`)."""
    return PALETTE[index % len(PALETTE)]


def embed_latents(points: Any) -> FloatArray:
    """Place latent points in 3D: dims 1–3 on x, y, z, zero-padded (ds < 3) or cut (ds > 3).

    Args:
        points: Latent points. Shape (n, ds), ds ≥ 1.

    Returns:
        Scene positions. Shape (n, 3).
    """
    array = as_float_array(points, "points", (None, None))
    if array.shape[1] < 1:
        raise ValueError(f"points: expected at least one latent dimension, received {array.shape}.")
    out = np.zeros((array.shape[0], 3))
    keep = min(3, array.shape[1])
    out[:, :keep] = array[:, :keep]
    return out


def _symmetric_factor(cov: FloatArray, name: str) -> FloatArray:
    """A matrix A with A Aᵀ = cov (eigen-decomposition; clear error if cov is not PSD)."""
    if not np.allclose(cov, cov.T, rtol=1e-8, atol=1e-12):
        raise ValueError(f"{name}: expected a symmetric matrix, received {cov.tolist()}.")
    values, vectors = np.linalg.eigh(cov)
    if values.min() < -1e-10 * max(1.0, float(abs(values).max())):
        raise ValueError(
            f"{name}: expected a positive semi-definite covariance, eigenvalues {values.tolist()}."
        )
    factor: FloatArray = vectors * np.sqrt(np.clip(values, 0.0, None))
    return factor


def interval_bounds(mean: Any, cov: Any, n_sigma: float = 2.0) -> tuple[float, float]:
    """The ±n_sigma interval of a one-dimensional Gaussian belief.

    Args:
        mean: μ. Shape (1,).
        cov: Σ. Shape (1, 1), Σ ≥ 0.
        n_sigma: Half-width in standard deviations (> 0).

    Returns:
        (μ - n_sigma·σ, μ + n_sigma·σ).
    """
    mu = as_float_array(mean, "mean", (1,))
    sigma2 = as_float_array(cov, "cov", (1, 1))
    check_n_sigma(n_sigma)
    if sigma2[0, 0] < 0:
        raise ValueError(f"cov: expected a variance ≥ 0, received {sigma2[0, 0]}.")
    half = n_sigma * float(np.sqrt(sigma2[0, 0]))
    return float(mu[0]) - half, float(mu[0]) + half


def ellipse_points(mean: Any, cov: Any, n_sigma: float = 2.0, n_points: int = 72) -> FloatArray:
    """Points on the n_sigma contour {s : (s-μ)ᵀ Σ⁻¹ (s-μ) = n_sigma²} of a 2D Gaussian.

    Args:
        mean: μ. Shape (2,).
        cov: Σ, symmetric positive semi-definite. Shape (2, 2).
        n_sigma: Mahalanobis radius of the contour (> 0).
        n_points: Number of points (≥ 3); the curve is closed by the caller.

    Returns:
        The contour. Shape (n_points, 2).
    """
    mu = as_float_array(mean, "mean", (2,))
    sigma = as_float_array(cov, "cov", (2, 2))
    check_n_sigma(n_sigma)
    if n_points < 3:
        raise ValueError(f"n_points: expected at least 3, received {n_points}.")
    angles = np.linspace(0.0, 2.0 * np.pi, n_points, endpoint=False)
    circle = np.stack([np.cos(angles), np.sin(angles)])  # (2, n)
    points: FloatArray = mu + (n_sigma * _symmetric_factor(sigma, "cov") @ circle).T
    return points


def ellipsoid_mesh(
    mean: Any, cov: Any, n_sigma: float = 2.0, n_rings: int = 12, n_segments: int = 24
) -> tuple[FloatArray, IntArray]:
    """A triangle mesh of the n_sigma ellipsoid of a 3D Gaussian (a transformed UV sphere).

    Args:
        mean: μ. Shape (3,).
        cov: Σ, symmetric positive semi-definite. Shape (3, 3).
        n_sigma: Mahalanobis radius (> 0).
        n_rings: Latitude bands (≥ 2).
        n_segments: Longitude segments (≥ 3).

    Returns:
        Vertices, shape (2 + (n_rings - 1)·n_segments, 3), and triangles (indices into the
        vertices), shape (2·n_segments·(n_rings - 1), 3), wound outwards.
    """
    mu = as_float_array(mean, "mean", (3,))
    sigma = as_float_array(cov, "cov", (3, 3))
    check_n_sigma(n_sigma)
    if n_rings < 2 or n_segments < 3:
        raise ValueError(
            f"n_rings ≥ 2 and n_segments ≥ 3 expected, received {n_rings} and {n_segments}."
        )
    polar = np.linspace(0.0, np.pi, n_rings + 1)[1:-1]
    azimuth = np.linspace(0.0, 2.0 * np.pi, n_segments, endpoint=False)
    ring_points = np.stack(
        [
            np.outer(np.sin(polar), np.cos(azimuth)).ravel(),
            np.outer(np.sin(polar), np.sin(azimuth)).ravel(),
            np.repeat(np.cos(polar), n_segments),
        ],
        axis=1,
    )
    unit = np.vstack([[0.0, 0.0, 1.0], ring_points, [0.0, 0.0, -1.0]])
    vertices: FloatArray = mu + n_sigma * unit @ _symmetric_factor(sigma, "cov").T
    faces: list[tuple[int, int, int]] = []
    top, bottom = 0, unit.shape[0] - 1

    def ring(r: int, k: int) -> int:
        return 1 + r * n_segments + k % n_segments

    for k in range(n_segments):
        faces.append((top, ring(0, k), ring(0, k + 1)))
        faces.append((bottom, ring(n_rings - 2, k + 1), ring(n_rings - 2, k)))
        for r in range(n_rings - 2):
            a, b = ring(r, k), ring(r, k + 1)
            c, d = ring(r + 1, k), ring(r + 1, k + 1)
            faces.extend([(a, c, d), (a, d, b)])
    return vertices, np.asarray(faces, dtype=np.int64)


def polyline_segments(points: Any) -> FloatArray:
    """Consecutive pairs of a polyline, as viser's line segments want them.

    Args:
        points: Vertices of the polyline. Shape (n, 3), n ≥ 2.

    Returns:
        Segments. Shape (n - 1, 2, 3).
    """
    array = as_float_array(points, "points", (None, 3))
    if array.shape[0] < 2:
        raise ValueError(f"points: a polyline needs at least 2 points, received {array.shape[0]}.")
    return np.stack([array[:-1], array[1:]], axis=1)


def surface_mesh(u: Any, v: Any, heights: Any) -> tuple[FloatArray, IntArray]:
    """A triangle mesh of the height field z = heights[i, j] over the grid (u[i], v[j]).

    Args:
        u: Grid along x. Shape (nu,), nu ≥ 2.
        v: Grid along y. Shape (nv,), nv ≥ 2.
        heights: Heights. Shape (nu, nv).

    Returns:
        Vertices (nu·nv, 3) in row-major order (vertex i·nv + j is (u[i], v[j], heights[i, j]))
        and triangles (2·(nu-1)·(nv-1), 3), wound counter-clockwise seen from +z.
    """
    u_arr = as_float_array(u, "u", (None,))
    v_arr = as_float_array(v, "v", (None,))
    if u_arr.shape[0] < 2 or v_arr.shape[0] < 2:
        raise ValueError(
            f"u, v: expected at least 2 grid values each, received {u_arr.shape[0]} and "
            f"{v_arr.shape[0]}."
        )
    z = as_float_array(heights, "heights", (u_arr.shape[0], v_arr.shape[0]))
    uu, vv = np.meshgrid(u_arr, v_arr, indexing="ij")
    vertices = np.stack([uu.ravel(), vv.ravel(), z.ravel()], axis=1)
    nu, nv = z.shape
    i, j = np.meshgrid(np.arange(nu - 1), np.arange(nv - 1), indexing="ij")
    a = (i * nv + j).ravel()
    b = a + nv  # (i+1, j)
    c = a + 1  # (i, j+1)
    d = b + 1  # (i+1, j+1)
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int64)
    return vertices, faces


@dataclass(frozen=True)
class ResponseGrid:
    """The GP predictive mean of one feature over a grid of (s_k, x_j), the rest held fixed.

    Attributes:
        feature: Index a of the feature y_a.
        latent_axis: Index k of the latent dimension on the first grid axis.
        action_axis: Index j of the action dimension on the second grid axis.
        latent_values: Grid of s_k. Shape (n_latent,).
        action_values: Grid of x_j. Shape (n_action,).
        mean: Predictive mean of y_a. Shape (n_latent, n_action).
        std: Predictive standard deviation of y_a (noise included). Shape (n_latent, n_action).
    """

    feature: int
    latent_axis: int
    action_axis: int
    latent_values: FloatArray
    action_values: FloatArray
    mean: FloatArray
    std: FloatArray


def response_grid(
    model: ManifoldModel,
    feature: int,
    action_axis: int = 0,
    latent_axis: int = 0,
    n_latent: int = 40,
    n_action: int = 40,
    latent_base: Any = None,
    action_base: Any = None,
    margin: float = 0.25,
) -> ResponseGrid:
    """Evaluate the learned response y_a = f_a(s, x) over a grid of (s_k, x_j).

    The grid spans the objects' latent range and the training actions' range, each widened by
    ``margin`` of its width; the other latent and action dimensions stay at ``latent_base``
    (default: the centre of the latents) and ``action_base`` (default: the training actions'
    mean).

    Args:
        model: A conditioned model.
        feature: Feature index a, 0 ≤ a < dy.
        action_axis: Action dimension j on the second axis, 0 ≤ j < dx.
        latent_axis: Latent dimension k on the first axis, 0 ≤ k < ds.
        n_latent: Grid size along s_k (≥ 2).
        n_action: Grid size along x_j (≥ 2).
        latent_base: Values of the other latent dims. Shape (ds,).
        action_base: Values of the other action dims. Shape (dx,).
        margin: Widening of the ranges, as a fraction of their width (≥ 0).

    Returns:
        The grid and the predictive mean and standard deviation on it.
    """
    h = model.hyperparameters
    for name, value, size in (
        ("feature", feature, h.observation_dim),
        ("action_axis", action_axis, h.action_dim),
        ("latent_axis", latent_axis, h.latent_dim),
    ):
        if not 0 <= value < size:
            raise ValueError(f"{name}: expected 0 ≤ {name} < {size}, received {value}.")
    if n_latent < 2 or n_action < 2:
        raise ValueError(f"n_latent, n_action: expected ≥ 2, received {n_latent}, {n_action}.")
    if margin < 0:
        raise ValueError(f"margin: expected ≥ 0, received {margin}.")
    latents = model.latents
    actions = model.data.actions
    s_base = (
        latents.mean(axis=0)
        if latent_base is None
        else as_float_array(latent_base, "latent_base", (h.latent_dim,))
    )
    x_base = (
        actions.mean(axis=0)
        if action_base is None
        else as_float_array(action_base, "action_base", (h.action_dim,))
    )

    s_low, s_high = float(latents[:, latent_axis].min()), float(latents[:, latent_axis].max())
    s_width = max(s_high - s_low, 1e-6)
    x_low, x_high = float(actions[:, action_axis].min()), float(actions[:, action_axis].max())
    x_width = max(x_high - x_low, 1e-6)
    s_values = np.linspace(s_low - margin * s_width, s_high + margin * s_width, n_latent)
    x_values = np.linspace(x_low - margin * x_width, x_high + margin * x_width, n_action)
    ss, xx = np.meshgrid(s_values, x_values, indexing="ij")
    query_s = np.tile(s_base, (ss.size, 1))
    query_s[:, latent_axis] = ss.ravel()
    query_x = np.tile(x_base, (xx.size, 1))
    query_x[:, action_axis] = xx.ravel()
    mean, variance = predict(model, query_s, query_x)
    return ResponseGrid(
        feature=feature,
        latent_axis=latent_axis,
        action_axis=action_axis,
        latent_values=s_values,
        action_values=x_values,
        mean=mean[:, feature].reshape(ss.shape),
        std=np.sqrt(variance[:, feature]).reshape(ss.shape),
    )


def scale_to_box(values: Any, low: float, high: float) -> FloatArray:
    """Map ``values`` affinely onto [low, high] (a constant array goes to the middle)."""
    array = np.asarray(values, dtype=np.float64)
    v_min, v_max = float(array.min()), float(array.max())
    if v_max - v_min < 1e-12:
        return np.full_like(array, 0.5 * (low + high))
    scaled: FloatArray = low + (array - v_min) * (high - low) / (v_max - v_min)
    return scaled


#: Link lengths of the schematic finger (scene units): proximal, middle + distal.
FINGER_LINKS = (0.9, 0.7)


def finger_points(
    flexion_deg: float, abduction_deg: float, link_lengths: Sequence[float] = FINGER_LINKS
) -> FloatArray:
    """The joints of a schematic 2-DoF finger (the paper's FFJ3 flexion, FFJ4 abduction).

    The finger points along +x when both angles are 0. Abduction turns it about +z (towards +y),
    flexion bends it downwards (towards -z) about the turned y axis; the distal link is coupled
    and bends by the same angle again, as the under-actuated distal joints of a tendon hand.

    Args:
        flexion_deg: FFJ3 angle in degrees.
        abduction_deg: FFJ4 angle in degrees.
        link_lengths: Lengths of the two links (> 0).

    Returns:
        Base, middle joint and fingertip. Shape (3, 3).
    """
    if len(link_lengths) != 2 or min(link_lengths) <= 0:
        raise ValueError(f"link_lengths: expected two positive lengths, received {link_lengths}.")
    flex = np.deg2rad(flexion_deg)
    abd = np.deg2rad(abduction_deg)
    heading = np.array([np.cos(abd), np.sin(abd), 0.0])

    def direction(angle: float) -> FloatArray:
        out: FloatArray = np.cos(angle) * heading + np.array([0.0, 0.0, -np.sin(angle)])
        return out

    base = np.zeros(3)
    middle = base + link_lengths[0] * direction(flex)
    tip = middle + link_lengths[1] * direction(2.0 * flex)
    return np.stack([base, middle, tip])


def trajectory_plot_points(
    angles_deg: Any, width: float = 3.0, height: float = 1.5
) -> list[FloatArray]:
    """Joint trajectories as 2D plot lines (time → x, angle → z) in a width × height box.

    All joints share one angle scale so their amplitudes compare.

    Args:
        angles_deg: Joint angles over time. Shape (T, J), T ≥ 2.
        width: Width of the plot (time axis).
        height: Height of the plot (angle axis).

    Returns:
        One polyline per joint, each of shape (T, 3) in the plot's x–z plane.
    """
    angles = as_float_array(angles_deg, "angles_deg", (None, None))
    if angles.shape[0] < 2:
        raise ValueError(f"angles_deg: expected at least 2 time steps, received {angles.shape[0]}.")
    t = np.linspace(0.0, width, angles.shape[0])
    z = scale_to_box(angles, 0.0, height)
    return [np.stack([t, np.zeros_like(t), z[:, j]], axis=1) for j in range(angles.shape[1])]


@dataclass(frozen=True)
class SceneLayout:
    """Where the parts of the scene go, sized to the model's latent points.

    The manifold's grid is centred on the origin (half-width ``extent``); the response surface
    stands to its right (+x), the trajectory plot and the finger behind it (+y), and the camera
    looks at the whole from the front (-y), from above.
    """

    extent: float
    response_origin: tuple[float, float, float]
    plan_origin: tuple[float, float, float]
    finger_origin: tuple[float, float, float]
    camera_position: tuple[float, float, float]
    camera_look_at: tuple[float, float, float]


def scene_layout(latents: Any = None) -> SceneLayout:
    """Lay out the scene around latent points (shape (L, ds)); ``None``: a default size."""
    if latents is None:
        extent = 2.0
    else:
        positions = embed_latents(latents)
        extent = float(np.ceil(max(1.0, 1.25 * float(np.abs(positions[:, :2]).max())) * 2) / 2)
    gap = 0.8
    response = (extent + gap, -RESPONSE_SIZE / 2, 0.0)
    plan = (-extent, extent + gap, 0.0)
    finger = (-extent - 1.0, extent + gap, 1.7)
    x_low, x_high = -extent - 1.6, extent + gap + RESPONSE_SIZE
    y_low, y_high = -extent, extent + gap + 0.5
    span = max(x_high - x_low, y_high - y_low)
    centre = (0.5 * (x_low + x_high), 0.5 * (y_low + y_high), 0.4)
    camera = (centre[0], centre[1] - 0.75 * span, 0.6 * span)
    return SceneLayout(
        extent=extent,
        response_origin=response,
        plan_origin=plan,
        finger_origin=finger,
        camera_position=camera,
        camera_look_at=centre,
    )


def check_n_sigma(n_sigma: float) -> None:
    """Raise :class:`ValueError` unless ``n_sigma`` is a finite positive number."""
    if not np.isfinite(n_sigma) or n_sigma <= 0:
        raise ValueError(f"n_sigma: expected a positive number, received {n_sigma}.")
