"""What the live viewer shows, as plain functions of an environment vector (no browser, no viser).

:func:`open_run` loads a trained ``point_particle`` or ``arm_reach`` run (:func:`protorch.load`)
and rebuilds its task from the run's ``config.yaml``; :func:`scene_state` turns one environment
into what is drawn: the map's mean trajectory, trajectories of weight samples (the spread), the
success check of the mean, its costs and the inference time. The arm uses the label-aware
inference (:func:`protorch.gp.model.label_aware_mean`): the homotopy class whose mean scores
lowest (the summed objectives, as the policy chooses) is chosen and shown. The samples use fixed
standard-normal draws (``eps``), so a small
change of the environment moves every drawn sample a little instead of redrawing them.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import yaml
from safetensors import safe_open
from torch import Tensor

from ..checks import check_tensor
from ..data.checkpoint import checkpoint_path, load
from ..experiments.registry import REGISTRY, for_task
from ..gp.model import EnvToProMP, class_score
from ..tasks.arm.reach import SIDES, ArmReachTask
from ..tasks.point_particle import PointParticleTask

__all__ = [
    "KINDS",
    "MAKE_RUN",
    "Param",
    "SceneState",
    "ViewRun",
    "arm_state",
    "build_task",
    "check_state",
    "find_runs",
    "open_run",
    "particle_state",
    "run_task_name",
    "scene_state",
    "task_params",
    "weight_noise",
]

# the viewer's scene kind of each task whose runs it shows (the experiments' ``scene`` hook)
KINDS = {
    getattr(e.task, "name"): e.scene for e in REGISTRY.values() if e.task is not None and e.scene
}
MAKE_RUN = (
    "python -m protorch experiment=point_particle hydra.run.dir=runs/pp  (or experiment=arm_reach)"
)


@dataclass(frozen=True)
class Param:
    """One environment coordinate: its name and the range its slider and handle allow."""

    name: str
    lo: float
    hi: float
    step: float


@dataclass
class ViewRun:
    """A loaded run: the map, the task, the environment coordinates and a starting environment."""

    run_dir: Path
    model: EnvToProMP
    task: object
    params: list[Param]
    env0: Tensor  # (E,)
    config: dict = field(default_factory=dict)

    @property
    def kind(self) -> str:
        """``"particle"`` or ``"arm"``."""
        return KINDS[self.model.task_name]

    def clamp(self, env) -> Tensor:
        """``env (E,)`` clipped into every coordinate's range (a float64 tensor)."""
        env = check_tensor(torch.as_tensor(env, dtype=torch.float64), "env", ndim=1)
        if env.shape[0] != len(self.params):
            raise ValueError(
                f"env must have {len(self.params)} values {[p.name for p in self.params]}, "
                f"got {env.shape[0]}"
            )
        lo = torch.tensor([p.lo for p in self.params], dtype=torch.float64)
        hi = torch.tensor([p.hi for p in self.params], dtype=torch.float64)
        return torch.maximum(torch.minimum(env, hi), lo)


@dataclass
class SceneState:
    """What one environment looks like (numpy arrays, ready to draw)."""

    env: np.ndarray  # (E,)
    mean: np.ndarray  # (T, 3) the mean path (particle: z = 0; arm: the end effector)
    samples: np.ndarray  # (S, T, 3) paths of weight samples
    success: bool
    costs: dict  # objective name -> cost of the mean
    # the map's answer (mean and variance; the arm: every class scored, then its variance)
    infer_ms: float
    total_ms: float  # inference, trajectories, success and costs
    label: str | None = None  # the arm's chosen side
    scores: dict | None = None  # the arm: side -> summed objectives of its mean
    joints: np.ndarray | None = None  # (T, D) the mean trajectory (the arm: joint angles)
    links: np.ndarray | None = None  # (P, F, 3) the arm's frame origins at a few phases of the mean


# ----------------------------------------------------------------------------- runs
def run_task_name(run_dir: str | Path) -> str | None:
    """The task a run solved, read from its checkpoint's header only; ``None`` if it has none."""
    path = checkpoint_path(run_dir)
    if not path.is_file():
        return None
    try:
        with safe_open(str(path), "pt") as f:
            meta = json.loads((f.metadata() or {}).get("protorch", "{}"))
    except Exception:  # a truncated or foreign file: not a run the viewer can open
        return None
    return meta.get("task_name")


