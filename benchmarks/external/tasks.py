"""fancy_gym's ProMP tasks as black-box objectives: one episode per weight vector, one context per
``env.reset(seed=context)`` (needs the external venv: ``bash benchmarks/external/setup.sh``).

An episode: ``env.reset(seed=context)`` then one ``env.step(weights)``, which runs the whole
ProMP trajectory with the task's own tracking controller and returns the episode's return and
per-step ``info``. Success is the task's own ``info["is_success"]`` at the last executed step
(box pushing: box within 5 cm and 0.5 rad of its goal pose; hole reacher: tip within 5 mm of the
hole's bottom, no collision; via-point reacher: tip within 5 mm of the goal at the last step).

fancy_gym 0.3.0's ViaPointReacher returns ``-inf`` at every step unless the arm collides, whatever
the weights (its reward starts at ``-inf``, and its distance term is ``inf`` at the steps that
are neither the via point's, 100, nor the goal's, 199), so every return is ``-inf`` or the
collision penalty and no optimiser can rank its samples. :func:`patch_via_point_reward` gives a
step without a collision the reward the code evidently means: minus the squared distance to the
via point at step 100 and to the goal at step 199 (0 at the other steps), minus the same
acceleration term. The return is then finite, the task's penalty of 1,000 on a collision kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TASKS = {  # short name -> fancy_gym id
    "box_pushing": "fancy_ProMP/BoxPushingDense-v0",
    "hole_reacher": "fancy_ProMP/HoleReacher-v0",
    "via_point_reacher": "fancy_ProMP/ViaPointReacher-v0",
}


def task_id(name: str) -> str:
    """A fancy_gym id from a short name of :data:`TASKS` or the id itself."""
    if name in TASKS:
        return TASKS[name]
    if name in TASKS.values():
        return name
    raise ValueError(f"unknown task {name!r}; choose one of {sorted(TASKS)} (or their fancy_gym ids)")


def short_name(name: str) -> str:
    return {v: k for k, v in TASKS.items()}.get(name, name)


def patch_via_point_reward() -> None:
    """Make ViaPointReacher's non-evaluation steps cost their acceleration term only (see module)."""
    from fancy_gym.envs.classic_control.viapoint_reacher.viapoint_reacher import ViaPointReacherEnv

    if getattr(ViaPointReacherEnv, "_protorch_patched", False):
        return
    original = ViaPointReacherEnv._get_reward

    def _get_reward(self, acc):
        reward, info = original(self, acc)
        if reward == -math.inf and not info["is_collided"]:
            target = {100: self._via_point, 199: self._goal}.get(self._steps)
            dist = 0.0 if target is None else float(np.linalg.norm(self.end_effector - target))
            reward = -dist**2 - 5e-8 * float(np.sum(np.asarray(acc) ** 2))
        return reward, info

    ViaPointReacherEnv._get_reward = _get_reward
    ViaPointReacherEnv._protorch_patched = True


def make_env(name: str):
    """The gymnasium env of a task (warnings of fancy_gym's wrappers silenced)."""
    import logging
    import warnings

    warnings.filterwarnings("ignore")
    logging.getLogger().setLevel(logging.ERROR)
    import fancy_gym  # noqa: F401  (registers the ids)
    import gymnasium as gym

    patch_via_point_reward()
    return gym.make(task_id(name))


@dataclass
class Outcome:
    """One episode: its return, the task's success and (box pushing) the box's final distances."""

    ret: float
    success: bool
    pos_dist: float = float("nan")
    rot_dist: float = float("nan")


def set_box_goal(env, goal) -> None:
    """Put box pushing's goal pose at ``goal = (x, y, yaw)`` (metres, radians about z), after a reset.

    fancy_gym 0.3.0's ``BoxPushingEnvBase.reset_model`` draws the goal and writes it into the MuJoCo
    model's bodies ``target_pos`` and ``replan_target_pos`` (position and quaternion, ``w`` first);
    success and reward read ``replan_target_pos``. This writes both the same way (``z = -0.01``, as
    the env's own goals) and recomputes the derived quantities with ``mj_forward``."""
    import mujoco

    u = env.unwrapped
    x, y, yaw = (float(v) for v in goal)
    quat = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    for body in ("target_pos", "replan_target_pos"):
        i = u.model.body(body).id
        u.model.body_pos[i] = (x, y, -0.01)
        u.model.body_quat[i] = quat
    mujoco.mj_forward(u.model, u.data)


def run_episode(env, weights: np.ndarray, context: int, goal=None) -> Outcome:
    """``env.reset(seed=context)`` (then, for box pushing, the goal pose ``goal = (x, y, yaw)`` if
    given: :func:`set_box_goal`) then one black-box step with ``weights (N,)``."""
    env.reset(seed=int(context))
    if goal is not None:
        set_box_goal(env, goal)
    _, ret, _, _, info = env.step(np.asarray(weights, dtype=np.float64))
    last = {k: np.asarray(v).reshape(-1)[-1] for k, v in info.items()
            if k in ("is_success", "box_goal_pos_dist", "box_goal_rot_dist") and np.size(v)}
    return Outcome(float(ret), bool(last.get("is_success", False)),
                   float(last.get("box_goal_pos_dist", math.nan)), float(last.get("box_goal_rot_dist", math.nan)))


class Episodes:
    """Evaluates batches of weights on one task, in this process (``workers=1``) or spread over a
    pool of processes, each holding its own env."""

    def __init__(self, name: str, workers: int = 1) -> None:
        self.name = task_id(name)
        self.workers = int(workers)
        self.env = make_env(self.name) if self.workers <= 1 else None
        self.pool = None
        if self.workers > 1:
            import multiprocessing as mp

            self.pool = mp.get_context("spawn").Pool(self.workers, initializer=_init_worker, initargs=(self.name,))

    @property
    def num_weights(self) -> int:
        env = self.env or make_env(self.name)
        return int(env.action_space.shape[0])

    def __call__(self, weights: np.ndarray, context: int, goals=None) -> list[Outcome]:
        """``weights (S, N)`` -> ``S`` outcomes, each from its own reset to ``context`` (and box
        pushing's goal pose ``goals[s] = (x, y, yaw)``, if given: ``(S, 3)``)."""
        goals = [None] * len(weights) if goals is None else goals
        if self.pool is None:
            return [run_episode(self.env, w, context, g) for w, g in zip(weights, goals)]
        return self.pool.starmap(_worker_episode, [(w, context, g) for w, g in zip(weights, goals)])

    def close(self) -> None:
        if self.pool is not None:
            self.pool.close()
            self.pool.join()


_ENV = None


def _init_worker(name: str) -> None:
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    global _ENV
    _ENV = make_env(name)


def _worker_episode(weights: np.ndarray, context: int, goal=None) -> Outcome:
    return run_episode(_ENV, weights, context, goal)
