"""The live 3D view of a recognition trial, served by viser (DESIGN.md, "The 3D view").

Two halves:

* **Pure geometry** (module functions, unit-tested without a server): where the latent points
  go in 3D, the outline of a Gaussian belief (interval, ellipse, ellipsoid), the learned GP
  response over (s, x) as a surface mesh, the finger's pose for two joint angles.
* :class:`ManifoldView`, a viser server that draws them and is updated by its caller::

      view = ManifoldView(host="127.0.0.1", port=8081)   # loopback by default
      view.show_model(model)                  # latent points, labels, GP response surface
      view.show_belief(belief, path=means, nearest_object="O2")   # after every step
      view.show_plan(angles_deg, timestep_s=0.01)                 # next planned touch
      view.clear_trial()                      # a new trial starts
      view.close()

  The dashboard embeds it in an ``<iframe>`` pointing at :attr:`ManifoldView.url`.
  :class:`TrialFollower` keeps a view in step with the web app through its REST API and event
  stream alone, so the view works beside any server, in-process or not.

Scene layout (z up): the manifold at the origin (latent dims 1–3 on x, y, z); the GP response
surface to the right (+x); the planned joint trajectories and the animated finger behind (+y).
"""

from __future__ import annotations

import contextlib
import io
import json
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from core.posterior import predict
from core.types import GaussianBelief, ManifoldModel
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


# ---------------------------------------------------------------------------------------------
# Pure geometry
# ---------------------------------------------------------------------------------------------


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
    _check_n_sigma(n_sigma)
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
    _check_n_sigma(n_sigma)
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
    _check_n_sigma(n_sigma)
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


def _check_n_sigma(n_sigma: float) -> None:
    if not np.isfinite(n_sigma) or n_sigma <= 0:
        raise ValueError(f"n_sigma: expected a positive number, received {n_sigma}.")


# ---------------------------------------------------------------------------------------------
# The viser view
# ---------------------------------------------------------------------------------------------


