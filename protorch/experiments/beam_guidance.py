"""What the kept variance buys in the beam teleoperation (Sec. IV-A): haptic guidance built from
the distribution each optimiser returns for the same two-stage task and rollout budget.

For every optimiser (the paper's PRO, EPRO, RWR, CEM, CMA-ES) the demonstrations' pose ProMP is
optimised as in :func:`~protorch.experiments.beam_window.optimize_pose_promp` (position, then
orientation with its window via points where the optimised position passes them), each stage
with at most ``budget`` rollouts (the experiment passes ``min(guidance_compare.budget, PRO's
rollouts per stage)``) and the contract's convergence rule; PRO's distribution is the
experiment's own (its 150 iterations). The same operators (the experiment's 100 intentions) are
then assisted by :class:`~protorch.control.guidance.HapticGuidance` from each distribution.

Two numbers per optimiser:

- ``assisted_success_rate``: assisted trials that succeed (:meth:`BeamWindowTask.success`);
- ``free_force``: the mean magnitude (N) of the position guidance force over the steps whose
  phase is more than ``margin`` away from every via point (start 0, the two window via points,
  end 1), over all trials. There the task does not constrain the motion, so any force the
  operator feels is the fixture fighting an intention the task allows: a distribution that kept
  its variance there renders a soft fixture and a small force; one that collapsed it everywhere
  pulls every operator onto its mean. The operators' intentions all differ from the mean (depth,
  tilt and timing errors), so this is the force felt by people who move differently, which is
  what the paper's "inversely proportional to the std" guidance is meant to allow.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..checks import check_int, check_keys
from ..control.guidance import HapticGuidance
from ..optim import CEM, CMAES, EPRO, RWR
from ..primitives.pose import PoseProMP
from ..tasks.beam_window import BeamWindowTask

__all__ = [
    "PEERS",
    "compare_settings",
    "pro_stage_rollouts",
    "free_phase_mask",
    "free_force",
    "optimize_with",
    "compare_guidance",
]

PEERS = ("EPRO", "RWR", "CEM", "CMA-ES")  # optimised here; "PRO" is the experiment's distribution


def free_phase_mask(
    phase_index: Tensor, num_steps: int, via_phases: Tensor, margin: float
) -> Tensor:
    """``(B, T)`` bool: steps whose phase (grid index ``phase_index (B, T)`` of ``num_steps``) is
    more than ``margin`` from each of ``via_phases (K,)``."""
    if not 0 <= margin < 0.5:
        raise ValueError(f"margin must be in [0, 0.5), got {margin}")
    z = phase_index.to(via_phases.dtype) / (num_steps - 1)  # (B, T)
    return ((z[..., None] - via_phases).abs() > margin).all(-1)


def free_force(force: Tensor, mask: Tensor) -> float:
    """Mean ``|F_position|`` (N) of ``force (B, T, 7)`` over the steps where ``mask (B, T)``."""
    if not bool(mask.any()):
        raise ValueError("no step lies away from the via points: lower the margin")
    return float(force[..., :3].norm(dim=-1)[mask].mean())


def compare_settings(cfg: dict | None) -> dict:
    """The experiment's ``guidance_compare`` settings checked, defaults filled in: ``enabled``
    (default true), ``budget`` (rollouts per stage for each peer, default 10,000), ``margin``
    (phase distance from every via point, default 0.1)."""
    out = {"enabled": True, "budget": 10_000, "margin": 0.1, **dict(cfg or {})}
    check_keys(out, {"enabled", "budget", "margin"}, "guidance_compare")
    if not isinstance(out["enabled"], bool):
        raise ValueError(f"guidance_compare.enabled must be true or false, got {out['enabled']!r}")
    out["budget"] = check_int(out["budget"], "guidance_compare.budget", 2)
    if not 0 <= float(out["margin"]) < 0.5:
        raise ValueError(f"guidance_compare.margin must be in [0, 0.5), got {out['margin']}")
    return out


def pro_stage_rollouts(optimizer: dict, num_objectives: int = 4) -> int:
    """Rollouts PRO may spend on one beam stage with the experiment's ``optimizer`` settings:
    ``max_iter * (relevance_samples + O * num_samples)`` (PRO's defaults where a key is unset)."""
    pro = dict(optimizer.get("pro") or {})
    return int(optimizer.get("max_iter", 200)) * (
        int(pro.get("relevance_samples", 200))
        + num_objectives * int(optimizer.get("num_samples", 100))
    )


def _make(name: str, mean: Tensor, var: Tensor, beta: float, seed: int, num_samples: int):
    common = dict(max_iter=10**9, tol=1e-3, window=5, seed=seed)
    if name == "EPRO":
        return EPRO(mean, var, **common)
    if name == "RWR":
        return RWR(mean, var, beta=beta, num_samples=num_samples, **common)
    if name == "CEM":
        return CEM(mean, var, elite_frac=0.1, num_samples=num_samples, **common)
    if name == "CMA-ES":
        return CMAES(
            mean, var, num_samples=4 + int(3 * math.log(mean.shape[-1])), **common
        )  # pycma's default popsize
    raise ValueError(f"unknown optimiser {name!r}; choose from {list(PEERS)}")


def _minimize(opt, costs, budget: int) -> tuple[Tensor, Tensor]:
    used = 0
    while (
        not opt.stop() and used + opt.num_samples <= budget
    ):  # one ask of num_samples per iteration
        w = opt.ask()  # (S, N)
        opt.tell(costs(w))
        used += w.shape[0]
    return opt.mean[0].clone(), opt.var[0].clone()


def optimize_with(
    name: str,
    task: BeamWindowTask,
    demo_model: PoseProMP,
    *,
    beta: float,
    budget: int,
    seed: int,
    num_samples: int = 200,
    eval_dtype: torch.dtype = torch.float32,
) -> PoseProMP:
    """Both beam stages with optimiser ``name`` from ``demo_model`` (not changed): a new ProMP."""
    model = demo_model.copy()
    ev = model.copy().to(eval_dtype)
    pos = lambda w: task.position_costs(ev.position.trajectory(w.to(eval_dtype))).to(w.dtype)  # noqa: E731
    opt = _make(name, model.position.mean, model.position.var, beta, seed, num_samples)
    model.set_distribution(position=_minimize(opt, pos, budget))
    z = task.window_phases(model.position.mean_trajectory()).to(eval_dtype)  # (4,)
    ev = model.copy().to(eval_dtype)
    rot = lambda w: task.orientation_costs(ev.orientation.trajectory(w.to(eval_dtype)), z).to(
        w.dtype
    )  # noqa: E731
    opt = _make(name, model.orientation.mean, model.orientation.var, beta, seed + 1, num_samples)
    model.set_distribution(orientation=_minimize(opt, rot, budget))
    return model


def compare_guidance(
    task: BeamWindowTask,
    demo_model: PoseProMP,
    pro_model: PoseProMP,
    intended: Tensor,
    lengths: Tensor,
    *,
    guidance: dict,
    hand: dict,
    beta: float,
    budget: int,
    seed: int,
    margin: float = 0.1,
    names=PEERS,
    eval_dtype: torch.dtype = torch.float32,
) -> dict:
    """``{name: {"assisted_success_rate", "free_force", "free_stiffness", "max_std_position"}}``
    for PRO
    (``pro_model``, the experiment's) and each of ``names`` optimised here (see the module
    docstring);
    ``free_stiffness`` is the mean position stiffness (N/m) over the same free steps."""
    compare_settings({"budget": budget, "margin": margin})
    models = {"PRO": pro_model}
    for name in names:
        models[name] = optimize_with(
            name, task, demo_model, beta=beta, budget=budget, seed=seed, eval_dtype=eval_dtype
        )
    out = {}
    for name, model in models.items():
        guide = HapticGuidance(model, **guidance)
        trials = guide.assist(intended, lengths=lengths, **hand)
        vias = task.window_phases(model.position.mean_trajectory()).to(trials.force.dtype)  # (4,)
        mask = free_phase_mask(trials.phase_index, guide.num_steps, vias, margin)  # (B, T)
        in_trial = (
            torch.arange(intended.shape[1], device=intended.device)
            < lengths.to(intended.device)[:, None]
        )
        out[name] = {
            "assisted_success_rate": float(task.success(trials.poses).double().mean()),
            "free_force": free_force(trials.force, mask & in_trial),
            "free_stiffness": float(
                trials.stiffness[..., :3][mask & in_trial].mean()
            ),  # N/m, position
            "max_std_position": float(model.std_trajectory()[:, :3].max()),
        }
    return out
