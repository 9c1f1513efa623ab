"""The live 3D view of a recognition trial, served by viser (docs/architecture.md, "The 3D view").

:class:`ManifoldView`, a viser server that draws a model and a trial and is updated by its
caller::

    view = ManifoldView(host="127.0.0.1", port=8081)   # loopback by default
    view.show_model(model)                  # latent points, labels, GP response surface
    view.show_belief(belief, path=means, nearest_object="O2")   # after every step
    view.show_plan(angles_deg, timestep_s=0.01)                 # next planned touch
    view.clear_trial()                      # a new trial starts
    view.close()

The dashboard embeds it in an ``<iframe>`` pointing at :attr:`ManifoldView.url`.

What it draws is computed in :mod:`app.viz.geometry` (pure functions, unit-tested without a
server): where the latent points go in 3D, the outline of a Gaussian belief (interval, ellipse,
ellipsoid), the learned GP response over (s, x) as a surface mesh, the finger's pose for two joint
angles. :class:`~app.viz.follower.TrialFollower` in :mod:`app.viz.follower` keeps a view in step
with the web app through its REST API and event stream alone, so the view works beside any server,
in-process or not.

Scene layout (z up): the manifold at the origin (latent dims 1–3 on x, y, z); the GP response
surface to the right (+x); the planned joint trajectories and the animated finger behind (+y).
"""

from __future__ import annotations

import contextlib
import io
import threading
from collections.abc import Sequence
from typing import Any

import numpy as np

from app.viz.geometry import (
    BELIEF_COLOR,
    HIGHLIGHT_COLOR,
    PALETTE,
    PLAN_HEIGHT,
    PLAN_WIDTH,
    RESPONSE_HEIGHT,
    RESPONSE_SIZE,
    FloatArray,
    ResponseGrid,
    SceneLayout,
    check_n_sigma,
    ellipse_points,
    ellipsoid_mesh,
    embed_latents,
    finger_points,
    interval_bounds,
    object_color,
    polyline_segments,
    response_grid,
    scale_to_box,
    scene_layout,
    surface_mesh,
    trajectory_plot_points,
)
from core.types import GaussianBelief, ManifoldModel
from core.validation import as_float_array


class ManifoldView:
    """A viser server showing a model's manifold and, live, a trial's belief and plan.

    Thread-safe: the methods may be called from any thread (a trial runner, an event follower).

    Args:
        host: Address to bind; loopback by default (docs/security.md).
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
        import viser  # imported here: importing this module must not need a server

        check_n_sigma(n_sigma)
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