def find_runs(root: str | Path = "runs") -> list[Path]:
    """Run directories under ``root`` (any depth) holding a ``point_particle`` or ``arm_reach``
    checkpoint, newest checkpoint first."""
    root = Path(root)
    if not root.is_dir():
        return []
    found = [p.parent.parent for p in root.rglob("checkpoint/dataset.safetensors")]
    found = [d for d in found if run_task_name(d) in KINDS]
    return sorted(found, key=lambda d: checkpoint_path(d).stat().st_mtime, reverse=True)


def read_config(run_dir: Path) -> dict:
    """The run's ``config.yaml`` as a dict (``{}`` when the run has none)."""
    path = Path(run_dir) / "config.yaml"
    if not path.is_file():
        return {}
    cfg = yaml.safe_load(path.read_text())
    if not isinstance(cfg, dict):
        raise ValueError(f"{path} does not hold a mapping")
    return cfg


def build_task(task_name: str, task_cfg: dict | None = None, robot=None):
    """The task of a run from its ``task.*`` settings (the keys the task class takes; the rest,
    e.g. ``demo_envs``, only shaped the training) and, for the arm, its ``robot.*`` settings
    (:func:`~protorch.robots.load_robot`; ``None``: the Panda)."""
    exp = for_task(task_name)
    if exp is None or exp.task is None or exp.scene is None:
        raise ValueError(
            f"the viewer shows {' and '.join(sorted(KINDS))} runs, this one solved {task_name!r}"
        )
    # the keys the task class takes, as the experiment passes them (the arm normalises its boxes)
    return exp.task(**exp.task_kwargs({"task": dict(task_cfg or {}), "robot": robot}))


def _particle_params(task: PointParticleTask) -> tuple[list[Param], Tensor]:
    start = [Param("start_x", 0.0, 6.5, 0.05), Param("start_y", 0.0, 10.0, 0.05)]
    rest = [
        Param("wall_x", 2.0, 8.0, 0.05),
        Param("hole_y", 1.0, 9.0, 0.05),
        Param("goal_x", 3.5, 10.0, 0.05),
        Param("goal_y", 0.0, 10.0, 0.05),
    ]
    env0 = [1.0, 2.0, 5.0, 6.5, 9.0, 3.0]
    if task.fixed_start is not None:
        return rest, torch.tensor(env0[2:], dtype=torch.float64)
    return start + rest, torch.tensor(env0, dtype=torch.float64)


def _arm_params(task: ArmReachTask, pad: float = 0.08) -> tuple[list[Param], Tensor]:
    (tx0, tx1), (ty0, ty1) = task.table
    params = []
    for name, (b0, b1) in zip(task.env_names, (*task.can_box, *task.goal_box)):
        t0, t1 = (tx0, tx1) if name.endswith("_x") else (ty0, ty1)
        params.append(Param(name, max(t0, b0 - pad), min(t1, b1 + pad), 0.005))
    return params, torch.tensor([0.56, 0.02, 0.70, 0.06], dtype=torch.float64)


def task_params(task) -> tuple[list[Param], Tensor]:
    """The environment coordinates of a ``point_particle`` or ``arm_reach`` task (name, slider
    range, step) and a starting environment ``(E,)``."""
    return (_arm_params if isinstance(task, ArmReachTask) else _particle_params)(task)


def open_run(run_dir: str | Path, *, device=None) -> ViewRun:
    """Load a ``point_particle`` or ``arm_reach`` run for the viewer (float64, ``device``)."""
    run_dir = Path(run_dir)
    if not checkpoint_path(run_dir).is_file():
        raise FileNotFoundError(
            f"{run_dir} holds no checkpoint ({checkpoint_path(run_dir)}); make a run with: "
            f"{MAKE_RUN}"
        )
    model = load(run_dir, device=device)
    if model.task_name not in KINDS:
        raise ValueError(
            f"{run_dir} is a {model.task_name!r} run; the viewer shows {sorted(KINDS)}"
        )
    cfg = read_config(run_dir)
    task = build_task(model.task_name, cfg.get("task"), cfg.get("robot"))
    if device is not None and hasattr(task, "to"):
        task = task.to(device)
    params, env0 = task_params(task)
    if len(params) != model.env_dim:
        raise ValueError(
            f"{run_dir}: the map takes {model.env_dim}-D environments, the task {len(params)}-D"
        )
    return ViewRun(run_dir, model, task, params, env0, cfg)


# ----------------------------------------------------------------------------- states
def weight_noise(num_weights: int, num_samples: int = 16, seed: int = 0) -> Tensor:
    """Fixed standard-normal draws ``(S, N)`` for the drawn samples (float64)."""
    return torch.randn(
        int(num_samples),
        int(num_weights),
        generator=torch.Generator().manual_seed(int(seed)),
        dtype=torch.float64,
    )


