"""A person at the controls of the beam (``python -m protorch.view teleop RUN``): the session.

:class:`TeleopSession` holds what the page drives, without any web code: the run's task and its
adaptive guide (the maps ``experiment=teleop_window`` wrote), the plan of trials, and one trial at
a time. The page sends the pose the person commands (their *wish*, integrated from the mouse,
keyboard or gamepad) at its own clock ``t`` (s); :meth:`TeleopSession.step` moves the wall by its
schedule, applies the guide of the trial's condition (none, fixed at the first wall pose,
adaptive; :class:`~protorch.control.teleop_guide.MixtureGuide`) and returns the executed pose, the
wall, the guide's mean path and spread at the wall, and the trial's state.

**Study mode** (``study=N``): ``N`` trials per condition in a counterbalanced order (block ``b``
runs the conditions rotated by ``b``: a Latin square over blocks), each with its own wall schedule
(``wall_seed + trial``). Every finished trial appends one row to ``trials.csv`` in ``out`` (the
columns :data:`CSV_COLUMNS`: trial, condition, wall schedule as JSON, success, time in s,
collisions = control steps touching the wall, effort in m s) and writes its raw poses to
``poses_<trial>.csv`` (t, the wish's 7 numbers, the executed 7, the wall's 4), both atomically.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import torch

from ..control.teleop_guide import MixtureGuide
from ..data.files import atomic_write_bytes
from ..experiments.teleop_window import MAP_FILE, VAR_MAP_FILE
from ..gp import load_env_map
from ..primitives.pose import quaternion_distance
from ..primitives.promp import ProMP
from ..tasks.teleop_trials import CONDITIONS, draw_schedules
from ..tasks.teleop_window import TeleopWindowTask
from .scene import read_config

__all__ = ["TeleopSession", "CSV_COLUMNS", "study_order"]

CSV_COLUMNS = ("trial", "condition", "wall_schedule", "success", "time", "collisions", "effort")
_POSE_COLUMNS = (
    ["t"]
    + [f"wish_{k}" for k in "xyz" + "wabc"]
    + [f"pose_{k}" for k in "xyz" + "wabc"]
    + [f"wall_{k}" for k in ("x", "y", "z", "yaw")]
)


def study_order(conditions, n: int) -> list[str]:
    """``n`` blocks of the conditions, block ``b`` rotated by ``b`` (counterbalanced)."""
    c = list(conditions)
    return [c[(b + i) % len(c)] for b in range(n) for i in range(len(c))]


class TeleopSession:
    """The trials of one run's guide (module docstring).

    Args:
        run_dir: a finished ``experiment=teleop_window`` run (its ``config.yaml`` and maps).
        conditions: the conditions offered (study mode: run in a counterbalanced order).
        study: trials per condition in study mode; 0: free mode (any condition, any number).
        out: where ``trials.csv`` and the raw poses go (default ``RUN/study``).
        time_limit: s a trial may last.
    """

    def __init__(
        self,
        run_dir,
        *,
        conditions=CONDITIONS,
        study: int = 0,
        out=None,
        time_limit: float = 30.0,
        wall_seed: int | None = None,
    ) -> None:
        run_dir = Path(run_dir)
        bad = [c for c in conditions if c not in CONDITIONS]
        if bad or not conditions:
            raise ValueError(
                f"unknown condition {bad[0] if bad else '(none)'!r}; choose from "
                f"{', '.join(CONDITIONS)}"
            )
        for f in (MAP_FILE, VAR_MAP_FILE):
            if not (run_dir / f).is_file():
                raise FileNotFoundError(
                    f"{run_dir / f} is missing: give a finished experiment=teleop_window run"
                )
        cfg = read_config(run_dir)
        settings = dict(cfg.get("settings") or {})
        task_cfg = {
            k: tuple(v) if isinstance(v, list) else v
            for k, v in dict(cfg.get("task") or {}).items()
            if k != "_target_"
        }
        self.task = TeleopWindowTask(**task_cfg)
        pcfg = dict(settings.get("promp") or {})
        self.promp = ProMP(7, int(pcfg.get("num_basis", 10)), int(pcfg.get("num_steps", 100)))
        start, end = self.task.endpoint_poses()
        self.start_pose, self.end_pose = start, end
        self.guide = MixtureGuide(
            self.promp,
            load_env_map(run_dir / MAP_FILE),
            load_env_map(run_dir / VAR_MAP_FILE),
            [0, 1],
            end[:3] - start[:3],
            **dict(settings.get("guide") or {}),
        )
        tele = dict(settings.get("teleop") or {})
        self.wall_cfg = dict(tele.get("wall") or {})
        self.wall_seed = int(tele.get("wall_seed", 0) if wall_seed is None else wall_seed)
        self.conditions = list(conditions)
        self.plan = study_order(self.conditions, int(study)) if study else []
        self.out = Path(out) if out is not None else run_dir / "study"
        self.time_limit = float(time_limit)
        self.trials_done = 0
        self.trial: dict | None = None

    # ------------------------------------------------------------------ the page's calls
    def geometry(self) -> dict:
        """What the page draws that never changes: the window, wall, beam, start and end."""
        t = self.task
        return {
            "window_width": t.window_width,
            "window_height": t.window_height,
            "wall_thickness": t.wall_thickness,
            "beam_length": t.beam_length,
            "beam_radius": t.beam_radius,
            "start": self.start_pose.tolist(),
            "end": self.end_pose.tolist(),
            "conditions": self.conditions,
            "study": len(self.plan),
            "trials_done": self.trials_done,
            "time_limit": self.time_limit,
        }

    def start(self, condition: str | None = None) -> dict:
        """Begin the next trial: the study plan's, or ``condition`` in free mode."""
        if self.plan:
            if self.trials_done >= len(self.plan):
                raise ValueError(f"the study's {len(self.plan)} trials are done")
            condition = self.plan[self.trials_done]
        condition = condition or self.conditions[-1]
        if condition not in self.conditions:
            raise ValueError(
                f"unknown condition {condition!r}; choose from {', '.join(self.conditions)}"
            )
        walls = draw_schedules(self.task, 1, self.wall_seed + self.trials_done, **self.wall_cfg)
        self.trial = {
            "index": self.trials_done,
            "condition": condition,
            "walls": walls,
            "env0": walls.at(0.0),
            "state": self.guide.start(1),
            "pose": self.start_pose[None].clone(),
            "t": 0.0,
            "effort": 0.0,
            "touches": 0,
            "done": False,
            "success": None,
            "time": None,
            "rows": [],
        }
        return {
            "trial": self.trials_done,
            "condition": condition,
            **self._view(self.start_pose[None]),
        }

    def step(self, wish, t: float) -> dict:
        """The executed pose for the commanded ``wish (7,)`` at the page's time ``t`` (s)."""
        tr = self.trial
        if tr is None or tr["done"]:
            raise ValueError("no trial running: start one")
        w = torch.as_tensor(wish, dtype=torch.float64).reshape(1, 7)
        if not bool(torch.isfinite(w).all()) or float(w[0, 3:].norm()) < 1e-8:
            raise ValueError(
                "the commanded pose must be 7 finite numbers with a non-zero quaternion"
            )
        w = torch.cat([w[:, :3], w[:, 3:] / w[:, 3:].norm()], -1)
        t = max(float(t), tr["t"])
        dt = max(t - tr["t"], 1e-3)
        env = tr["walls"].at(t)  # (1, 4)
        if tr["condition"] == "none":
            x = w
        else:
            cond_env = env if tr["condition"] == "adaptive" else tr["env0"]
            x, tr["state"], _ = self.guide.step(tr["state"], w, cond_env, dt)
        touch = bool(self.task.collides_at(x, env)[0])
        tr["touches"] += int(touch)
        gap = float(
            (w[0, :3] - x[0, :3]).norm()
            + 0.5 * self.task.beam_length * quaternion_distance(w[0, 3:], x[0, 3:])
        )
        tr["effort"] += gap * dt
        tr["pose"], tr["t"] = x, t
        tr["rows"].append([t, *w[0].tolist(), *x[0].tolist(), *env[0].tolist()])
        arrived = bool(self.task.at_pose(x[0], self.end_pose))
        if arrived or t >= self.time_limit:
            tr.update(done=True, success=arrived and tr["touches"] == 0, time=t)
            self._record()
        return self._view(x, env, touch)

    # ------------------------------------------------------------------ helpers
    def _view(self, x, env=None, touch: bool = False) -> dict:
        tr = self.trial
        env = tr["walls"].at(tr["t"]) if env is None else env
        cond_env = tr["env0"] if tr["condition"] == "fixed" else env
        out = {
            "pose": x[0].tolist(),
            "wall": env[0].tolist(),
            "t": tr["t"],
            "touch": touch,
            "touches": tr["touches"],
            "effort": tr["effort"],
            "done": tr["done"],
            "success": tr["success"],
            "condition": tr["condition"],
            "trial": tr["index"],
        }
        if tr["condition"] != "none":
            mu, std = self.guide.infer(cond_env)  # (1, K, T, 7)
            b = tr["state"].belief[0]
            k = int(b.argmax())
            out["guide"] = {
                "mean": mu[0, k, :, :3].tolist(),
                "std": std[0, k, :, :3].norm(dim=-1).tolist(),
                "belief": b.tolist(),
                "phase": float(tr["state"].z[0, k]) / (mu.shape[2] - 1),
            }
        return out

    def _record(self) -> None:
        """Append the finished trial's CSV row and write its raw poses (atomically)."""
        tr = self.trial
        self.trials_done += 1
        self.out.mkdir(parents=True, exist_ok=True)
        path = self.out / "trials.csv"
        old = path.read_text() if path.is_file() else ""
        buf = io.StringIO()
        writer = csv.writer(buf)
        if not old:
            writer.writerow(CSV_COLUMNS)
        writer.writerow(
            [
                tr["index"],
                tr["condition"],
                json.dumps(tr["walls"].rows()[0]),
                int(bool(tr["success"])),
                f"{tr['time']:.3f}",
                tr["touches"],
                f"{tr['effort']:.5f}",
            ]
        )
        atomic_write_bytes(path, (old + buf.getvalue()).encode())
        raw = io.StringIO()
        w = csv.writer(raw)
        w.writerow(_POSE_COLUMNS)
        w.writerows([[f"{v:.6g}" for v in row] for row in tr["rows"]])
        atomic_write_bytes(self.out / f"poses_{tr['index']:03d}.csv", raw.getvalue().encode())
