"""The physics section of ``experiment=arm_reach``: the trained map's motions executed in MuJoCo.

After the kinematic tests, on the same environments (:mod:`protorch.sim`):

* ``physics.test``: every held-out environment (static can and target), the map's label-aware
  mean executed by the inverse-dynamics controller;
* ``physics.dynamic``: the kinematic moving test's episodes replayed (the same can and target at
  every control instant), the map queried and the class chosen every control step from the
  simulated arm's joints, as the kinematic test does from its own.

Each has ``success_rate``, ``contacts`` (episodes with any arm-can or arm-table contact MuJoCo
reported; ``contact_steps``: physics steps with one), ``tracking_rms``, ``max_torque_ratio``,
the failures by name, and the agreement of the kinematic and physics verdicts per episode.
Every executed episode goes into ``<run>/physics/episodes.npz`` (:func:`save_episodes`); with
``plot`` a held-out reach and a moving episode in which the arm switches sides are rendered
(:mod:`protorch.sim.render`, in a subprocess with EGL, else OSMesa; where neither works one line
says so and the metrics are written all the same).

``physics.run``: ``auto`` runs it where MuJoCo is installed and otherwise skips it with one line
naming the extra; ``always`` refuses to start without MuJoCo; ``never`` skips it.
"""

from __future__ import annotations

import dataclasses
import inspect
import io
import time
from pathlib import Path

import numpy as np
import torch

from ..checks import check_number
from ..control.arm import arm_follow, count_switches, run_arm_episodes
from ..control.arm_choice import ArmClassChoice
from ..control.episodes import check_timing
from ..control.physics import FixedMeans, run_physics_episodes, substeps
from ..data.files import atomic_write_bytes
from ..gp.model import label_aware_mean
from ..sim.controller import check_gains
from ..sim.mj import INSTALL_HINT, MujocoMissing, load_mujoco, mujoco_available
from ..sim.render import render_in_subprocess
from ..sim.scene import build_scene, controller_model

__all__ = [
    "PHYSICS_RUN",
    "PHYSICS_DEFAULTS",
    "MujocoMissing",
    "check_physics",
    "skip_reason",
    "physics_section",
    "save_episodes",
]

PHYSICS_RUN = ("auto", "always", "never")
PHYSICS_DEFAULTS = {
    "run": "auto",
    "timestep": 0.002,
    "kp": 400.0,
    "kd": 40.0,
    "mass_scale": 1.0,
    "feasible": True,
    "feasible_scale": 0.9,
    "render": True,
}


def _dynamic_defaults(dyn_cfg: dict) -> dict:
    """The moving test's settings as :func:`~protorch.control.arm.run_arm_episodes` uses them."""
    sig = inspect.signature(run_arm_episodes).parameters
    return {
        k: dyn_cfg.get(k, p.default)
        for k, p in sig.items()
        if p.default is not inspect.Parameter.empty
    }


def check_physics(physics: dict | None, dyn_cfg: dict) -> dict:
    """The ``physics.*`` settings checked (before any work): ``run`` one of :data:`PHYSICS_RUN`
    (``always`` without MuJoCo: one line naming the extra), the control step a whole multiple of
    ``timestep``, gains stable at that timestep, ``mass_scale > 0``, ``feasible`` a bool and
    ``feasible_scale`` in ``(0, 1]`` (the fraction of the torque limits the torque-feasible
    reference keeps the command within,
    :meth:`~protorch.sim.controller.ComputedTorque.feasible_torques`)."""
    cfg = {**PHYSICS_DEFAULTS, **dict(physics or {})}
    unknown = sorted(set(cfg) - set(PHYSICS_DEFAULTS))
    if unknown:
        raise ValueError(
            f"physics.{unknown[0]} is not a physics setting; known: {', '.join(PHYSICS_DEFAULTS)}"
        )
    if cfg["run"] not in PHYSICS_RUN:
        raise ValueError(f"physics.run must be one of {', '.join(PHYSICS_RUN)}, got {cfg['run']!r}")
    if cfg["run"] == "always":
        load_mujoco()
    cfg["timestep"] = check_number(cfg["timestep"], "physics.timestep")
    cfg["mass_scale"] = check_number(cfg["mass_scale"], "physics.mass_scale")
    cfg["kp"], cfg["kd"] = check_gains(cfg["kp"], cfg["kd"], cfg["timestep"])
    substeps(check_number(_dynamic_defaults(dyn_cfg)["dt"], "dynamic.dt"), cfg["timestep"])
    for key in ("render", "feasible"):
        if not isinstance(cfg[key], bool):
            raise ValueError(f"physics.{key} must be true or false, got {cfg[key]!r}")
    cfg["feasible_scale"] = check_number(cfg["feasible_scale"], "physics.feasible_scale")
    if cfg["feasible_scale"] > 1:
        raise ValueError(f"physics.feasible_scale must be in (0, 1], got {cfg['feasible_scale']}")
    return cfg


