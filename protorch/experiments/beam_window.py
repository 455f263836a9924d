"""Sec. IV-A and Fig. 5 of the paper: assisted teleoperation of a beam through a window.

1. **Demonstrations**: 10 trials of a :class:`~protorch.tasks.SimulatedOperator` (depth
   misjudged, orientation off, jitter), most of which hit the wall.
2. **Pose ProMP** (:class:`~protorch.primitives.pose.PoseProMP`) fitted to them: a position and a
   quaternion ProMP (quaternions renormalised and sign-aligned).
3. **Two-stage PRO** as in the paper: four via points (start, two at the window computed from
   its pose, end), reward ``exp(-beta (obj + 0.1 len + 1e5 jerk))``, ``beta = 200``, 150
   iterations x 200 samples; first the position ProMP, then the orientation ProMP with its
   window via points at the phases where the optimised position mean passes the window via
   points.
4. **Evaluation**: the optimised mean and 1000 samples (position and orientation weights drawn
   independently) checked for collisions along the densely resampled trajectory.
5. **Haptic guidance** (:class:`~protorch.control.guidance.HapticGuidance`): ``F = K(z) (mu(z) -
x)``,
   ``K`` inversely proportional to the optimised ProMP's std (clipped); 100 simulated operator
   trials without and the same 100 with guidance (paired: the same intentions).
6. **Figures** (``fig5_beam_window.png``, ``teleop.png``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import torch

from ..checks import check_int, check_keys
from ..control.guidance import HapticGuidance
from ..figures.beam import fig5_figure, teleop_figure
from ..figures.guidance import guidance_figure
from ..optim import PRO
from ..primitives.pose import PoseProMP
from ..tasks.beam_window import BeamWindowTask, SimulatedOperator
from ..threads import torch_threads
from .beam_guidance import compare_guidance, compare_settings, pro_stage_rollouts
from .common import optimizer_kwargs, resolve_dtype

__all__ = ["run", "optimize_pose_promp"]

_DEMO_SEED = 101  # demonstrations: seed + _DEMO_SEED
_EVAL_SEED = 202  # the optimised distribution's samples
_TELEOP_SEED = 303  # the simulated teleoperation trials (never the demonstrations' stream)
_TELEOP_KEYS = {"trials", "human_position_stiffness", "human_rotation_stiffness"}
_PROMP_KEYS = {"num_basis", "num_steps", "width", "ridge"}


def _tuples(cfg: dict) -> dict:
    return {k: tuple(v) if isinstance(v, (list, tuple)) else v for k, v in cfg.items()}


def optimize_pose_promp(
    task: BeamWindowTask,
    promp: PoseProMP,
    *,
    optimizer: dict,
    seed: int = 0,
    eval_dtype: torch.dtype = torch.float32,
    progress: bool = False,
) -> dict:
    """The paper's two PRO problems on ``promp`` (changed in place): position, then orientation.

    ``optimizer`` holds PRO's settings (``beta``, ``num_samples``, ``max_iter``, ``tol``,
    ``window`` and a ``pro`` section). Samples are evaluated in ``eval_dtype`` (the distribution
    stays in the ProMP's dtype). Returns per stage the :class:`~protorch.optim.OptimizeResult`,
    the seconds it took, and the via phases used by the orientation stage.
    """
    kwargs = optimizer_kwargs(optimizer, optimizer.get("pro"))
    if "beta" not in kwargs or not float(kwargs["beta"]) > 0:
        raise ValueError(f"optimizer.beta must be > 0, got {kwargs.get('beta')}")
    out: dict = {}
    # ---- stage 1: position
    ev = promp.copy().to(eval_dtype)
    opt = PRO(promp.position.mean, promp.position.var, seed=seed, **kwargs)
    t0 = time.perf_counter()
    res = opt.minimize(
        lambda w: task.position_costs(ev.position.trajectory(w.to(eval_dtype))).to(w.dtype),
        progress=progress,
    )
    out["position"] = {"result": res, "seconds": time.perf_counter() - t0}
    promp.set_distribution(
        position=(res.mean.to(promp.position.mean), res.var.to(promp.position.mean))
    )
    # ---- stage 2: orientation, its window via points where the optimised position passes them
    phases = task.window_phases(promp.position.mean_trajectory())  # (4,)
    ev = promp.copy().to(eval_dtype)
    z = phases.to(eval_dtype)
    opt = PRO(promp.orientation.mean, promp.orientation.var, seed=seed + 1, **kwargs)
    t0 = time.perf_counter()
    res = opt.minimize(
        lambda w: task.orientation_costs(ev.orientation.trajectory(w.to(eval_dtype)), z).to(
            w.dtype
        ),
        progress=progress,
    )
    out["orientation"] = {"result": res, "seconds": time.perf_counter() - t0}
    promp.set_distribution(
        orientation=(res.mean.to(promp.orientation.mean), res.var.to(promp.orientation.mean))
    )
    out["phases"] = phases
    return out


def run(
    out_dir: Path,
    *,
    seed: int = 0,
    device: str | torch.device = "cpu",
    dtype: torch.dtype = torch.float64,
    optimizer: dict,
    plot: bool = True,
    task: dict | None = None,
    operator: dict | None = None,
    num_demos: int = 10,
    promp: dict | None = None,
    eval_dtype: str = "float32",
    eval_samples: int = 1000,
    guidance: dict | None = None,
    teleop: dict | None = None,
    num_threads: int | None = None,
    progress: bool = False,
    guidance_compare: dict | None = None,
) -> dict:
    """Run the experiment into ``out_dir`` and return its metrics (see the module docstring).

    ``task``: :class:`~protorch.tasks.BeamWindowTask` fields (wall pose, window, beam, start and
    end poses, weights); ``operator``: :class:`~protorch.tasks.SimulatedOperator` fields;
    ``promp``: ``num_basis``, ``num_steps``, ``width``, ``ridge``; ``guidance``:
    :class:`~protorch.control.guidance.HapticGuidance` gains; ``teleop``: ``trials`` and the hand's
    stiffness ``human_position_stiffness`` (N/m), ``human_rotation_stiffness``. ``num_threads``:
    torch's intra-op threads during the run (``None``: torch's default). The tensors are small
    (200 x 250 x 4), so on a machine whose cores are busy with other jobs one thread is several
    times faster than two that wait on each other. Every setting is validated before any work
    starts.
    """
    if num_threads is not None:
        num_threads = check_int(num_threads, "num_threads", 1)
    with torch_threads(num_threads):
        return _run(
            out_dir,
            seed=seed,
            device=device,
            dtype=dtype,
            optimizer=optimizer,
            plot=plot,
            task=task,
            operator=operator,
            num_demos=num_demos,
            promp=promp,
            eval_dtype=eval_dtype,
            eval_samples=eval_samples,
            guidance=guidance,
            teleop=teleop,
            progress=progress,
            guidance_compare=guidance_compare,
        )


@dataclass
class _Setup:
    """The validated settings of one run: the task, the person, the ProMP and the guidance."""

    beam: BeamWindowTask
    person: SimulatedOperator
    model: PoseProMP
    guide_cfg: dict
    hand: dict  # the hand's stiffnesses of the teleoperation
    trials: int
    num_demos: int
    eval_samples: int
    eval_dtype: torch.dtype


def _setup(
    *,
    dtype,
    device,
    optimizer,
    task,
    operator,
    num_demos,
    promp,
    eval_dtype,
    eval_samples,
    guidance,
    teleop,
) -> _Setup:
    """Validate every setting (naming the bad one) and build the task, person and ProMP."""
    promp_cfg, guide_cfg, tele_cfg = dict(promp or {}), dict(guidance or {}), dict(teleop or {})
    check_keys(promp_cfg, _PROMP_KEYS, "promp")
    check_keys(tele_cfg, _TELEOP_KEYS, "teleop")
    if "beta" not in optimizer or not float(optimizer["beta"]) > 0:
        raise ValueError(f"optimizer.beta must be > 0, got {optimizer.get('beta')}")
    for k, lo in (("max_iter", 1), ("num_samples", 2)):
        if k in optimizer:
            check_int(optimizer[k], f"optimizer.{k}", lo)
    num_demos = check_int(num_demos, "num_demos", 2)
    eval_samples = check_int(eval_samples, "eval_samples", 1)
    trials = check_int(tele_cfg.pop("trials", 100), "teleop.trials", 1)
    ev_dtype = resolve_dtype(eval_dtype)
    beam = BeamWindowTask(**_tuples(dict(task or {})))
    person = SimulatedOperator(**_tuples(dict(operator or {})))
    model = PoseProMP(
        **{"num_basis": 10, "num_steps": 250, **promp_cfg}, dtype=dtype, device=device
    )
    guide_cfg = HapticGuidance.check_settings(**guide_cfg)
    for k in ("human_position_stiffness", "human_rotation_stiffness"):
        if k in tele_cfg and not float(tele_cfg[k]) >= 0:
            raise ValueError(f"teleop.{k} must be >= 0, got {tele_cfg[k]}")
    return _Setup(
        beam=beam,
        person=person,
        model=model,
        guide_cfg=guide_cfg,
        hand={k: float(v) for k, v in tele_cfg.items()},
        trials=trials,
        num_demos=num_demos,
        eval_samples=eval_samples,
        eval_dtype=ev_dtype,
    )


def _run(out_dir, *, seed, plot, progress, guidance_compare=None, **settings) -> dict:
    """Build task and demonstrations -> optimise (two-stage PRO) -> evaluate (teleoperation, and
    guidance from each optimiser's distribution) -> figures. ``settings``: :func:`_setup`'s."""
    t_start = time.perf_counter()
    out_dir = Path(out_dir)
    cfg = _setup(**settings)
    dtype, device, optimizer = settings["dtype"], settings["device"], settings["optimizer"]
    compare = compare_settings(guidance_compare)
    gen = torch.Generator(device=cfg.model.phase.device).manual_seed(int(seed) + _EVAL_SEED)
    demos, demo_hits, demo_model, metrics_demos = _demonstrations(
        cfg, seed, gen, dtype=dtype, device=device
    )
    metrics: dict = {"demos": metrics_demos}
    stages = optimize_pose_promp(
        cfg.beam,
        cfg.model,
        optimizer=optimizer,
        seed=int(seed),
        eval_dtype=cfg.eval_dtype,
        progress=progress,
    )
    samples, metrics["optimized"] = _optimized_metrics(cfg, stages, gen)
    tele, metrics["teleop"] = _teleoperation(
        cfg, demo_model, stages["phases"], seed, dtype=dtype, device=device
    )
    if compare.pop(
        "enabled"
    ):  # guidance from each optimiser's distribution (protorch.experiments.beam_guidance)
        compare["budget"] = min(
            compare["budget"], pro_stage_rollouts(optimizer)
        )  # never more than PRO's
        metrics["guidance"] = compare_guidance(
            cfg.beam,
            demo_model,
            cfg.model,
            tele["intended"],
            tele["lengths"],
            guidance=cfg.guide_cfg,
            hand=cfg.hand,
            beta=float(optimizer["beta"]),
            seed=int(seed),
            eval_dtype=cfg.eval_dtype,
            **compare,
        )
    if plot:
        if "guidance" in metrics:
            guidance_figure(out_dir / "guidance.png", metrics["guidance"])
        fig5_figure(
            out_dir / "fig5_beam_window.png",
            cfg.beam,
            demos,
            demo_hits,
            demo_model,
            cfg.model,
            samples[:30],
            stages["phases"],
        )
        teleop_figure(
            out_dir / "teleop.png",
            cfg.beam,
            tele["guide"],
            tele["intended"],
            tele["assisted"],
            tele["free_ok"],
            tele["guided_ok"],
            tele["lengths"],
        )
    metrics["seconds"] = round(time.perf_counter() - t_start, 3)
    return metrics


def _demonstrations(cfg: _Setup, seed: int, gen: torch.Generator, *, dtype, device):
    """The person's trials, the ProMP fitted to them (``cfg.model``, and a copy kept) and their
    metrics; ``gen`` draws the copy's samples. Returns ``(demos, hits (n,), demo_model,
    metrics)``."""
    beam, model = cfg.beam, cfg.model
    demos = cfg.person.trials(
        beam, cfg.num_demos, torch.Generator().manual_seed(int(seed) + _DEMO_SEED), dtype=dtype
    )
    demos = [d.to(device) for d in demos]
    demo_hits = torch.stack([beam.collides(d) for d in demos])  # (n,)
    demo_ok = torch.stack([beam.success(d) for d in demos])  # (n,)
    model.fit(demos, reference=torch.tensor(beam.start_quaternion, dtype=dtype, device=device))
    demo_model = model.copy()
    w_pos, w_rot = demo_model.sample(cfg.eval_samples, generator=gen)
    demo_samples = demo_model.trajectory(w_pos, w_rot)  # (S, T, 7)
    metrics = {
        "count": cfg.num_demos,
        "collision_free_rate": float((~demo_hits).double().mean()),
        "success_rate": float(demo_ok.double().mean()),
        "promp_mean_collision_free": not bool(beam.collides(demo_model.mean_trajectory())),
        "promp_samples_collision_free_rate": float((~beam.collides(demo_samples)).double().mean()),
        "promp_mean_via_errors": beam.via_errors(demo_model.mean_trajectory()),
    }
    return demos, demo_hits, demo_model, metrics


def _optimized_metrics(
    cfg: _Setup, stages: dict, gen: torch.Generator
) -> tuple[torch.Tensor, dict]:
    """The optimised ProMP's mean and ``eval_samples`` samples (drawn with ``gen``) checked by the
    task, and each stage's iterations and costs. Returns ``(samples (S, T, 7), metrics)``."""
    beam, model = cfg.beam, cfg.model
    mean = model.mean_trajectory()  # (T, 7)
    w_pos, w_rot = model.sample(cfg.eval_samples, generator=gen)
    samples = model.trajectory(w_pos, w_rot)  # (S, T, 7)
    std = model.std_trajectory()  # (T, 7)
    metrics = {
        "mean_collision_free": not bool(beam.collides(mean)),
        "mean_success": bool(beam.success(mean)),
        "samples_collision_free_rate": float((~beam.collides(samples)).double().mean()),
        "samples_success_rate": float(beam.success(samples).double().mean()),
        "num_samples": cfg.eval_samples,
        "via_errors": beam.via_errors(mean),
        "window_phases": stages["phases"].tolist(),
        "max_std_position": float(std[:, :3].max()),
        "max_std_quaternion": float(std[:, 3:].max()),
    }
    for name in ("position", "orientation"):
        res = stages[name]["result"]
        metrics[name] = {
            "iterations": res.iterations,
            "seconds": round(stages[name]["seconds"], 3),
            "final_cost": res.history["cost"][-1].tolist(),
            "initial_cost": res.history["cost"][0].tolist(),
        }
    return samples, metrics