class ManifoldView:
    """A viser server showing a model's manifold and, live, a trial's belief and plan.

    Thread-safe: the methods may be called from any thread (a trial runner, an event follower).

    Args:
        host: Address to bind; loopback by default (DESIGN.md, Security).
        port: Port to bind; 0 picks a free one (see :attr:`port`). viser tries the next ports
            when the one asked for is taken.
        n_sigma: Radius of the belief outline in standard deviations.
        verbose: Let viser print its start-up banner.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8080,
        n_sigma: float = 2.0,
        verbose: bool = False,
    ) -> None:
        import viser  # imported here: the geometry above must not need a server

        _check_n_sigma(n_sigma)
        self._lock = threading.RLock()
        # viser prints its address banner unconditionally; keep it off stdout unless asked.
        quiet = contextlib.nullcontext() if verbose else contextlib.redirect_stdout(io.StringIO())
        with quiet:
            self._server = viser.ViserServer(
                host=host, port=port, label="ActiveTouch", verbose=verbose
            )
        self._host = host
        self._n_sigma = n_sigma
        self._model: ManifoldModel | None = None
        self._belief: GaussianBelief | None = None
        self._plan_stop = threading.Event()
        self._plan_thread: threading.Thread | None = None
        self._closed = False
        self._build_scene()
        self._build_gui()

    # -- properties ---------------------------------------------------------------------------

    @property
    def host(self) -> str:
        """The bound address."""
        return self._host

    @property
    def port(self) -> int:
        """The bound port (the real one, also when 0 was asked for)."""
        return int(self._server.get_port())

    @property
    def url(self) -> str:
        """The address a browser (or the dashboard's iframe) opens."""
        host = "127.0.0.1" if self._host in ("0.0.0.0", "::", "") else self._host
        return f"http://{host}:{self.port}"

    @property
    def n_clients(self) -> int:
        """How many browsers are connected right now."""
        return len(self._server.get_clients())

    @property
    def model(self) -> ManifoldModel | None:
        """The model on show."""
        return self._model

    @property
    def belief(self) -> GaussianBelief | None:
        """The belief on show (``None`` between trials)."""
        return self._belief

    # -- scene --------------------------------------------------------------------------------

    def _build_scene(self) -> None:
        scene = self._server.scene
        scene.set_up_direction("+z")
        self._apply_layout(scene_layout())

    def _apply_layout(self, layout: SceneLayout) -> None:
        """Grid, titles and camera for ``layout`` (also for browsers already connected)."""
        self._layout = layout
        scene = self._server.scene
        e = layout.extent
        scene.add_grid(
            "/manifold/grid", width=2 * e, height=2 * e, cell_size=0.25, section_size=1.0
        )
        scene.add_label(
            "/manifold/title", "object manifold (latent s₁, s₂)", position=(-e, -e - 0.15, 0.0)
        )
        self._server.initial_camera.position = layout.camera_position
        self._server.initial_camera.look_at = layout.camera_look_at
        for client in self._server.get_clients().values():
            client.camera.position = layout.camera_position
            client.camera.look_at = layout.camera_look_at

    def _build_gui(self) -> None:
        gui = self._server.gui
        self._status = gui.add_markdown("**No model loaded.**")
        self._feature = gui.add_dropdown(
            "GP feature", ("y_1",), hint="Feature whose learned response f(s, x) is drawn."
        )
        self._action_axis = gui.add_dropdown(
            "Action dim", ("x_1",), hint="Action dimension on the response surface's depth axis."
        )
        self._show_response = gui.add_checkbox("Show GP response", True)
        self._feature.on_update(lambda _: self._redraw_response())
        self._action_axis.on_update(lambda _: self._redraw_response())
        self._show_response.on_update(lambda _: self._redraw_response())

    def show_model(self, model: ManifoldModel, feature: int = 0, action_axis: int = 0) -> None:
        """Draw the latent points with labels and the GP response; clears the trial overlay.

        Args:
            model: The fitted model.
            feature: Feature whose response surface is drawn first.
            action_axis: Action dimension on the surface's depth axis.
        """
        h = model.hyperparameters
        if not 0 <= feature < h.observation_dim:
            raise ValueError(f"feature: expected 0 ≤ feature < {h.observation_dim}, got {feature}.")
        if not 0 <= action_axis < h.action_dim:
            raise ValueError(
                f"action_axis: expected 0 ≤ action_axis < {h.action_dim}, got {action_axis}."
            )
        with self._lock:
            self._model = model
            self._apply_layout(scene_layout(model.latents))
            self.clear_trial()
            scene = self._server.scene
            positions = embed_latents(model.latents)
            for index, name in enumerate(model.object_names):
                color = object_color(index)
                scene.add_icosphere(
                    f"/manifold/objects/{index}",
                    radius=0.08,
                    color=color,
                    position=positions[index],
                )
                scene.add_label(
                    f"/manifold/labels/{index}",
                    name,
                    position=positions[index] + np.array([0.0, 0.0, 0.12]),
                    anchor="bottom-center",
                )
            features = tuple(f"y_{a + 1}" for a in range(h.observation_dim))
            actions = tuple(f"x_{j + 1}" for j in range(h.action_dim))
            self._feature.options = features
            self._feature.value = features[feature]  # type: ignore[misc]
            self._action_axis.options = actions
            self._action_axis.value = actions[action_axis]  # type: ignore[misc]
            self._status.content = (
                f"**Model**: {model.data.n_objects} objects, ds = {h.latent_dim}, "
                f"dx = {h.action_dim}, dy = {h.observation_dim}  \n"
                f"log-likelihood {model.log_likelihood:.2f}"
            )
        self._redraw_response()

    def _redraw_response(self) -> None:
        with self._lock:
            model = self._model
            scene = self._server.scene
            if model is None:
                return
            if not self._show_response.value:
                scene.add_frame("/response", show_axes=False, position=self._layout.response_origin)
                return
            feature = int(str(self._feature.value).split("_")[1]) - 1
            action_axis = int(str(self._action_axis.value).split("_")[1]) - 1
            base = None if self._belief is None else self._belief.mean
            grid = response_grid(model, feature, action_axis, latent_base=base)
            self._draw_response(model, grid)

    def _draw_response(self, model: ManifoldModel, grid: ResponseGrid) -> None:
        scene = self._server.scene
        size, height = RESPONSE_SIZE, RESPONSE_HEIGHT
        u = scale_to_box(grid.latent_values, 0.0, size)
        v = scale_to_box(grid.action_values, 0.0, size)
        z_low, z_high = float(grid.mean.min()), float(grid.mean.max())
        heights = scale_to_box(grid.mean, 0.0, height)
        vertices, faces = surface_mesh(u, v, heights)
        scene.add_frame("/response", show_axes=False, position=self._layout.response_origin)
        scene.add_mesh_simple(
            "/response/surface",
            vertices,
            faces,
            color=(120, 170, 220),
            opacity=0.85,
            side="double",
            flat_shading=False,
        )
        scene.add_mesh_simple(
            "/response/wire", vertices, faces, color=(60, 90, 130), wireframe=True
        )
        # Each object's slice s = s_l of the surface, in its colour.
        s_min, s_max = float(grid.latent_values.min()), float(grid.latent_values.max())
        for index, latent in enumerate(model.latents[:, grid.latent_axis]):
            i = int(np.argmin(np.abs(grid.latent_values - latent)))
            x_of_object = float(np.interp(latent, [s_min, s_max], [0.0, size]))
            points = np.stack([np.full_like(v, x_of_object), v, heights[i] + 0.01], axis=1)
            scene.add_line_segments(
                f"/response/objects/{index}",
                polyline_segments(points),
                object_color(index),
                thickness=0.03,
            )
        k, j, a = grid.latent_axis + 1, grid.action_axis + 1, grid.feature + 1
        base = np.array([[0, 0, 0], [size, 0, 0], [size, size, 0], [0, size, 0], [0, 0, 0]])
        scene.add_line_segments(
            "/response/base", polyline_segments(base), (150, 150, 150), thickness=0.01
        )
        scene.add_label(
            "/response/title",
            f"GP response y_{a} = f(s_{k}, x_{j}),  y_{a} ∈ [{z_low:.3g}, {z_high:.3g}]",
            position=(0.5 * size, 0.0, height + 0.25),
            anchor="bottom-center",
        )
        scene.add_label(
            "/response/s_axis", f"s_{k}", position=(0.5 * size, -0.1, 0.0), anchor="top-center"
        )
        scene.add_label(
            "/response/x_axis",
            f"x_{j}",
            position=(size + 0.1, 0.5 * size, 0.0),
            anchor="center-left",
        )

    # -- trial overlay ------------------------------------------------------------------------

    def clear_trial(self) -> None:
        """Remove the belief, its path, the highlight and the plan (a new trial starts)."""
        with self._lock:
            self._stop_animation()
            self._belief = None
            scene = self._server.scene
            scene.add_frame("/belief", show_axes=False)
            scene.add_frame("/plan", show_axes=False, position=self._layout.plan_origin)
            scene.add_frame("/finger", show_axes=False, position=self._layout.finger_origin)

    def show_belief(
        self,
        belief: GaussianBelief,
        path: Any = None,
        nearest_object: str | None = None,
    ) -> None:
        """Draw the belief outline, the path of its mean and highlight the nearest object.

        ds = 1: an interval on the x axis; ds = 2: an ellipse; ds ≥ 3: an ellipsoid of the first
        three dimensions (the marginal of the belief on them).

        Args:
            belief: The current belief N(μ, Σ) over s. Its dimension must be the model's ds.
            path: Belief means so far, prior first. Shape (t, ds); ``None`` draws no path.
            nearest_object: Name of the object to highlight (an object of the model).
        """
        with self._lock:
            model = self._model
            if model is not None and belief.dim != model.latent_dim:
                raise ValueError(
                    f"belief: expected dimension {model.latent_dim} (the model's ds), "
                    f"received {belief.dim}."
                )
            self._belief = belief
            scene = self._server.scene
            scene.add_frame("/belief", show_axes=False)
            ds = belief.dim
            center = embed_latents(belief.mean[None, :])[0]
            scene.add_icosphere("/belief/mean", radius=0.06, color=BELIEF_COLOR, position=center)
            if ds == 1:
                low, high = interval_bounds(belief.mean, belief.cov, self._n_sigma)
                segment = np.array([[[low, 0.0, 0.0], [high, 0.0, 0.0]]])
                scene.add_line_segments("/belief/outline", segment, BELIEF_COLOR, thickness=0.04)
            elif ds == 2:
                ring = ellipse_points(belief.mean, belief.cov, self._n_sigma)
                ring3 = embed_latents(np.vstack([ring, ring[:1]]))
                scene.add_line_segments(
                    "/belief/outline", polyline_segments(ring3), BELIEF_COLOR, thickness=0.025
                )
            else:
                vertices, faces = ellipsoid_mesh(belief.mean[:3], belief.cov[:3, :3], self._n_sigma)
                scene.add_mesh_simple(
                    "/belief/outline", vertices, faces, color=(90, 90, 90), opacity=0.3
                )
            if path is not None:
                means = as_float_array(path, "path", (None, ds))
                if means.shape[0] >= 2:
                    scene.add_line_segments(
                        "/belief/path",
                        polyline_segments(embed_latents(means)),
                        (60, 60, 60),
                        thickness=0.015,
                    )
                    scene.add_point_cloud(
                        "/belief/path_points",
                        embed_latents(means),
                        (60, 60, 60),
                        point_size=0.05,
                        point_shape="circle",
                    )
            if nearest_object is not None and model is not None:
                if nearest_object not in model.object_names:
                    raise ValueError(
                        f"nearest_object: {nearest_object!r} is not an object of the model "
                        f"({', '.join(model.object_names)})."
                    )
                index = model.object_names.index(nearest_object)
                scene.add_icosphere(
                    "/belief/nearest",
                    radius=0.16,
                    color=HIGHLIGHT_COLOR,
                    opacity=0.45,
                    position=embed_latents(model.latents[index : index + 1])[0],
                )
                scene.add_label(
                    "/belief/nearest_label",
                    f"nearest: {nearest_object}",
                    position=center + np.array([0.0, 0.0, -0.15]),
                    anchor="top-center",
                )

    def show_plan(
        self,
        angles_deg: Any,
        timestep_s: float,
        joint_names: Sequence[str] = ("FFJ3 flexion", "FFJ4 abduction"),
        animate: bool = True,
    ) -> None:
        """Draw the planned joint trajectories and animate the finger along them (looping).

        Args:
            angles_deg: Planned joint angles, one column per joint, FFJ3 (flexion) first, then
                FFJ4 (abduction). Shape (T, J), J ≥ 1, T ≥ 2.
            timestep_s: Time between two rows (> 0); the animation plays in real time.
            joint_names: Names of the J joints for the legend.
            animate: Run the finger animation (a background thread) until the next plan.
        """
        angles = as_float_array(angles_deg, "angles_deg", (None, None))
        if angles.shape[1] != len(joint_names):
            raise ValueError(
                f"angles_deg: expected {len(joint_names)} columns ({', '.join(joint_names)}), "
                f"received {angles.shape[1]}."
            )
        if not timestep_s > 0:
            raise ValueError(f"timestep_s: expected > 0, received {timestep_s}.")
        lines = trajectory_plot_points(angles, width=PLAN_WIDTH, height=PLAN_HEIGHT)
        with self._lock:
            self._stop_animation()
            scene = self._server.scene
            scene.add_frame("/plan", show_axes=False, position=self._layout.plan_origin)
            duration_s = timestep_s * (angles.shape[0] - 1)
            axes = np.array([[0.0, 0.0, PLAN_HEIGHT], [0.0, 0.0, 0.0], [PLAN_WIDTH, 0.0, 0.0]])
            scene.add_line_segments(
                "/plan/axes", polyline_segments(axes), (150, 150, 150), thickness=0.012
            )
            scene.add_label(
                "/plan/title",
                f"next touch: joint trajectories over {duration_s:.2f} s",
                position=(0.0, 0.0, PLAN_HEIGHT + 0.25),
                anchor="bottom-left",
            )
            label_heights: list[float] = []
            for j, (line, name) in enumerate(zip(lines, joint_names, strict=True)):
                color = PALETTE[(j + 3) % len(PALETTE)]
                scene.add_line_segments(
                    f"/plan/joint_{j}", polyline_segments(line), color, thickness=0.03
                )
                low, high = float(angles[:, j].min()), float(angles[:, j].max())
                z = float(line[-1, 2])
                while any(abs(z - other) < 0.2 for other in label_heights):
                    z -= 0.2  # keep the joint names apart when the lines end together
                label_heights.append(z)
                scene.add_label(
                    f"/plan/label_{j}",
                    f"{name} {low:.0f}…{high:.0f}°",
                    position=(PLAN_WIDTH + 0.08, 0.0, z),
                    anchor="center-left",
                )
            flexion = angles[:, 0]
            abduction = angles[:, 1] if angles.shape[1] > 1 else np.zeros_like(flexion)
            self._draw_finger(float(flexion[0]), float(abduction[0]))
            if animate:
                self._plan_stop = threading.Event()
                self._plan_thread = threading.Thread(
                    target=self._animate,
                    args=(flexion, abduction, timestep_s, self._plan_stop),
                    name="viz-finger",
                    daemon=True,
                )
                self._plan_thread.start()

    def _draw_finger(self, flexion_deg: float, abduction_deg: float) -> None:
        points = finger_points(flexion_deg, abduction_deg)
        scene = self._server.scene
        scene.add_line_segments(
            "/finger/links", polyline_segments(points), (70, 70, 70), thickness=0.08
        )
        scene.add_point_cloud(
            "/finger/joints", points, (220, 80, 40), point_size=0.12, point_shape="circle"
        )

    def _animate(
        self, flexion: FloatArray, abduction: FloatArray, timestep_s: float, stop: threading.Event
    ) -> None:
        frame_s = max(timestep_s, 1.0 / 15.0)  # at most 15 frames a second
        stride = max(1, round(frame_s / timestep_s))
        while not stop.is_set():
            for i in range(0, flexion.shape[0], stride):
                if stop.wait(frame_s):
                    return
                with self._lock:
                    if stop.is_set() or self._closed:
                        return
                    self._draw_finger(float(flexion[i]), float(abduction[i]))
            if stop.wait(0.6):  # rest at the end of the touch, then replay
                return

    def _stop_animation(self) -> None:
        self._plan_stop.set()
        thread = self._plan_thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2.0)
        self._plan_thread = None

    def close(self) -> None:
        """Stop the animation and the server."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._stop_animation()
        self._server.stop()


# ---------------------------------------------------------------------------------------------
# Following the web app
# ---------------------------------------------------------------------------------------------


def _belief_from(mean: Any, cov: Any) -> GaussianBelief:
    mu = np.asarray(mean, dtype=np.float64)
    return GaussianBelief(mean=mu, cov=np.asarray(cov, dtype=np.float64).reshape(mu.size, mu.size))


def sse_events(lines: Iterator[str]) -> Iterator[tuple[str, str, str]]:
    """Parse a server-sent event stream into (id, event type, data) triples.

    Args:
        lines: The stream's lines, without line endings.
    """
    event_id, event_type = "", "message"
    data: list[str] = []
    for line in lines:
        if line == "":
            if data:
                yield event_id, event_type, "\n".join(data)
            event_type, data = "message", []
            continue
        if line.startswith(":"):
            continue
        field, _, value = line.partition(":")
        value = value.removeprefix(" ")
        if field == "id":
            event_id = value
        elif field == "event":
            event_type = value
        elif field == "data":
            data.append(value)


class TrialFollower:
    """Keeps a :class:`ManifoldView` in step with the web app's trials (REST + events only).

    Listens to ``GET /api/v1/events``; on any event that names a trial it fetches
    ``GET /api/v1/trials/{id}`` and draws its belief, mean path and nearest object (loading the
    trial's model through ``GET /api/v1/models/{id}/export`` when it changes), and the planned
    trajectory of the step when the step carries one. Runs in a daemon thread; reconnects with
    ``Last-Event-ID`` when the stream drops.

    Args:
        view: The view to update.
        base_url: The web app, e.g. ``http://127.0.0.1:8000``.
        token: API token, if the server wants one.
        on_error: Called with each exception the loop survives (default: ignore).
    """

    def __init__(
        self,
        view: ManifoldView,
        base_url: str,
        token: str | None = None,
        on_error: Callable[[Exception], None] | None = None,
    ) -> None:
        import httpx

        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self._client = httpx.Client(base_url=base_url.rstrip("/"), headers=headers, timeout=10.0)
        self._view = view
        self._on_error = on_error
        self._stop = threading.Event()
        self._model_id: Any = None
        self._trial_id: Any = None
        self._last_event_id = ""
        self._response: Any = None
        self._thread = threading.Thread(target=self._run, name="viz-follower", daemon=True)

    def start(self) -> TrialFollower:
        """Start following; returns self."""
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop following: close the event stream (so the server sees the client go), join."""
        self._stop.set()
        response = self._response
        if response is not None:
            with contextlib.suppress(Exception):
                response.close()
        self._client.close()
        self._thread.join(timeout=1.0)

    def show_model(self, model_id: Any) -> None:
        """Load model ``model_id`` from the app and show it."""
        from app.documents import model_from_document

        response = self._client.get(f"/api/v1/models/{model_id}/export")
        response.raise_for_status()
        self._view.show_model(model_from_document(response.json()))
        self._model_id = model_id

    def show_trial(self, trial_id: Any) -> None:
        """Fetch trial ``trial_id`` and draw its current state."""
        response = self._client.get(f"/api/v1/trials/{trial_id}")
        response.raise_for_status()
        trial = response.json()
        if trial.get("model_id") != self._model_id:
            self.show_model(trial["model_id"])
        if trial_id != self._trial_id:
            self._view.clear_trial()
            self._trial_id = trial_id
        steps = trial.get("steps") or []
        prior_mean = trial.get("prior_mean")
        means = ([prior_mean] if prior_mean is not None else []) + [
            _step_belief(step)["mean"] for step in steps
        ]
        if steps:
            last = _step_belief(steps[-1])
            self._view.show_belief(
                _belief_from(last["mean"], last["cov"]),
                path=np.asarray(means) if len(means) >= 2 else None,
                nearest_object=steps[-1].get("nearest_object"),
            )
            plan = _step_trajectory(steps[-1])
            if plan is not None:
                angles, timestep, names = plan
                self._view.show_plan(angles, timestep, joint_names=names)
        elif prior_mean is not None and trial.get("prior_cov") is not None:
            self._view.show_belief(_belief_from(prior_mean, trial["prior_cov"]))

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                headers = {"Last-Event-ID": self._last_event_id} if self._last_event_id else {}
                with self._client.stream(
                    "GET", "/api/v1/events", headers=headers, timeout=None
                ) as response:
                    self._response = response
                    response.raise_for_status()
                    for event_id, event_type, data in sse_events(response.iter_lines()):
                        if self._stop.is_set():
                            return
                        if event_id:
                            self._last_event_id = event_id
                        self._handle(event_type, data)
            except Exception as exc:  # the follower must outlive a dropped stream
                if self._stop.is_set():
                    return
                if self._on_error is not None:
                    self._on_error(exc)
                self._stop.wait(1.0)

    def _handle(self, event_type: str, data: str) -> None:
        try:
            payload = json.loads(data)
        except ValueError:
            return
        if not isinstance(payload, dict):
            return
        if isinstance(payload.get("type"), str) and isinstance(payload.get("data"), dict):
            event_type, payload = payload["type"], payload["data"]  # {"id","type","time","data"}
        trial_id = payload.get("trial_id")
        if trial_id is None and event_type.startswith("trial") and "id" in payload:
            trial_id = payload["id"]
        if trial_id is not None:
            self.show_trial(trial_id)
        elif event_type.startswith("model") and payload.get("status") == "ready":
            model_id = payload.get("model_id", payload.get("id"))
            if model_id is not None and self._trial_id is None:
                self.show_model(model_id)


def _step_belief(step: dict[str, Any]) -> dict[str, Any]:
    belief = step.get("belief")
    if isinstance(belief, dict):
        return belief
    return {"mean": step["belief_mean"], "cov": step["belief_cov"]}


def _step_trajectory(step: dict[str, Any]) -> tuple[FloatArray, float, tuple[str, ...]] | None:
    """(angles (T, J), timestep, joint names) of a step's trajectory, if it has one."""
    trajectory = step.get("trajectory")
    if not isinstance(trajectory, dict):
        return None
    angles = trajectory.get("commanded_deg") or trajectory.get("angles_deg")
    timestep = trajectory.get("dt_s") or trajectory.get("timestep_s")
    if angles is None or timestep is None:
        return None
    array = np.asarray(angles, dtype=np.float64)
    if array.ndim != 2 or array.shape[0] < 2:
        return None
    names = trajectory.get("joint_names") or ["FFJ3", "FFJ4"][: array.shape[1]]
    if len(names) != array.shape[1]:
        return None
    return array, float(timestep), tuple(str(n) for n in names)


def wait_for_clients(view: ManifoldView, count: int = 1, timeout_s: float = 10.0) -> bool:
    """Wait until ``count`` browsers are connected to ``view``; whether they were in time."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if view.n_clients >= count:
            return True
        time.sleep(0.05)
    return view.n_clients >= count


def wait_for_belief_mean(
    view: ManifoldView, mean: FloatArray, timeout_s: float = 15.0, rtol: float = 1e-12
) -> bool:
    """Wait until ``view`` shows a belief whose mean is ``mean`` (shape (ds,), to ``rtol``), as
    after its follower has drawn a trial's last step; whether it did in time."""

    def shown() -> bool:
        belief = view.belief
        return belief is not None and bool(np.allclose(belief.mean, mean, rtol=rtol, atol=0))

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if shown():
            return True
        time.sleep(0.05)
    return shown()