def skip_reason(cfg: dict) -> str | None:
    """Why the physics section will not run (``None``: it will)."""
    if cfg["run"] == "never":
        return "physics.run=never"
    if not mujoco_available():
        return f"MuJoCo is not installed: {INSTALL_HINT}"
    return None


def save_episodes(
    path: Path, test, dynamic, kin_test: np.ndarray, kin_dynamic: np.ndarray | None, task
) -> Path:
    """Every executed episode into one ``.npz`` (atomic): ``q (E, T+1, J)``, ``qd`` (the measured
    joint velocities), ``tau`` (the torques applied from each instant on, clipped), ``q_ref``,
    ``can``,
    ``target (E, T+1, 2)``, ``contact (E, T+1)``, ``labels (E, T+1)`` (the tracked class; -1 for a
    held-out episode), ``success (E,)``, ``moving (E,)``,
    ``kinematic_success (E,)``, one ``failure_<name> (E,)`` per failure, and ``dt``,
    ``timestep``, ``can_radius``, ``can_height``, ``goal_tol``, ``ee_height`` (the target's height),
    ``margin``, ``collision``."""
    parts = [test] + ([dynamic] if dynamic is not None else [])

    def cat(get):
        return np.concatenate([get(p) for p in parts])

    arrays = {
        name: cat(lambda p, n=name: getattr(p, n))
        for name in ("q", "qd", "tau", "q_ref", "can", "target", "contact")
    }
    labels = [np.full(test.q.shape[:2], -1)] + ([dynamic.labels] if dynamic is not None else [])
    arrays.update(
        labels=np.concatenate(labels),
        success=cat(lambda p: p.success),
        moving=np.concatenate(
            [np.zeros(test.num_episodes, bool)]
            + ([np.ones(dynamic.num_episodes, bool)] if dynamic is not None else [])
        ),
        kinematic_success=np.concatenate(
            [kin_test] + ([kin_dynamic] if dynamic is not None else [])
        ),
    )
    for name in test.failures:
        arrays[f"failure_{name}"] = cat(lambda p, n=name: p.failures[n])
    arrays.update(
        dt=np.float64(test.dt),
        timestep=np.float64(test.timestep),
        can_radius=np.float64(task.can_radius),
        can_height=np.float64(task.can_height),
        goal_tol=np.float64(task.goal_tol),
        ee_height=np.float64(task.ee_height),
        margin=np.float64(task.margin),
        collision=np.str_(task.collision),
    )
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return atomic_write_bytes(path, buf.getvalue())


def _task_kwargs(task) -> dict:
    """The task's settings as JSON (the robot as the settings it was loaded from)."""
    kw = {f.name: getattr(task, f.name) for f in dataclasses.fields(task) if f.init}
    return kw | {"robot": task.robot.settings}


def _picks(test, dynamic) -> dict:
    """The episodes to render: a successful held-out reach whose can is nearest the straight path,
    and a moving episode in which the arm switched sides (a successful one if there is)."""
    out = {}
    ok = np.flatnonzero(test.success)
    if ok.size:
        s, g, c = np.array(test.task.start[:2]), test.target[:, 0], test.can[:, 0]
        u = np.clip(((c - s) * (g - s)).sum(-1) / np.square(g - s).sum(-1), 0, 1)
        off = np.linalg.norm(c - s - u[:, None] * (g - s), axis=-1)
        out["reach"] = int(ok[np.argmin(off[ok])])
    if dynamic is not None and dynamic.labels is not None:
        sw = count_switches(torch.from_numpy(dynamic.labels)).numpy() > 0
        cand = (
            np.flatnonzero(sw & dynamic.success)
            if (sw & dynamic.success).any()
            else np.flatnonzero(sw)
        )
        if cand.size:
            out["switch"] = test.num_episodes + int(cand[0])
    return out


