"""The teach page's web server: a thin viser edge over :class:`~protorch.view.teach.TeachSession`.

Point particle: the workspace is a drawing board; pressing anywhere on it (or on the particle at
the start) and dragging records the pointer's positions (viser's scene-node drag events, about 20
a second, each the pointer projected onto the board); at release the stroke is resampled,
checked and shown. Arm: the hand carries a transform control; dragging it moves the target of the
arm's inverse kinematics (:class:`~protorch.view.teach_tasks.HandFollower`, the hand pointing
down) and records the joint angles at every update; at release the same. Keep (only if the
checks pass), Keep anyway (a flagged one, marked), Discard; sliders set the environment (locked
while it is half taught), Next environment skips to the next proposal. Drag callbacks are
``async`` so viser runs them in order; every callback only calls the session and redraws.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from . import draw
from .scene import scene_state, task_params, weight_noise
from .teach import TeachSession
from .teach_tasks import HandFollower

__all__ = ["Teacher", "board_point", "teach_markdown"]


def board_point(point, camera) -> np.ndarray:
    """The pointer's point on the board ``z = 0``: viser reports it on the camera-facing plane
    through the grabbed point (the particle's top face is a little above the board), so it is
    moved along the ray from the camera at ``camera (3,)`` down to ``z = 0``: ``(3,)``."""
    p, c = np.asarray(point, dtype=np.float64), np.asarray(camera, dtype=np.float64)
    if c[2] - p[2] <= 1e-9:  # a camera at or below the point: no such ray
        return p
    return c + (p - c) * (c[2] / (c[2] - p[2]))


def teach_markdown(session: TeachSession, map_verdict: str | None = None) -> str:
    """The panel: progress, the demonstration on show and its checks, what to do next."""
    p, teach = session.progress(), session.teach
    lines = [
        f"**Teach {teach.name}** into `{session.folder}`",
        f"environments: **{p['envs_done']} of {p['num_envs']}** done; this one: "
        f"**{p['kept_here']} of {p['per_env']}** kept",
        f"demonstrations kept: {p['kept']} ({p['marked']} marked)",
    ]
    if map_verdict is not None:
        lines.append(f"the map's mean here: **{map_verdict}**")
    shown = session.pending
    if shown is None:
        what = (
            "drag on the board from the start (green) to the goal (red)"
            if teach.kind == "particle"
            else "drag the hand's control from the start to the target (green) around the can"
        )
        lines.append(f"next: {what}")
    else:
        head = f"shown: {shown.raw.shape[0]} samples -> {shown.traj.shape[0]} steps: "
        lines.append(
            head
            + (
                "**OK**"
                if shown.quality.ok
                else "**flagged**: " + "; ".join(shown.quality.messages)
            )
        )
    if p["finished"]:
        lines.append(
            f"target reached: python -m protorch experiment={teach.name} task.demos="
            f"{session.folder}"
        )
    return "\n\n".join(lines)


class Teacher:
    """Serve ``session`` on ``host:port`` (port 0: a free one). ``run`` (a
    :class:`~protorch.view.scene.ViewRun` of the same task) adds the map's mean path and verdict.
    :attr:`strokes` counts the finished drags."""

    def __init__(
        self, session: TeachSession, *, run=None, host: str = "127.0.0.1", port: int = 8080
    ) -> None:
        import viser

        self.session, self.teach, self.run = session, session.teach, run
        self.params, _ = task_params(self.teach.task)
        self.stroke: list = []
        # time.monotonic() of each stroke sample (the csv format writes them)
        self.stroke_times: list = []
        self.ik_error = 0.0
        self.strokes = 0
        self.note = "; ".join(
            session.notes
        )  # shown until the next action: what opening the folder repaired
        self._syncing = False
        self.eps = None if run is None else weight_noise(run.model.promp.num_weights, 1)
        self.server = viser.ViserServer(
            host=host, port=port, label=f"protorch teach: {self.teach.name}", verbose=False
        )
        self.server.gui.configure_theme(show_share_button=False)
        self.server.gui.main_panel.dock_right()  # the panel beside the scene, not over the board
        (self._particle_setup if self.teach.kind == "particle" else self._arm_setup)()
        self._gui_setup()
        self.refresh()

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    # ------------------------------------------------------------------ setup
    def _particle_setup(self) -> None:
        scene, cam = self.server.scene, self.server.initial_camera
        cam.position, cam.look_at, cam.up = (5.0, 5.0, 11.0), (5.0, 5.0, 0.0), (0.0, 1.0, 0.0)
        self.board = scene.add_box(
            "/board",
            (250, 250, 250),
            (10.0, 10.0, 0.02),
            position=(5.0, 5.0, -0.01),
            cast_shadow=False,
            receive_shadow=False,
        )
        scene.add_grid(
            "/workspace",
            10.0,
            10.0,
            position=(5.0, 5.0, 0.001),
            cell_size=1.0,
            section_size=5.0,
            plane_opacity=0.0,
        )
        self.particle = scene.add_cylinder(
            "/teach/particle", 0.2, 0.04, (255, 0, 200), position=(0.0, 0.0, 0.02)
        )
        for node in (self.board, self.particle):
            node.on_drag(self._on_draw)

    def _arm_setup(self) -> None:
        scene, cam, task = self.server.scene, self.server.initial_camera, self.teach.task
        draw.draw_arm_static(scene, task.table, np.asarray(task.start))
        cam.position, cam.look_at, cam.up = (1.0, -0.62, 0.72), (0.66, 0.1, 0.06), (0.0, 0.0, 1.0)
        self.follower = HandFollower(task)
        self.arm_pose = draw.ArmPose(scene)
        self.hand = scene.add_transform_controls(
            "/teach/hand", scale=0.15, disable_rotations=True, depth_test=False
        )
        self.hand.on_update(self._on_hand)
        self._rest_arm()

    def _gui_setup(self) -> None:
        gui = self.server.gui
        self.sliders = []
        with gui.add_folder("Environment"):
            for i, p in enumerate(self.params):
                s = gui.add_slider(p.name, p.lo, p.hi, p.step, float(self.session.env[i]))
                s.on_update(lambda _e: self._on_slider())
                self.sliders.append(s)
            self.next_button = gui.add_button(
                "Next environment", hint="skip to the next proposed environment"
            )
        self.keep_button = gui.add_button("Keep", hint="write the demonstration on show")
        self.insist_button = gui.add_button(
            "Keep anyway", color="red", hint="keep a flagged demonstration (marked)"
        )
        self.discard_button = gui.add_button("Discard", hint="drop the demonstration on show")
        self.info = gui.add_markdown("")
        self.next_button.on_click(lambda _e: self._act(self.session.next_env))
        self.keep_button.on_click(lambda _e: self._act(self.session.keep))
        self.insist_button.on_click(lambda _e: self._act(lambda: self.session.keep(insist=True)))
        self.discard_button.on_click(lambda _e: self._act(self.session.discard))

    # ------------------------------------------------------------------ events
    def _act(self, action) -> None:
        """A button: the session's action, then the arm back at its start, then a redraw."""
        with self.session.lock:
            try:
                action()
                self.note = ""
            except (
                ValueError
            ) as exc:  # a refused action (e.g. a locked environment) is shown, not raised
                self.note = str(exc)
            if self.teach.kind == "arm" and self.session.pending is None:
                self._rest_arm()
            self.refresh()

    def _on_slider(self) -> None:
        if self._syncing:
            return
        env = torch.tensor([float(s.value) for s in self.sliders], dtype=torch.float64)
        self._act(lambda: self.session.set_env(env))

    async def _on_draw(self, event) -> None:
        """A drag on the board (or the particle): record the pointer; at release, show
        the stroke."""
        point = self.teach.clip(board_point(event.end_position, event.client.camera.position))
        with self.session.lock:
            if event.phase == "start":
                self.session.discard()
                self.stroke, self.stroke_times = [point], [time.monotonic()]
                self._draw_paths()
            elif not self.stroke or not torch.equal(self.stroke[-1], point):
                self.stroke.append(point)
                self.stroke_times.append(time.monotonic())
            self.particle.position = (float(point[0]), float(point[1]), 0.02)
            if event.phase == "end":
                self.session.record(torch.stack(self.stroke), times=self.stroke_times)
                self.strokes += 1
                self.stroke = []
                self.refresh()
            else:
                self._draw_stroke()

    async def _on_hand(self, event) -> None:
        """A drag of the hand's control: follow it by IK, record; at release, show the recording."""
        with self.session.lock:
            if event.phase == "start":
                self.session.discard()
                self.stroke, self.ik_error = [self.follower.q.clone()], 0.0
                self.stroke_times = [time.monotonic()]
                self._draw_paths()
            else:
                q, err = self.follower.move(self.hand.position)
                self.stroke.append(q)
                self.stroke_times.append(time.monotonic())
                self.ik_error = max(self.ik_error, err)
                self.arm_pose.update(self.teach.task.kinematics.link_positions(q).cpu().numpy())
            if event.phase == "end":
                self.session.record(
                    torch.stack(self.stroke).cpu(), times=self.stroke_times, ik_error=self.ik_error
                )
                self.strokes += 1
                self.stroke = []
                self.hand.position = tuple(float(v) for v in self.follower.hand)
                self.refresh()
            else:
                self._draw_stroke()

    def _rest_arm(self) -> None:
        self.follower.reset()
        self.arm_pose.update(
            self.teach.task.kinematics.link_positions(self.follower.q).cpu().numpy()
        )
        self.hand.position = tuple(float(v) for v in self.follower.hand)

    # ------------------------------------------------------------------ drawing
    @property
    def _width(self) -> float:
        return 0.08 if self.teach.kind == "particle" else 0.006

    def _draw_stroke(self) -> None:
        stroke = self.teach.path(torch.stack(self.stroke).cpu()) if len(self.stroke) > 1 else None
        draw.draw_stroke(self.server.scene, stroke, width=self._width)

    def _draw_paths(self) -> None:
        s, shown = self.session, self.session.pending
        draw.draw_teach(
            self.server.scene,
            s.kept_paths(),
            None if shown is None else shown.path,
            shown is None or shown.quality.ok,
            width=self._width,
        )
        self._draw_stroke()

    def _draw_env(self) -> str | None:
        scene, s, task = self.server.scene, self.session, self.teach.task
        env = s.env
        if self.teach.kind == "particle":
            draw.draw_particle_env(
                scene, task.wall_rectangles(env).numpy(), env[0:2].numpy(), env[4:6].numpy()
            )
            if s.pending is None and not self.stroke:
                self.particle.position = (float(env[0]), float(env[1]), 0.02)
        else:
            draw.draw_arm_env(
                scene,
                env[:2].numpy(),
                task.goal_point(env).numpy(),
                task.can_radius,
                task.can_height,
            )
        if self.run is None:
            return None
        state = scene_state(self.run, env, self.eps)
        scene.add_line_segments(
            "/teach/map_mean",
            draw.polylines(state.mean),
            (0, 0, 0),
            thickness=0.03 if self.teach.kind == "particle" else 0.003,
        )
        return "SUCCESS" if state.success else "FAILURE"

    def refresh(self) -> None:
        """Redraw everything from the session: environment, sliders, paths, buttons, panel."""
        s = self.session
        with s.lock:
            verdict = self._draw_env()
            self._syncing = True
            try:
                for slider, v in zip(self.sliders, s.env.tolist()):
                    if abs(float(slider.value) - v) > 1e-12:
                        slider.value = v
                    slider.disabled = s.locked
            finally:
                self._syncing = False
            self.next_button.disabled = s.locked
            shown = s.pending
            self.keep_button.disabled = shown is None or not shown.quality.ok
            self.insist_button.disabled = shown is None or shown.quality.ok
            self.discard_button.disabled = shown is None
            self._draw_paths()
            self.info.content = teach_markdown(s, verdict) + (
                f"\n\nnote: {self.note}" if self.note else ""
            )

    def close(self) -> None:
        self.server.stop()