def _as_query(run: ViewRun, env) -> Tensor:
    ref = run.model.promp.basis
    return run.clamp(env).to(dtype=ref.dtype, device=ref.device)[None]  # (1, E)


def particle_state(run: ViewRun, env, eps: Tensor, *, check: bool = True) -> SceneState:
    """The point particle's scene for ``env (E,)``: mean and sample paths in the plane ``z = 0``.
    ``check=False`` leaves the success check and the costs out (:func:`check_state` adds them)."""
    t0 = time.perf_counter()
    q = _as_query(run, env)  # (1, E)
    promp = run.model.promp
    with torch.no_grad():
        mu, var = run.model.env_map.predict(q)  # (1, N), (1, N)
        t1 = time.perf_counter()
        w = mu + var.clamp_min(0).sqrt() * eps.to(mu)  # (S, N)
        mean = promp.trajectory(mu)  # (1, T, 2)
        samples = promp.trajectory(w)  # (S, T, 2)
    flat = lambda x: torch.cat([x, torch.zeros_like(x[..., :1])], -1).cpu().numpy()
    state = SceneState(
        env=q[0].cpu().numpy(),
        mean=flat(mean[0]),
        samples=flat(samples),
        success=False,
        costs={},
        infer_ms=1e3 * (t1 - t0),
        total_ms=1e3 * (time.perf_counter() - t0),
        joints=mean[0].cpu().numpy(),
    )
    return check_state(run, state) if check else state


def arm_state(run: ViewRun, env, eps: Tensor, *, check: bool = True, poses: int = 5) -> SceneState:
    """The arm's scene for ``env (4,)``: the label-aware choice of class (the class whose mean
    scores lowest, as :func:`~protorch.gp.model.label_aware_mean`, here with its variance), its
    mean joint trajectory, end-effector path and frame origins at ``poses`` phases (the last one
    the end), and the end-effector paths of weight samples."""
    t0 = time.perf_counter()
    q = _as_query(run, env)  # (1, 4)
    model, task = run.model, run.task
    promp = model.promp
    with torch.no_grad():
        best = model.env_map.predict_best(q, class_score(promp, task), need_var=True)
        t1 = time.perf_counter()
        mu, var = best.mean, best.var  # (1, N), (1, N)
        w = mu + var.clamp_min(0).sqrt() * eps.to(mu)  # (S, N)
        joints = promp.trajectory(mu)[0]  # (T, J)
        pick = torch.linspace(0, joints.shape[0] - 1, int(poses)).round().long()  # (P,)
        links = task.kinematics.link_positions(joints[pick])  # (P, F, 3)
        mean = task.ee_path(joints)  # (T, 3)
        samples = task.ee_path(promp.trajectory(w))  # (S, T, 3)
    label = int(best.label[0])
    scores = {
        SIDES.get(int(c), str(int(c))): float(s) for c, s in zip(best.candidates, best.scores[0])
    }
    state = SceneState(
        env=q[0].cpu().numpy(),
        mean=mean.cpu().numpy(),
        samples=samples.cpu().numpy(),
        success=False,
        costs={},
        infer_ms=1e3 * (t1 - t0),
        total_ms=1e3 * (time.perf_counter() - t0),
        label=SIDES.get(label, str(label)),
        scores=scores,
        joints=joints.cpu().numpy(),
        links=links.cpu().numpy(),
    )
    return check_state(run, state) if check else state


def check_state(run: ViewRun, state: SceneState) -> SceneState:
    """Fill in the success check and the costs of the state's mean (in place; returned)."""
    t0 = time.perf_counter()
    ref = run.model.promp.basis
    q = torch.as_tensor(state.env, dtype=ref.dtype, device=ref.device)[None]  # (1, E)
    traj = torch.as_tensor(state.joints, dtype=ref.dtype, device=ref.device)[None]  # (1, T, D)
    with torch.no_grad():
        state.success = bool(run.task.success(traj, q)[0])
        state.costs = dict(zip(run.task.objective_names, run.task.costs(traj, q)[0].tolist()))
    state.total_ms += 1e3 * (time.perf_counter() - t0)
    return state


def scene_state(run: ViewRun, env, eps: Tensor, *, check: bool = True) -> SceneState:
    """:func:`particle_state` or :func:`arm_state`, by the run's task."""
    return (particle_state if run.kind == "particle" else arm_state)(run, env, eps, check=check)
