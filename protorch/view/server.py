"""The viewer's web server: a thin viser edge over :mod:`protorch.view.scene`.

:class:`Viewer` serves one run: a slider per environment coordinate and a drag handle per object
(point particle: start, goal and the hole, which carries the wall; arm: the can and the target).
Every change re-infers the map's mean and variance at the new environment and redraws the mean
path and the sample paths at once, then checks the mean (success, costs) and updates the info
panel. The play button runs the moving-environment controller (:mod:`protorch.view.live`) in real
time against whatever environment the person drags to. viser is imported here only, lazily, so
the rest of protorch does not need it (``pip install -e ".[view]"``).
"""

from __future__ import annotations

import threading
import time

import numpy as np
import torch

from . import draw
from .live import make_player
from .scene import SceneState, ViewRun, check_state, scene_state, weight_noise

__all__ = ["Viewer", "info_markdown"]


def info_markdown(run: ViewRun, state: SceneState, player=None) -> str:
    """The info panel: inference time, the mean's success check and costs, the arm's side."""
    verdict = "SUCCESS" if state.success else "FAILURE"
    costs = ", ".join(f"{k} {v:.3f}" for k, v in state.costs.items())
    lines = [
        f"**{run.model.task_name}** ({run.model.env_map.num_points} map entries)",
        f"inference: {state.infer_ms:.1f} ms; whole scene: {state.total_ms:.1f} ms",
        f"mean trajectory: **{verdict}**",
        f"costs: {costs}",
    ]
    if state.label is not None:
        scores = ", ".join(f"{k} {v:.3f}" for k, v in (state.scores or {}).items())
        lines.append(f"side: **{state.label}** (summed objectives: {scores})")
    if player is not None and player.started:
        t = player.t * player.dt
        extra = (
            f", side {player.label}, switches {player.switches}"
            if hasattr(player, "switches")
            else ""
        )
        result = (
            "running" if player.success is None else ("SUCCESS" if player.success else "FAILURE")
        )
        lines.append(f"live: t = {t:.2f} s{extra}: {result}")
    return "\n\n".join(lines)