def _teleoperation(cfg: _Setup, demo_model, phases: torch.Tensor, seed: int, *, dtype, device):
    """Simulated teleoperation trials unassisted, guided by the optimised ProMP and by the
    demonstrations' ProMP. Returns ``(what the figure needs, metrics)``."""
    beam, person, trials = cfg.beam, cfg.person, cfg.trials
    guide = HapticGuidance(cfg.model, **cfg.guide_cfg)
    intended, lengths = person.intentions(
        beam, trials, torch.Generator().manual_seed(int(seed) + _TELEOP_SEED), dtype=dtype
    )
    intended = intended.to(device)  # (B, T_max, 7)
    t0 = time.perf_counter()
    assisted = guide.assist(intended, lengths=lengths, **cfg.hand)
    assist_seconds = time.perf_counter() - t0
    free_ok, free_hit = beam.success(intended), beam.collides(intended)  # (B,)
    guided_ok, guided_hit = beam.success(assisted.poses), beam.collides(assisted.poses)  # (B,)
    # the same guidance from the demonstrations' ProMP (before PRO): what the optimisation adds
    demo_guided = HapticGuidance(demo_model, **cfg.guide_cfg).assist(
        intended, lengths=lengths, **cfg.hand
    )
    i_front, i_back = (phases[1:3] * (guide.num_steps - 1)).round().long().tolist()
    unassisted_rate = float(free_ok.double().mean())
    assisted_rate = float(guided_ok.double().mean())
    metrics = {
        "trials": trials,
        "unassisted_success_rate": unassisted_rate,
        "assisted_success_rate": assisted_rate,
        "unassisted_collision_rate": float(free_hit.double().mean()),
        "assisted_collision_rate": float(guided_hit.double().mean()),
        "success_ratio": assisted_rate / unassisted_rate if unassisted_rate > 0 else None,
        "assisted_by_demos_promp_success_rate": float(
            beam.success(demo_guided.poses).double().mean()
        ),
        "paired": {
            "fixed_by_guidance": int((guided_ok & ~free_ok).sum()),
            "broken_by_guidance": int((~guided_ok & free_ok).sum()),
        },
        "stiffness_at_window": {
            "position": float(guide.stiffness[i_front : i_back + 1, :3].mean()),
            "quaternion": float(guide.stiffness[i_front : i_back + 1, 3:].mean()),
        },
        "stiffness_median": {
            "position": float(guide.stiffness[:, :3].median()),
            "quaternion": float(guide.stiffness[:, 3:].median()),
        },
        "max_force_position": float(assisted.force[..., :3].norm(dim=-1).max()),
        "seconds": round(assist_seconds, 3),
    }
    tele = {
        "guide": guide,
        "intended": intended,
        "assisted": assisted.poses,
        "free_ok": free_ok,
        "guided_ok": guided_ok,
        "lengths": lengths,
    }
    return tele, metrics
