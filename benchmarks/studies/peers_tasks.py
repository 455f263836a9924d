"""The problems of benchmarks/studies/peers.py: one start distribution, its costs and its success
check
per problem, each with ``NUISANCE`` extra weights that no objective reads (see peers.py)."""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/configs.py
from configs import experiment_config, experiment_settings  # noqa: E402

from protorch import ProMP
from protorch.experiments.point_particle import prepare as prepare_particle
from protorch.gp.model import label_aware_mean
from protorch.primitives.pose import PoseProMP, quaternion_distance
from protorch.tasks import WindowTask
from protorch.tasks.beam_window import BeamWindowTask, SimulatedOperator

NUISANCE = 10  # weights of the DoF no objective reads
# --seed S shifts every problem and optimiser seed by S * SEED_STEP (S = 0: the published seeds)
SEED_STEP = 100_003
F64 = torch.float64
BEAM_POSITION_TOL = 0.005  # m: every position via point of the mean within 5 mm
BEAM_ANGLE_TOL = 2.0  # deg: every orientation via point of the mean within 2 degrees


@dataclass
class Problem:
    """One start distribution and its task: weights ``(N_task + NUISANCE,)``."""

    task: str
    repeat: int
    mean: torch.Tensor  # (N,)
    var: torch.Tensor  # (N,)
    n_task: int
    costs: Callable[[torch.Tensor], torch.Tensor]  # (..., N) -> (..., O)
    success: Callable[[torch.Tensor], bool]  # (N,) mean -> solved?
    num_basis: int
    # the seed set (benchmarks/studies/peers.py --seed): the optimiser's seed is 1000 + repeat +
    # SEED_STEP * seed
    seed: int = 0
    promp: ProMP | None = (
        None  # the task's ProMP over the first n_task weights (point particle, arm)
    )
    env: torch.Tensor | None = None  # the problem's environment (point particle, arm)
    task_obj: object = None  # the task (point particle, arm)

    @property
    def optimizer_seed(self) -> int:
        return 1000 + self.repeat + SEED_STEP * self.seed


