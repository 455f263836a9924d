"""The GP map plus the self-improvement loop on fancy_gym's box pushing, over the box's goal pose.

Set up once (its own venv; fancy_gym pins mujoco 2.3.3): ``bash
benchmarks/studies/external/setup.sh``, then

    benchmarks/studies/external/.venv/bin/python benchmarks/studies/external/loop.py --smoke
    benchmarks/studies/external/.venv/bin/python benchmarks/studies/external/loop.py \\
        --train 20 --heldout 30 --max-iter 30 --json
        benchmarks/studies/results/external/loop/box_goal_loop.json

The task (:class:`BoxGoalTask`) is a task of the user's-own-task kind (docs/your_own_task.md):
the environment vector is the goal pose ``(x, y, yaw)`` of ``fancy_ProMP/BoxPushingDense-v0``,
scaled to the unit cube of the chosen ranges; its ``costs`` and ``success`` come from executed
episodes (``env.reset(seed=0)``, the goal set with :func:`tasks.set_box_goal`, one black-box step
with the 35 ProMP weights: fancy_gym's own ProMP and tracking controller run the episode). The
loop's ProMP is the identity: 7 DoF x 5 basis functions on 5 phases with a basis width of
``1e-3``, whose normalised basis matrix is exactly ``I``, so the "trajectory" ``(5, 7)`` the loop
hands to the task is the weight vector laid out, and :meth:`BoxGoalTask.weights` reads it back
bit for bit. The cost is ``-return`` (one objective; every step's dense reward is negative), the
success fancy_gym's ``is_success`` at the last step (box within 5 cm and 0.5 rad of its goal).

An episode is deterministic (the box starts at the same pose, the arm in the same
configuration), so the task caches outcomes by (weights, goal): the loop asks for the same mean's
success and cost several times (the start's check, the ``solved`` check, the acceptance) and
each is one episode. ``task.episodes`` counts the episodes of training poses,
``task.heldout_episodes`` those of held-out poses (the map's mean checked after every step).

The loop (:func:`protorch.loop.self_improve`): the initial data set is one prior entry,
``N(0, start_std^2 I)`` at the centre of the pose ranges (no demonstrations: the same start as
the per-context runs of run.py); ``--train`` goal poses drawn uniformly (seed ``--seed``),
tried one at a time (``B = 1``, the paper's sequential loop): the GP map predicts each pose's
weight Gaussian (floored at ``--min-var``), the optimiser (``--optimizer``, CMA-ES by default,
``--samples`` an iteration, at most ``--max-iter`` iterations) improves it until its mean
succeeds (``solved``: checked before the first and after every iteration) or its budget ends, and
the optimised mean joins the map (``--add-only``, default ``all``: a pose not yet solved still
moves the map toward it; its variance floored by ``--var-floor``). ``--heldout`` other poses
(seed ``--seed + 1``) are the test: after every step the map's mean is executed once per pose.

Results: ``--json``, written atomically after every step of the loop: ``meta`` (command, commit,
versions, settings), ``rows`` (the loop's metrics per step, with the episodes spent so far), and at
the end ``heldout`` (per pose: the pose, the map mean's return, success and the box's final
distance / rotation to its goal) and ``train`` (the same per training pose, from the final
solutions).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import json
import math
import shlex
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

sys.path.insert(0, str(Path(__file__).resolve().parent))

from protorch.data.files import atomic_write_bytes

NUM_DOF, NUM_BASIS = (
    7,
    5,
)  # fancy_gym's box-pushing ProMP: 7 joints x 5 basis functions = 35 weights
# the goal poses: the box starts at (0.4, 0.3) with yaw pi (fancy_gym's box_init_pos quaternion (0,
# 0, 0, 1))
X_RANGE, Y_RANGE, YAW_RANGE = (0.35, 0.55), (-0.35, -0.05), (0.75 * math.pi, 1.25 * math.pi)


def identity_promp(dtype: torch.dtype = torch.float64):
    """A protorch ProMP whose trajectory is its weights: ``(..., 35) -> (..., 5, 7)``,
    basis ``I``."""
    from protorch import ProMP

    promp = ProMP(NUM_DOF, NUM_BASIS, NUM_BASIS, width=1e-3, dtype=dtype)
    if not torch.equal(promp.basis, torch.eye(NUM_BASIS, dtype=dtype)):
        raise RuntimeError("the identity ProMP's basis is not exactly I")
    return promp


class BoxGoalTask:
    """Box pushing with the goal pose as the environment: a
    :class:`protorch.tasks.SelfImprovementTask`.

    Args:
        episode: ``(weights (S, 35) float64, goals (S, 3) = (x, y, yaw)) -> S outcomes`` with
            ``.ret``, ``.success``, ``.pos_dist``, ``.rot_dist`` (default: fancy_gym's episodes,
            :class:`tasks.Episodes`, made on first use; ``workers`` processes).
        x_range, y_range, yaw_range: the goal poses, ``env in [0, 1]^3`` maps onto them linearly.
    """

    name = "box_pushing_goal"
    num_dof = NUM_DOF
    env_dim = 3

    def __init__(
        self,
        episode: Callable | None = None,
        *,
        x_range=X_RANGE,
        y_range=Y_RANGE,
        yaw_range=YAW_RANGE,
        workers: int = 1,
    ) -> None:
        self.lo = np.array([x_range[0], y_range[0], yaw_range[0]], dtype=np.float64)  # (3,)
        self.hi = np.array([x_range[1], y_range[1], yaw_range[1]], dtype=np.float64)  # (3,)
        if not np.all(self.hi >= self.lo):
            raise ValueError(
                f"each range must be (low, high) with low <= high, got {x_range}, {y_range}, "
                f"{yaw_range}"
            )
        self._episode, self.workers = episode, int(workers)
        self.cache: dict[bytes, object] = {}
        self.heldout: set[bytes] = set()  # env keys whose episodes count as held-out checks
        self.episodes = 0  # episodes on training poses (optimiser samples and mean checks)
        self.heldout_episodes = 0

    # ---------------------------------------------------------------- poses
    def pose(self, env: Tensor) -> np.ndarray:
        """``env (..., 3)`` in the unit cube -> goal poses ``(..., 3) = (x, y, yaw)``."""
        e = np.asarray(
            env.detach().cpu().double().numpy() if isinstance(env, Tensor) else env,
            dtype=np.float64,
        )
        return self.lo + e * (self.hi - self.lo)

    def sample_envs(
        self, n: int, generator: torch.Generator, dtype: torch.dtype = torch.float64
    ) -> Tensor:
        """``n`` goal poses drawn uniformly in the ranges, as unit-cube vectors ``(n, 3)``."""
        return torch.rand(n, 3, generator=generator, dtype=torch.float64).to(dtype)

    def mark_heldout(self, env: Tensor) -> None:
        """Count later episodes at ``env (Q, 3)`` as held-out checks, not training episodes."""
        for row in env.detach().cpu().double().numpy():
            self.heldout.add(row.tobytes())

    # ---------------------------------------------------------------- episodes
    @staticmethod
    def weights(traj: Tensor) -> Tensor:
        """The identity ProMP's trajectories ``(..., 5, 7)`` -> its weights ``(..., 35)``
        (DoF-major)."""
        if traj.shape[-2:] != (NUM_BASIS, NUM_DOF):
            raise ValueError(
                f"trajectories must be (..., {NUM_BASIS}, {NUM_DOF}) (identity_promp), "
                f"got {tuple(traj.shape)}"
            )
        return traj.transpose(-1, -2).flatten(-2)

    def outcomes(self, traj: Tensor, env: Tensor) -> list:
        """Outcomes of ``traj (..., 5, 7)`` in ``env (..., 3)`` (broadcast), flattened over ``...``;
        each distinct (weights, goal) pair runs one episode, the rest come from the cache."""
        w = self.weights(traj)  # (..., 35)
        batch = torch.broadcast_shapes(w.shape[:-1], env.shape[:-1])
        w = (
            w.expand(*batch, w.shape[-1]).reshape(-1, w.shape[-1]).detach().cpu().double().numpy()
        )  # (M, 35)
        e = (
            env.expand(*batch, env.shape[-1])
            .reshape(-1, env.shape[-1])
            .detach()
            .cpu()
            .double()
            .numpy()
        )  # (M, 3)
        keys = [wi.tobytes() + ei.tobytes() for wi, ei in zip(w, e)]
        todo = sorted({k: i for i, k in enumerate(keys) if k not in self.cache}.values())
        if todo:
            if self._episode is None:
                from tasks import Episodes

                ep = Episodes("box_pushing", self.workers)
                self._episode = lambda ws, gs: ep(ws, 0, gs)
            outs = self._episode(w[todo], self.pose(e[todo]))
            if len(outs) != len(todo):
                raise ValueError(
                    f"the episode function returned {len(outs)} outcomes for {len(todo)} episodes"
                )
            for i, o in zip(todo, outs):
                self.cache[keys[i]] = o
                if e[i].tobytes() in self.heldout:
                    self.heldout_episodes += 1
                else:
                    self.episodes += 1
        return [self.cache[k] for k in keys]

    def costs(self, traj: Tensor, env: Tensor) -> Tensor:
        """``-return`` of each episode: ``(..., 1)``, >= 0."""
        out = self.outcomes(traj, env)
        shape = torch.broadcast_shapes(traj.shape[:-2], env.shape[:-1])
        ret = torch.tensor([o.ret for o in out], dtype=traj.dtype, device=traj.device)
        return (-ret).clamp_min(0.0).reshape(*shape, 1)

    def success(self, traj: Tensor, env: Tensor) -> Tensor:
        """fancy_gym's ``is_success`` at the episode's last step: ``(...)`` bool."""
        out = self.outcomes(traj, env)
        shape = torch.broadcast_shapes(traj.shape[:-2], env.shape[:-1])
        return torch.tensor([bool(o.success) for o in out], device=traj.device).reshape(shape)

    def demonstrations(self, num_envs: int, per_env: int, generator: torch.Generator):
        raise NotImplementedError(
            "box pushing has no demonstrations here: the loop starts from a prior entry"
        )


def prior_dataset(task: BoxGoalTask, promp, start_std: float):
    """The initial data set: one prior entry ``N(0, start_std^2 I)`` at the centre of the ranges."""
    from protorch.data.dataset import TrajectoryDataset

    n = promp.num_weights
    ds = TrajectoryDataset(promp, task.env_dim, task_name=task.name, dtype=torch.float64)
    ds.append(
        torch.full((task.env_dim,), 0.5, dtype=torch.float64),
        torch.zeros(n, dtype=torch.float64),
        torch.full((n,), float(start_std) ** 2, dtype=torch.float64),
        origin="prior",
    )
    return ds


def describe(task: BoxGoalTask, promp, mean: Tensor, env: Tensor) -> list[dict]:
    """Per pose: the pose, and the return, success and box distances of ``mean (P, 35)`` at ``env
    (P, 3)``."""
    outs = task.outcomes(promp.trajectory(mean.to(promp.basis.dtype)), env.to(promp.basis.dtype))
    poses = task.pose(env)
    return [
        {
            "x": float(p[0]),
            "y": float(p[1]),
            "yaw": float(p[2]),
            "return": o.ret,
            "success": bool(o.success),
            "pos_dist": o.pos_dist,
            "rot_dist": o.rot_dist,
        }
        for p, o in zip(poses, outs)
    ]


def summarise(rows: list[dict]) -> dict:
    if not rows:
        return {}
    med = lambda k: float(np.median([r[k] for r in rows]))  # noqa: E731
    return {
        "poses": len(rows),
        "success": sum(r["success"] for r in rows),
        "median_return": med("return"),
        "median_pos_dist": med("pos_dist"),
        "median_rot_dist": med("rot_dist"),
    }


def floats(text: str) -> tuple[float, float]:
    """``"LO,HI"`` -> ``(LO, HI)`` with ``LO <= HI``."""
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LO,HI (two numbers), got {text!r}") from None
    if not lo <= hi:
        raise argparse.ArgumentTypeError(f"expected LO <= HI, got {text!r}")
    return lo, hi


def fmt_ranges(r: dict) -> str:
    return ", ".join(f"{k} [{r[k][0]:.3g}, {r[k][1]:.3g}]" for k in ("x", "y", "yaw"))


def report(path: str) -> str:
    """The markdown table of docs/external.md from a results file (no fancy_gym needed)."""
    out = json.loads(Path(path).read_text())
    s, rows, st = out.get("summary", {}), out["rows"], out["meta"]["settings"]
    h, t = s.get("heldout", {}), s.get("train", {})
    started = sum(r.get("initial_success", 0) for r in rows[1:])
    curve = ", ".join(
        f"{r['envs_done']}: {r['eval_success']:.2f}"
        for r in rows
        if r["envs_done"] % 5 == 0 or r is rows[-1]
    )
    cm = lambda d: (
        f"{100 * d['median_pos_dist']:.1f} cm, {d['median_rot_dist']:.2f} rad" if d else "-"
    )  # noqa: E731
    lines = [
        "| quantity | value |",
        "|---|---|",
        f"| training goal poses tried (loop steps, `B = 1`) | {rows[-1]['envs_done']} |",
        "| training poses whose optimised mean succeeds | "
        f"{sum(r.get('success', 0) for r in rows[1:])} / {rows[-1]['envs_done']} |",
        f"| ... already solved by the map's prediction (0 iterations) | {started} |",
        "| training episodes (optimiser samples + distinct means executed) | "
        f"{s.get('episodes', rows[-1]['episodes'])} |",
        f"| optimiser samples (`loop.rollouts`) | {s.get('rollouts', '-')} |",
        f"| **held-out unseen goal poses: the map's mean succeeds** | **{h.get('success', '-')} / "
        f"{h.get('poses', '-')}** |",
        f"| held-out: median box distance to its goal (position, rotation) | {cm(h)} |",
        f"| held-out: median return of the map's mean | {h.get('median_return', float('nan')):.1f} "
        "|",
        f"| training poses: median box distance of the optimised means | {cm(t)} |",
        f"| held-out success against training poses tried | {curve} |",
        "| wall time (shared 2-core machine, `nice -n 19`) | "
        f"{s.get('wall_seconds', rows[-1]['wall_seconds']) / 60:.0f} min |",
        f"| goal poses (x m, y m, yaw rad) | {fmt_ranges(out['meta']['ranges'])} |",
        f"| settings | {st['optimizer']}, {st['samples']} samples, <= {st['max_iter']} iterations "
        "a pose, "
        f"start N(0, {st['start_std']}^2 I), alpha {st['alpha']}, min_var {st['min_var']}, "
        f"var_floor {st['var_floor']}, "
        f"add_only {st['add_only']}, choice {st['choice']}, seed {st['seed']} |",
    ]
    if out.get("partial"):
        lines.append(
            f"| (partial: the run had tried {rows[-1]['envs_done']} of {st['train']} poses) | |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--train", type=int, default=20, help="training goal poses the loop tries")
    ap.add_argument("--heldout", type=int, default=30, help="unseen goal poses of the test")
    ap.add_argument(
        "--optimizer",
        default="CMAES",
        choices=("CMAES", "EPRO", "PRO", "CEM"),
        help="the loop's optimiser",
    )
    ap.add_argument("--samples", type=int, default=20, help="samples per iteration")
    ap.add_argument("--max-iter", type=int, default=30, help="iterations per training pose at most")
    ap.add_argument(
        "--start-std", type=float, default=1.0, help="the prior entry is N(0, start_std^2 I)"
    )
    ap.add_argument(
        "--min-var", type=float, default=0.04, help="floor on the map's predicted variance"
    )
    ap.add_argument(
        "--var-floor",
        type=float,
        default=0.01,
        help="floor on a new entry's variance (its GP noise)",
    )
    ap.add_argument(
        "--alpha", type=float, default=5.0, help="GP kernel exp(-alpha |e - e'|^2) on the unit cube"
    )
    ap.add_argument("--add-only", default="all", choices=("all", "success", "converged"))
    ap.add_argument(
        "--choice",
        default="nearest",
        choices=("nearest", "random"),
        help="the next training pose: the untried one nearest a known pose (the authors' "
        "curriculum) or in draw order",
    )
    ap.add_argument("--x-range", type=floats, default=X_RANGE, metavar="LO,HI", help="goal x (m)")
    ap.add_argument("--y-range", type=floats, default=Y_RANGE, metavar="LO,HI", help="goal y (m)")
    ap.add_argument(
        "--yaw-range",
        type=floats,
        default=YAW_RANGE,
        metavar="LO,HI",
        help="goal yaw (rad about z; the box starts at pi)",
    )
    ap.add_argument(
        "--seed", type=int, default=0, help="training poses and optimiser seeds; held-out: seed + 1"
    )
    ap.add_argument("--workers", type=int, default=1, help="processes the episodes are spread over")
    ap.add_argument(
        "--json",
        default=None,
        help="results file (default benchmarks/studies/results/external/loop/box_goal_loop.json)",
    )
    ap.add_argument(
        "--smoke", action="store_true", help="2 training poses, 3 iterations, 3 held-out poses"
    )
    ap.add_argument(
        "--report", metavar="JSON", help="print the markdown table of a results file and exit"
    )
    args = ap.parse_args(argv)
    if args.report:
        print(report(args.report))
        return {}
    if args.smoke:
        args.train, args.heldout, args.max_iter = 2, 3, 3
        args.json = args.json or "/tmp/box_goal_loop_smoke.json"
    args.json = args.json or str(
        Path(__file__).resolve().parents[3]
        / "benchmarks/studies/results/external/loop/box_goal_loop.json"
    )
    for name in ("train", "heldout", "samples", "max_iter", "workers"):
        if getattr(args, name) < 1:
            raise SystemExit(
                f"error: --{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}"
            )
    import fancy_gym
    import mujoco
    from run import commit

    from protorch.data.dataset import ORIGINS
    from protorch.gp import make_env_map
    from protorch.loop import LoopSettings, OptimizerSpec, Run, self_improve
    from protorch.optim import CEM, CMAES, EPRO, PRO

    torch.set_num_threads(1)
    optimizer = {"CMAES": CMAES, "EPRO": EPRO, "PRO": PRO, "CEM": CEM}[args.optimizer]
    kwargs = {"num_samples": args.samples, "max_iter": args.max_iter, "tol": 0.0}
    kwargs.update(
        {
            "PRO": {"beta": 0.05, "relevance_samples": args.samples, "noise_floor": 3.0},
            "CEM": {"elite_frac": 0.1},
        }.get(args.optimizer, {})
    )
    task = BoxGoalTask(
        x_range=args.x_range, y_range=args.y_range, yaw_range=args.yaw_range, workers=args.workers
    )
    promp = identity_promp()
    heldout = task.sample_envs(args.heldout, torch.Generator().manual_seed(args.seed + 1))  # (Q, 3)
    task.mark_heldout(heldout)
    meta = {
        "command": "python benchmarks/studies/external/loop.py "
        + shlex.join(sys.argv[1:] if argv is None else argv),
        "commit": commit(),
        "fancy_gym": getattr(fancy_gym, "__version__", "0.3.0"),
        "mujoco": mujoco.__version__,
        "ranges": {"x": list(args.x_range), "y": list(args.y_range), "yaw": list(args.yaw_range)},
        "settings": {k: v for k, v in vars(args).items() if k != "json"},
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
    }
    out: dict = {"meta": meta, "rows": [], "partial": True}
    t0 = time.perf_counter()

    def write() -> None:
        atomic_write_bytes(args.json, json.dumps(out, indent=1).encode())

    def on_step(row: dict) -> None:
        out["rows"].append(
            {
                **row,
                "episodes": task.episodes,
                "heldout_episodes": task.heldout_episodes,
                "wall_seconds": round(time.perf_counter() - t0, 1),
            }
        )
        write()
        print(
            f"step {row['step']}: success {row['success']} (start {row['initial_success']}), "
            f"iterations {row['iterations_mean']}, held-out {row['eval_success']}, episodes "
            f"{task.episodes}, "
            f"{time.perf_counter() - t0:.0f} s",
            flush=True,
        )

    res = self_improve(
        task,
        promp,
        prior_dataset(task, promp, args.start_std),
        OptimizerSpec(optimizer, kwargs),
        lambda: make_env_map("torch", args.alpha),
        LoopSettings(
            num_envs=args.train,
            batch_size=1,
            add_only=args.add_only,
            choice=args.choice,
            seed=args.seed,
            min_var=args.min_var,
            var_floor=args.var_floor,
            refill=False,
            eval_dtype=None,
            threads=1,
        ),
        Run(on_step=on_step),
        solved=task.success,
        eval_envs=heldout,
    )
    out["rows"].insert(
        0, {**res.metrics[0], "episodes": 0, "heldout_episodes": 0, "wall_seconds": 0.0}
    )
    mean_q = res.env_map.predict_mean(heldout)  # (Q, 35)
    out["heldout"] = describe(task, promp, mean_q, heldout)
    ds = res.dataset
    keep = ds.origin == ORIGINS.index("learned")  # (M,) the loop's solutions
    out["train"] = describe(task, promp, ds.mean[keep], ds.env[keep])
    out["summary"] = {
        "heldout": summarise(out["heldout"]),
        "train": summarise(out["train"]),
        "episodes": task.episodes,
        "heldout_episodes": task.heldout_episodes,
        "rollouts": int(sum(r.get("rollouts") or 0 for r in res.metrics[1:])),
        "loop_seconds": round(res.seconds, 1),
        "wall_seconds": round(time.perf_counter() - t0, 1),
    }
    out["partial"] = False
    write()
    print(json.dumps(out["summary"], indent=1))
    return out


if __name__ == "__main__":
    main()