class Viewer:
    """Serve ``run`` on ``host:port`` (port 0: a free one). ``num_samples`` sample paths are drawn
    (fixed draws, ``seed``). :attr:`state` is the last state drawn; :attr:`redraws` counts them."""

    def __init__(
        self,
        run: ViewRun,
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        num_samples: int = 16,
        seed: int = 0,
    ) -> None:
        import viser

        self.run = run
        self.eps = weight_noise(run.model.promp.num_weights, num_samples, seed)  # (S, N)
        self.env = run.env0.clone()  # (E,)
        self.lock = threading.RLock()
        self.state: SceneState | None = None
        self.redraws = 0
        self.timings: dict = {}
        self.player = make_player(run)
        self._syncing = False
        self._thread: threading.Thread | None = None
        self._playing = False
        self.server = viser.ViserServer(
            host=host, port=port, label=f"protorch view: {run.model.task_name}", verbose=False
        )
        self._scene_setup()
        self._gui_setup()
        scene_state(run, self.env, self.eps)  # warm-up: the first answer pays one-off costs
        self.redraw()

    # ------------------------------------------------------------------ setup
    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    def _scene_setup(self) -> None:
        scene, cam = self.server.scene, self.server.initial_camera
        if self.run.kind == "particle":
            draw.draw_particle_static(scene)
            cam.position, cam.look_at, cam.up = (5.0, 5.0, 11.0), (5.0, 5.0, 0.0), (0.0, 1.0, 0.0)
            handles = {"start": (0, 1), "goal": (4, 5), "hole (moves the wall)": (2, 3)}
            if self.run.task.fixed_start is not None:
                handles = {k: (a - 2, b - 2) for k, (a, b) in handles.items() if k != "start"}
            scale = 1.2
        else:
            task = self.run.task
            draw.draw_arm_static(scene, task.table, np.asarray(task.start))
            cam.position, cam.look_at, cam.up = (1.05, -0.7, 0.6), (0.5, 0.0, 0.12), (0.0, 0.0, 1.0)
            handles, scale = {"can": (0, 1), "target": (2, 3)}, 0.15
            self.arm_pose = draw.ArmPose(scene)
        self.handles = {}
        for name, cols in handles.items():
            h = scene.add_transform_controls(
                f"/handles/{name.split()[0]}",
                scale=scale,
                active_axes=(True, True, False),
                disable_rotations=True,
                depth_test=False,
            )
            h.on_update(lambda event, cols=cols: self._on_handle(event.target, cols))
            self.handles[cols] = h

    def _gui_setup(self) -> None:
        gui = self.server.gui
        self.sliders = []
        with gui.add_folder("Environment"):
            for i, p in enumerate(self.run.params):
                s = gui.add_slider(p.name, p.lo, p.hi, p.step, float(self.env[i]))
                s.on_update(lambda _e, i=i: self._on_slider(i))
                self.sliders.append(s)
        self.play_button = gui.add_button(
            "Play", hint="run the moving-environment controller live; keep dragging"
        )
        self.play_button.on_click(lambda _e: self.toggle_play())
        self.info = gui.add_markdown("")

    # ------------------------------------------------------------------ events
    def _on_slider(self, i: int) -> None:
        if self._syncing:
            return
        env = self.env.clone()
        env[i] = float(self.sliders[i].value)
        self.set_env(env)

    def _on_handle(self, handle, cols) -> None:
        if self._syncing:
            return
        env = self.env.clone()
        env[list(cols)] = torch.tensor(
            [float(handle.position[0]), float(handle.position[1])], dtype=env.dtype
        )
        self.set_env(env, dragged=cols)

    def set_env(self, env, *, dragged=None) -> SceneState:
        """Move to ``env (E,)`` (clipped to the ranges), sync the sliders and handles, redraw."""
        t0 = time.perf_counter()
        with self.lock:
            self.env = self.run.clamp(env)
            self._syncing = True
            try:
                for s, v in zip(self.sliders, self.env.tolist()):
                    if abs(float(s.value) - v) > 1e-12:
                        s.value = v
                for cols, h in self.handles.items():
                    if cols != dragged:
                        h.position = self._handle_position(cols)
            finally:
                self._syncing = False
            return self.redraw(t0)

    def _handle_position(self, cols) -> tuple[float, float, float]:
        z = 0.0 if self.run.kind == "particle" else self.run.task.ee_height
        return float(self.env[cols[0]]), float(self.env[cols[1]]), z

    # ------------------------------------------------------------------ drawing
    def redraw(self, t0: float | None = None) -> SceneState:
        """Infer at the current environment, send the mean and sample paths, then the check.
        :attr:`timings` holds the milliseconds from ``t0`` (default: now) to the state, to the
        paths sent and to the info panel sent."""
        t0 = time.perf_counter() if t0 is None else t0
        with self.lock:
            state = scene_state(self.run, self.env, self.eps, check=False)
            t1 = time.perf_counter()
            self.send_paths(state)
            t2 = time.perf_counter()
            check_state(self.run, state)
            self.state = state
            self.redraws += 1
            self.info.content = info_markdown(self.run, state, self.player)
            t3 = time.perf_counter()
            self.timings = {
                "state_ms": 1e3 * (t1 - t0),
                "sent_ms": 1e3 * (t2 - t0),
                "info_ms": 1e3 * (t3 - t0),
            }
            return state

    def send_paths(self, state: SceneState) -> None:
        """The environment's objects, the mean and the sample paths (and the arm at the mean)."""
        scene, run = self.server.scene, self.run
        if run.kind == "particle":
            env6 = run.task.full_env(torch.as_tensor(state.env))
            rects = run.task.wall_rectangles(env6).numpy()
            draw.draw_particle_env(scene, rects, env6[0:2].numpy(), env6[4:6].numpy())
            draw.draw_paths(scene, state.mean, state.samples, width=0.08)
        else:
            task = run.task
            e = torch.as_tensor(state.env)
            draw.draw_arm_env(
                scene, state.env[:2], task.goal_point(e).numpy(), task.can_radius, task.can_height
            )
            draw.draw_paths(
                scene, state.mean, state.samples, width=0.01, color=draw.SIDE_COLORS[state.label]
            )
            draw.draw_arm_ghosts(scene, state.links[:-1])
            if not self._playing:
                self.arm_pose.update(state.links[-1])
        if self.redraws == 0:
            for cols, h in self.handles.items():
                h.position = self._handle_position(cols)

    # ------------------------------------------------------------------ live controller
    def toggle_play(self) -> None:
        """Start the live controller from the start (or stop it)."""
        if self._playing:
            self._playing = False
            return
        with self.lock:
            self.player.reset(self.env)
        self._playing = True
        self.play_button.label = "Stop"
        self._thread = threading.Thread(target=self._play_loop, daemon=True)
        self._thread.start()

    def _play_loop(self) -> None:
        p, scene = self.player, self.server.scene
        next_t = time.perf_counter()
        while self._playing and not p.done:
            with self.lock:
                out = p.step(self.env).cpu()
                trace = p.trace()
                if self.run.kind == "particle":
                    draw.draw_trace(scene, trace, trace[-1], radius=0.15)
                else:
                    links = self.run.task.kinematics.link_positions(out).numpy()
                    self.arm_pose.update(links)
                    draw.draw_trace(scene, trace, trace[-1], radius=0.02)
                if p.t % 5 == 0 or p.done:
                    self.info.content = info_markdown(self.run, self.state, p)
            next_t += p.dt
            time.sleep(max(0.0, next_t - time.perf_counter()))
        self._playing = False
        self.play_button.label = "Play"

    def wait_play(self, timeout: float = 30.0) -> None:
        """Block until the live controller has finished (tests, scripts)."""
        if self._thread is not None:
            self._thread.join(timeout)

    def close(self) -> None:
        self._playing = False
        self.wait_play(5.0)
        self.server.stop()