def physics_section(exp, model, out_dir: Path, plot: bool) -> dict:
    """Run the physics tests of the trained ``model`` (module docstring); the metrics' section."""
    cfg = exp.physics_cfg
    reason = skip_reason(cfg)
    if reason is not None:
        print(f"[protorch] physics test skipped: {reason}", flush=True)
        return {"skipped": reason}
    t0 = time.perf_counter()
    task, promp, dyn = exp.task, model.promp, _dynamic_defaults(exp.dyn_cfg)
    scene = build_scene(task, timestep=cfg["timestep"])
    ctrl = controller_model(task, timestep=cfg["timestep"], mass_scale=cfg["mass_scale"])
    timing = check_timing(dyn["dt"], dyn["duration"], dyn["hold"])
    common = dict(
        kp=cfg["kp"],
        kd=cfg["kd"],
        ref_kp=float(dyn["kp"]),
        max_acceleration=task.robot.max_acceleration
        if dyn.get("max_acceleration") is None
        else dyn["max_acceleration"],
        threads=max(1, torch.get_num_threads()),
        feasible=cfg["feasible_scale"] if cfg["feasible"] else None,
    )
    envs = exp.test_envs
    with torch.no_grad():
        best = label_aware_mean(
            model.env_map, promp, task, envs, dtype=promp.basis.dtype, check=True
        )
        kin_test = task.success(promp.trajectory(best.mean), envs).cpu().numpy()
    walk = envs[:, None].expand(-1, timing.total + 1, -1).cpu()
    test = run_physics_episodes(scene, ctrl, FixedMeans(best.mean), promp, timing, walk, **common)
    out = {"test": test.summary(kin_test)}
    kin = getattr(exp, "last_moving", None)
    dynamic, kin_dyn = None, None
    if kin is not None and kin.num_episodes:
        choice = ArmClassChoice(
            task,
            model.env_map,
            promp,
            kin.envs.clone(),
            [[] for _ in range(kin.num_episodes)],
            timing.total,
            place_clearance=float(dyn["place_clearance"]),
            switch_margin=float(dyn["switch_margin"]),
            generator=None,
            reuse_answers=True,
            check=bool(dyn["check"]),
            follow=arm_follow(task, float(dyn["kp"]), common["max_acceleration"], timing),
            switch_clearance=float(dyn["switch_clearance"]),
        )
        dynamic = run_physics_episodes(scene, ctrl, choice, promp, timing, kin.envs.cpu(), **common)
        kin_dyn = kin.success.cpu().numpy()
        sw = count_switches(torch.from_numpy(dynamic.labels))
        out["dynamic"] = {
            **dynamic.summary(kin_dyn),
            "switches": int(sw.sum()),
            "episodes_with_switch": int((sw > 0).sum()),
            "map_queries": choice.queries,
        }
    path = save_episodes(
        Path(out_dir) / "physics" / "episodes.npz", test, dynamic, kin_test, kin_dyn, task
    )
    out["episodes_file"] = str(path.relative_to(out_dir))
    out["settings"] = {
        k: cfg[k] for k in ("timestep", "kp", "kd", "mass_scale", "feasible", "feasible_scale")
    } | {"collision": task.collision}
    out["seconds"] = round(
        time.perf_counter() - t0, 3
    )  # the two tests and the file, not the pictures
    if plot and cfg["render"]:
        t1 = time.perf_counter()
        out["render"] = render_in_subprocess(
            path,
            Path(out_dir) / "physics",
            _task_kwargs(task),
            _picks(test, dynamic),
            timestep=cfg["timestep"],
        )
        out["render_seconds"] = round(time.perf_counter() - t1, 3)
    return out