def with_nuisance(mean: torch.Tensor, var: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Append ``NUISANCE`` weights of mean 0 and the median task variance."""
    v = var.median()
    return torch.cat([mean, mean.new_zeros(NUISANCE)]), torch.cat([var, v.expand(NUISANCE)])


def window_problems(repeats: int, seed: int = 0) -> list[Problem]:
    task = WindowTask()
    out = []
    for r in range(repeats):
        demos = task.demonstrations(
            5, generator=torch.Generator().manual_seed(r + SEED_STEP * seed), dtype=F64
        )
        promp = ProMP(2, 10, 100, dtype=F64).fit(demos)
        mean, var = with_nuisance(promp.mean, promp.var)
        n = promp.mean.shape[-1]

        def costs(w, promp=promp, n=n):  # (..., N) -> (..., 3)
            return task.costs(promp.trajectory(w[..., :n]))

        def success(w, promp=promp, n=n):
            return bool(task.success(promp.trajectory(w[..., :n])))

        out.append(Problem("window", r, mean, var, n, costs, success, 10, seed))
    return out


def point_particle_problems(repeats: int, seed: int = 0, beta: float = 20.0) -> list[Problem]:
    """Random single environments, started from the GP map of the 30 x 3 synthetic demonstrations
    (Eq. 7, 8): the guess the self-improvement loop has to improve (it fails in every one here)."""
    setup = prepare_particle(
        optimizer={"beta": beta},
        task={"objectives": "clearance"},
        loop={"num_envs": 0},
        test={"num_envs": 1},
        dynamic={"episodes": 0},
    )
    data = setup.initial_data()
    gp = setup.env_map().fit(data.env, data.mean, data.var, data.label)
    envs = setup.task.sample_envs(
        repeats, torch.Generator().manual_seed(12345 + SEED_STEP * seed), dtype=F64
    )  # (R, 6)
    mu, var = gp.predict(envs)  # (R, N), (R, N)
    promp, task = setup.promp, setup.task
    n = mu.shape[-1]
    out = []
    for r in range(repeats):
        env = envs[r]
        mean, v = with_nuisance(mu[r], var[r])

        def costs(w, env=env):  # (..., N) -> (..., 3)
            return task.costs(promp.trajectory(w[..., :n]), env)

        def success(w, env=env):
            return bool(task.success(promp.trajectory(w[..., :n]), env))

        out.append(
            Problem("point_particle", r, mean, v, n, costs, success, 10, seed, promp, env, task)
        )
    return out


def _beam_setup(repeat: int, seed: int = 0) -> tuple[BeamWindowTask, PoseProMP]:
    """The experiment's beam task and pose ProMP of 10 simulated operator trials (``repeat``,
    ``seed``)."""
    cfg = experiment_config("beam_window")  # composed as the app composes it
    tup = {
        k: tuple(v) if isinstance(v, list) else v for k, v in cfg["task"].items() if k != "_target_"
    }
    beam = BeamWindowTask(**tup)
    person = SimulatedOperator(
        **{
            k: tuple(v) if isinstance(v, list) else v
            for k, v in cfg["settings"]["operator"].items()
        }
    )
    demos = person.trials(
        beam, 10, torch.Generator().manual_seed(repeat + 101 + SEED_STEP * seed), dtype=F64
    )
    model = PoseProMP(num_basis=10, num_steps=250, dtype=F64)
    model.fit(demos, reference=torch.tensor(beam.start_quaternion, dtype=F64))
    return beam, model


def via_angles(beam: BeamWindowTask, q: torch.Tensor, phases: torch.Tensor) -> torch.Tensor:
    """Angles (deg) of the quaternion path ``q (T, 4)`` to the four via orientations at ``phases
    (4,)``."""
    idx = (phases * (q.shape[0] - 1)).round().long()  # (4,)
    return torch.rad2deg(quaternion_distance(q[idx], beam.via_array(q)[:, 3:]))  # (4,)


def beam_problems(repeats: int, stage: str, seed: int = 0) -> list[Problem]:
    """The beam's two PRO stages (Sec. IV-A) from the demonstrations' ProMP: ``position`` (success:
    the mean's four via-point distances <= 5 mm) or ``orientation`` at the window phases of the
    demonstrations' mean position (success: the four via angles <= 2 degrees)."""
    out = []
    for r in range(repeats):
        beam, model = _beam_setup(r, seed)
        prim = model.position if stage == "position" else model.orientation
        n = prim.mean.shape[-1]
        mean, var = with_nuisance(prim.mean, prim.var)
        if stage == "position":
            via = beam.via_array(prim.mean)[:, :3]  # (4, 3)

            def costs(w, prim=prim, beam=beam, n=n):  # (..., N) -> (..., 4)
                return beam.position_costs(prim.trajectory(w[..., :n]))

            def success(w, prim=prim, beam=beam, n=n, via=via):
                x = prim.trajectory(w[:n])  # (T, 3)
                idx = (beam.window_phases(x) * (x.shape[0] - 1)).round().long()
                return bool(((x[idx] - via).norm(dim=-1) <= BEAM_POSITION_TOL).all())
        else:
            phases = beam.window_phases(model.position.mean_trajectory())  # (4,)

            def costs(w, prim=prim, beam=beam, n=n, z=phases):  # (..., N) -> (..., 4)
                return beam.orientation_costs(prim.trajectory(w[..., :n]), z)

            def success(w, prim=prim, beam=beam, n=n, z=phases):
                return bool(via_angles(beam, prim.trajectory(w[:n]), z).max() <= BEAM_ANGLE_TOL)

        out.append(Problem(f"beam_{stage}", r, mean, var, n, costs, success, 10, seed))
    return out


def arm_problems(
    repeats: int, seed: int = 0, can_objective: str | None = None, **task_overrides
) -> list[Problem]:
    """Single arm problems (Sec. IV-C): random environments whose start, the label-aware GP map of
    the experiment's demonstrations and priors, fails; the first ``repeats`` of them.
    ``task_overrides`` replace task settings (a test uses fewer priors). ``can_objective``
    (``"ee"``,
    ``"skeleton"``, ``"volume"``): the can objective the optimisers read instead of the task's; the
    problems (environments and starts) stay those of the task's own objective."""
    from protorch.experiments.arm_reach import prepare as prepare_arm

    # composed as the app composes it (the experiment's yaml alone lacks PRO's beta, which lives in
    # conf/experiment_optimizer/arm_reach/pro.yaml)
    st = experiment_settings("arm_reach", [f"task.{k}={v}" for k, v in task_overrides.items()])
    setup = prepare_arm(
        optimizer=st["optimizer"],
        task=st["task"],
        gp=st["gp"],
        promp=st["promp"],
        loop={"num_envs": 0},
        test={"num_envs": 1},
        dynamic={"episodes": 0},
    )
    data = setup.initial_data()
    gp = setup.env_map().fit(data.env, data.mean, data.var, data.label)
    task, promp = setup.task, setup.promp
    envs = task.sample_envs(
        10 * repeats, torch.Generator().manual_seed(54321 + SEED_STEP * seed), dtype=F64
    )  # (10R, 4)
    label = label_aware_mean(gp, promp, task, envs).label
    mu, var = gp.predict(envs, label)  # (10R, N)
    failing = (~task.success(promp.trajectory(mu), envs)).nonzero()[:, 0][:repeats].tolist()
    n = mu.shape[-1]
    if can_objective is not None:
        task = dataclasses.replace(task, can_objective=can_objective)  # success is the same check
    out = []
    for r, i in enumerate(failing):
        env = envs[i]
        mean, v = with_nuisance(mu[i], var[i])

        def costs(w, env=env):  # (..., N) -> (..., 3)
            return task.costs(promp.trajectory(w[..., :n]), env)

        def success(w, env=env):
            return bool(task.success(promp.trajectory(w[:n]), env))

        out.append(Problem("arm", r, mean, v, n, costs, success, 10, seed, promp, env, task))
    return out
