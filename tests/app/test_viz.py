"""The viser view: its geometry (pure functions) and the server it runs (loopback, free port)."""

from __future__ import annotations

import socket
import urllib.request

import numpy as np
import pytest

from app.viz.follower import sse_events
from app.viz.geometry import (
    ellipse_points,
    ellipsoid_mesh,
    embed_latents,
    finger_points,
    interval_bounds,
    polyline_segments,
    response_grid,
    scale_to_box,
    scene_layout,
    surface_mesh,
    trajectory_plot_points,
)
from app.viz.view import ManifoldView
from core.evaluation.worlds import EXPERIMENT1_THETAS, sample_experiment1
from core.gp.posterior import condition, predict
from core.types import GaussianBelief, Hyperparameters, ManifoldModel


def _mahalanobis(points: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    diff = points - mean
    return np.sqrt(np.einsum("ni,ij,nj->n", diff, np.linalg.inv(cov), diff))


def _model(latent_dim: int, seed: int = 0) -> ManifoldModel:
    """Experiment 1 data conditioned on fixed hyperparameters (no fit: fast, deterministic)."""
    rng = np.random.default_rng(seed)
    data = sample_experiment1(rng, touches_per_object=15)
    latents = np.zeros((data.n_objects, latent_dim))
    latents[:, 0] = np.asarray(EXPERIMENT1_THETAS)
    if latent_dim > 1:
        latents[:, 1:] = rng.normal(scale=0.3, size=(data.n_objects, latent_dim - 1))
    hyper = Hyperparameters(
        signal_variance=np.full(3, 0.3),
        noise_variance=np.full(3, 0.01),
        latent_lengthscales=np.full((3, latent_dim), 0.5),
        action_lengthscales=np.full((3, 1), 0.8),
    )
    return condition(data, latents, hyper)


# --- geometry ------------------------------------------------------------------------------


def test_embed_latents_pads_and_cuts() -> None:
    assert embed_latents([[1.0], [2.0]]).tolist() == [[1, 0, 0], [2, 0, 0]]
    assert embed_latents([[1.0, 2.0]]).tolist() == [[1, 2, 0]]
    assert embed_latents([[1.0, 2.0, 3.0, 4.0]]).tolist() == [[1, 2, 3]]
    with pytest.raises(ValueError, match=r"points: expected shape \(any, any\)"):
        embed_latents([1.0, 2.0])


@pytest.mark.parametrize(
    "cov",
    [
        np.array([[1.0, 0.0], [0.0, 1.0]]),
        np.array([[2.0, 0.9], [0.9, 0.5]]),
        np.array([[0.01, -0.004], [-0.004, 0.003]]),
    ],
)
def test_ellipse_points_lie_on_the_sigma_contour(cov: np.ndarray) -> None:
    mean = np.array([0.3, -1.2])
    points = ellipse_points(mean, cov, n_sigma=2.0, n_points=50)
    assert points.shape == (50, 2)
    np.testing.assert_allclose(_mahalanobis(points, mean, cov), 2.0, rtol=1e-9)
    # The contour surrounds the mean: its centroid is the mean (symmetric sampling).
    np.testing.assert_allclose(points.mean(axis=0), mean, atol=1e-12)


def test_ellipse_rejects_bad_covariances() -> None:
    with pytest.raises(ValueError, match="symmetric"):
        ellipse_points([0, 0], [[1.0, 0.5], [0.0, 1.0]])
    with pytest.raises(ValueError, match="positive semi-definite"):
        ellipse_points([0, 0], [[1.0, 2.0], [2.0, 1.0]])
    with pytest.raises(ValueError, match=r"cov: expected shape \(2, 2\), received \(3, 3\)"):
        ellipse_points([0, 0], np.eye(3))
    with pytest.raises(ValueError, match="n_sigma"):
        ellipse_points([0, 0], np.eye(2), n_sigma=0.0)


def test_interval_bounds() -> None:
    assert interval_bounds([1.0], [[0.25]], n_sigma=2.0) == pytest.approx((0.0, 2.0))
    with pytest.raises(ValueError, match="variance ≥ 0"):
        interval_bounds([1.0], [[-0.25]])


def test_ellipsoid_mesh_vertices_on_contour_and_faces_outward() -> None:
    rng = np.random.default_rng(3)
    a = rng.normal(size=(3, 3))
    cov = a @ a.T + 0.1 * np.eye(3)
    mean = np.array([1.0, -2.0, 0.5])
    vertices, faces = ellipsoid_mesh(mean, cov, n_sigma=1.5, n_rings=8, n_segments=10)
    assert vertices.shape == (2 + 7 * 10, 3)
    assert faces.shape == (2 * 10 * 7, 3)
    assert faces.min() == 0
    assert faces.max() == len(vertices) - 1
    np.testing.assert_allclose(_mahalanobis(vertices, mean, cov), 1.5, rtol=1e-9)
    # Outward winding: each face normal points away from the mean (in whitened coordinates,
    # where the ellipsoid is a sphere, the test is exact).
    whiten = np.linalg.inv(np.linalg.cholesky(cov))
    unit = (vertices - mean) @ whiten.T
    tri = unit[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(np.einsum("fi,fi->f", normals, tri.mean(axis=1)) > 0)


def test_surface_mesh_indexing_and_winding() -> None:
    u = np.array([0.0, 1.0, 2.0])
    v = np.array([0.0, 0.5])
    heights = np.array([[0.0, 1.0], [2.0, 3.0], [4.0, 5.0]])
    vertices, faces = surface_mesh(u, v, heights)
    assert vertices.shape == (6, 3)
    assert faces.shape == (2 * 2 * 1, 3)
    # Vertex i*nv + j is (u[i], v[j], heights[i, j]).
    np.testing.assert_array_equal(vertices[1 * 2 + 1], [1.0, 0.5, 3.0])
    flat = vertices.copy()
    flat[:, 2] = 0.0
    tri = flat[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(normals[:, 2] > 0)  # counter-clockwise seen from +z
    with pytest.raises(ValueError, match=r"heights: expected shape \(3, 2\)"):
        surface_mesh(u, v, heights.T)


def test_polyline_segments() -> None:
    points = np.arange(9.0).reshape(3, 3)
    segments = polyline_segments(points)
    assert segments.shape == (2, 2, 3)
    np.testing.assert_array_equal(segments[1], points[1:])
    with pytest.raises(ValueError, match="at least 2 points"):
        polyline_segments(points[:1])


def test_scale_to_box() -> None:
    np.testing.assert_allclose(scale_to_box([2.0, 4.0, 3.0], 0.0, 1.0), [0.0, 1.0, 0.5])
    np.testing.assert_allclose(scale_to_box([7.0, 7.0], 0.0, 2.0), [1.0, 1.0])


def test_finger_points_kinematics() -> None:
    straight = finger_points(0.0, 0.0, (1.0, 0.5))
    np.testing.assert_allclose(straight, [[0, 0, 0], [1, 0, 0], [1.5, 0, 0]], atol=1e-12)
    bent = finger_points(90.0, 0.0, (1.0, 0.5))
    np.testing.assert_allclose(bent[1], [0.0, 0.0, -1.0], atol=1e-12)  # proximal points down
    np.testing.assert_allclose(bent[2], [-0.5, 0.0, -1.0], atol=1e-12)  # distal curls back
    turned = finger_points(0.0, 90.0, (1.0, 0.5))
    np.testing.assert_allclose(turned[2], [0.0, 1.5, 0.0], atol=1e-12)
    for flexion, abduction in [(10.0, -20.0), (45.0, 15.0)]:
        points = finger_points(flexion, abduction, (1.0, 0.5))
        np.testing.assert_allclose(np.linalg.norm(np.diff(points, axis=0), axis=1), [1.0, 0.5])


def test_trajectory_plot_points_share_one_scale() -> None:
    angles = np.stack([np.linspace(0, 40, 11), np.linspace(10, 20, 11)], axis=1)
    lines = trajectory_plot_points(angles, width=2.0, height=1.0)
    assert len(lines) == 2
    assert lines[0].shape == (11, 3)
    assert lines[0][:, 2].max() == pytest.approx(1.0)  # the largest angle reaches the top
    assert lines[1][:, 2].max() == pytest.approx(0.5)  # 20° is half of 0..40°
    assert lines[0][-1, 0] == pytest.approx(2.0)


def test_scene_layout_keeps_the_panels_apart() -> None:
    latents = np.array([[-2.2, 0.5], [1.0, -1.9], [0.3, 0.3]])
    layout = scene_layout(latents)
    assert layout.extent >= 1.25 * 2.2  # every point on the grid, with a margin
    assert layout.response_origin[0] > layout.extent  # the surface stands right of the grid
    assert layout.plan_origin[1] > layout.extent  # the trajectory plot stands behind it
    assert layout.finger_origin[0] < layout.plan_origin[0]  # the finger left of the plot
    camera, target = np.array(layout.camera_position), np.array(layout.camera_look_at)
    assert camera[1] < target[1]  # from the front
    assert camera[2] > target[2]  # from above
    assert scene_layout(None).extent == 2.0


def test_response_grid_matches_predict() -> None:
    model = _model(latent_dim=2)
    grid = response_grid(model, feature=0, action_axis=0, n_latent=5, n_action=7)
    assert grid.mean.shape == (5, 7)
    assert grid.std.shape == (5, 7)
    assert grid.latent_values[0] < model.latents[:, 0].min()
    assert grid.latent_values[-1] > model.latents[:, 0].max()
    i, j = 3, 2
    query_s = model.latents.mean(axis=0).copy()
    query_s[0] = grid.latent_values[i]
    mean, variance = predict(model, query_s[None, :], np.array([[grid.action_values[j]]]))
    assert grid.mean[i, j] == pytest.approx(mean[0, 0], rel=1e-12)
    assert grid.std[i, j] == pytest.approx(np.sqrt(variance[0, 0]), rel=1e-12)
    with pytest.raises(ValueError, match="feature: expected 0 ≤ feature < 3"):
        response_grid(model, feature=3)


def test_response_grid_follows_the_world() -> None:
    """Conditioned on Experiment 1 data, the surface along an object's slice tracks h(θ, x)."""
    model = _model(latent_dim=1)
    grid = response_grid(model, feature=0, n_latent=41, n_action=9, margin=0.0)
    from core.evaluation.worlds import experiment1_h

    errors = []
    for theta in EXPERIMENT1_THETAS:
        i = int(np.argmin(np.abs(grid.latent_values - theta)))
        assert grid.latent_values[i] == pytest.approx(theta, abs=1e-9)  # θ is on the grid
        inside = np.abs(grid.action_values) < 1.5
        truth = experiment1_h(theta, grid.action_values[inside][:, None])[:, 0]
        errors.append(np.abs(grid.mean[i, inside] - truth).max())
    print("max |surface - h| per object:", errors)
    assert max(errors) < 0.15


def test_sse_events_parser() -> None:
    lines = [": keep-alive", "id: 7", "event: trial.step", 'data: {"a": 1}', "", "data: x", ""]
    assert list(sse_events(iter(lines))) == [
        ("7", "trial.step", '{"a": 1}'),
        ("7", "message", "x"),
    ]


# --- the server ------------------------------------------------------------------------------


@pytest.fixture
def view():
    created = ManifoldView(host="127.0.0.1", port=0)
    yield created
    created.close()


def test_view_binds_loopback_and_serves_the_client(view: ManifoldView) -> None:
    assert view.port > 0
    assert view.url == f"http://127.0.0.1:{view.port}"
    with urllib.request.urlopen(view.url, timeout=10) as response:  # viser's web client
        assert response.status == 200
        assert b"<html" in response.read().lower()
    # Not reachable on another interface address of this machine (bound to loopback only).
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.settimeout(1.0)
        try:
            other = socket.gethostbyname(socket.gethostname())
        except OSError:
            pytest.skip("no hostname address to probe")
        if other.startswith("127."):
            return
        assert probe.connect_ex((other, view.port)) != 0


@pytest.mark.parametrize("latent_dim", [1, 2, 3])
def test_view_draws_model_belief_and_plan(view: ManifoldView, latent_dim: int) -> None:
    model = _model(latent_dim)
    view.show_model(model)
    belief = GaussianBelief(mean=np.full(latent_dim, 0.1), cov=0.2 * np.eye(latent_dim))
    path = np.linspace(0.0, 0.1, 3)[:, None] * np.ones(latent_dim)
    view.show_belief(belief, path=path, nearest_object=model.object_names[1])
    angles = np.stack([np.linspace(0, 30, 20), np.linspace(0, -10, 20)], axis=1)
    view.show_plan(angles, timestep_s=0.01)
    view.show_plan(angles[::-1], timestep_s=0.01)  # replaces the running animation
    view.clear_trial()
    with pytest.raises(ValueError, match=r"belief: expected dimension"):
        view.show_belief(GaussianBelief(mean=np.zeros(latent_dim + 1), cov=np.eye(latent_dim + 1)))
    with pytest.raises(ValueError, match="not an object of the model"):
        view.show_belief(belief, nearest_object="no such cup")
    with pytest.raises(ValueError, match=r"angles_deg: expected 2 columns"):
        view.show_plan(angles[:, :1], timestep_s=0.01)
