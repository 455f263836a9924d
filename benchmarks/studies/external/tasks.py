"""fancy_gym's ProMP tasks as black-box objectives: one episode per weight vector, one context per
``env.reset(seed=context)`` (needs the external venv: ``bash
benchmarks/studies/external/setup.sh``).

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
    raise ValueError(
        f"unknown task {name!r}; choose one of {sorted(TASKS)} (or their fancy_gym ids)"
    )


def short_name(name: str) -> str:
    return {v: k for k, v in TASKS.items()}.get(name, name)


def patch_via_point_reward() -> None:
    """Make ViaPointReacher's non-evaluation steps cost their acceleration term only
    (see module)."""
    from fancy_gym.envs.classic_control.viapoint_reacher.viapoint_reacher import ViaPointReacherEnv

    if getattr(ViaPointReacherEnv, "_protorch_patched", False):
        return
    original = ViaPointReacherEnv._get_reward

    def _get_reward(self, acc):
        reward, info = original(self, acc)
        if reward == -math.inf and not info["is_collided"]:
            target = {100: self._via_point, 199: self._goal}.get(self._steps)
            dist = 0.0 if target is None else float(np.linalg.norm(self.end_effector - target))
            reward = -(dist**2) - 5e-8 * float(np.sum(np.asarray(acc) ** 2))
        return reward, info

    ViaPointReacherEnv._get_reward = _get_reward
    ViaPointReacherEnv._protorch_patched = True


def make_env(name: str, fast: bool = True):
    """The gymnasium env of a task (warnings of fancy_gym's wrappers silenced); ``fast``: the same
    env with its per-step overheads removed (:func:`speed_up`: the same episodes, bit for bit)."""
    import logging
    import warnings

    warnings.filterwarnings("ignore")
    logging.getLogger().setLevel(logging.ERROR)
    import fancy_gym  # noqa: F401  (registers the ids)
    import gymnasium as gym

    patch_via_point_reward()
    env = gym.make(task_id(name))
    return speed_up(env) if fast else env


def speed_up(env):
    """Remove what a reacher episode spends outside its dynamics, without changing any number.

    Profiled (docs/external.md, "The harness's speed"), a ViaPointReacher episode spent about a
    third of its time in gymnasium 0.29's wrapper attribute look-ups: fancy_gym's black-box wrapper
    reads ``current_pos`` and ``current_vel`` through ``get_wrapper_attr`` (which builds
    ``dir(wrapper)``) four times a step, and each read passes three wrappers whose ``__getattr__``
    formats and issues a deprecation warning (filtered out, but paid for). A third went to the
    self-collision test, run twice a step on the same state (once by ``step``, again by the reward)
    with numpy scalars; HoleReacher repeats its wall test the same way. This swaps, per instance,
    every wrapper's class for a subclass whose look-ups skip the warning and ``dir`` (same answers),
    and the reacher's class for one that computes each collision test once per state, the
    self-collision one with fancy_gym's own ``intersect`` on Python floats (the same IEEE double
    operations). Box pushing keeps its env class (its time is MuJoCo's)."""
    import gymnasium as gym

    layer = env
    while isinstance(layer, gym.Wrapper):
        layer.__class__ = _quiet(type(layer))
        layer = layer.env
    base = env.unwrapped
    if hasattr(base, "_check_self_collision") and hasattr(base, "_joints"):
        base.__class__ = _memo_collisions(type(base))
    return env


_QUIET: dict[type, type] = {}


def _quiet(cls: type) -> type:
    """``cls`` (a gymnasium Wrapper) with attribute look-ups that skip the deprecation warning and
    ``dir()``: the same attribute found, the same errors raised."""
    if getattr(cls, "_protorch_quiet", False):
        return cls
    if cls not in _QUIET:

        def __getattr__(self, name):
            if name.startswith("_"):  # gymnasium's own refusal (private names, _np_random)
                return cls.__getattr__(self, name)
            return getattr(self.env, name)

        in_class: dict[str, bool] = {}

        def get_wrapper_attr(self, name):
            # gymnasium: `name in self.__dir__()`; object.__dir__ lists the instance's __dict__
            # and the __dict__ of every class of the MRO (fixed once the class is made)
            if name not in in_class:
                in_class[name] = any(name in vars(k) for k in type(self).__mro__)
            if in_class[name] or name in self.__dict__:
                return getattr(self, name)
            return self.env.get_wrapper_attr(name)

        import gymnasium as gym

        body = {"_protorch_quiet": True, "__module__": cls.__module__}
        if cls.__getattr__ is gym.Wrapper.__getattr__:  # a wrapper's own look-up is left alone
            body["__getattr__"] = __getattr__
        if cls.get_wrapper_attr is gym.Wrapper.get_wrapper_attr:
            body["get_wrapper_attr"] = get_wrapper_attr
        _QUIET[cls] = type(cls.__name__, (cls,), body)
    return _QUIET[cls]


_MEMO: dict[type, type] = {}


def _memo_collisions(cls: type) -> type:
    """``cls`` (a fancy_gym reacher) whose collision tests run once per state: a state is the joint
    angle array ``step`` has just assigned (a new array every step) at one step count."""
    if getattr(cls, "_protorch_memo", False):
        return cls
    if cls not in _MEMO:
        from fancy_gym.envs.classic_control.utils import intersect

        def once(self, kind, compute):
            memo = self.__dict__.setdefault("_protorch_collisions", {})
            key = (kind, self._steps)
            hit = memo.get(key)
            if hit is not None and hit[0] is self._joint_angles:
                return hit[1]
            if len(memo) > 8:  # keep only this step's answers
                memo.clear()
            value = compute()
            memo[key] = (self._joint_angles, value)  # holds the array: `is` stays meaningful
            return value

        def _check_self_collision(self):
            def compute():
                if self.allow_self_collision:
                    return False
                if np.any(self._joint_angles > self.j_max) or np.any(
                    self._joint_angles < self.j_min
                ):
                    return True
                pts = (
                    self._joints.tolist()
                )  # (n_links + 1, 2) floats: link i runs pts[i] -> pts[i + 1]
                n = len(pts) - 1
                return any(
                    intersect(pts[i], pts[i + 1], pts[j], pts[j + 1])
                    for i in range(n)
                    for j in range(i + 2, n)
                )

            return once(self, "self", compute)

        body = {
            "_check_self_collision": _check_self_collision,
            "_protorch_memo": True,
            "__module__": cls.__module__,
        }
        if hasattr(cls, "check_wall_collision"):
            body["check_wall_collision"] = lambda self: once(
                self, "wall", lambda: cls.check_wall_collision(self)
            )

        def reset(self, *args, **kwargs):
            self.__dict__.pop("_protorch_collisions", None)
            return cls.reset(self, *args, **kwargs)

        body["reset"] = reset
        _MEMO[cls] = type(cls.__name__, (cls,), body)
    return _MEMO[cls]


@dataclass
class Outcome:
    """One episode: its return, the task's success and (box pushing) the box's final distances."""

    ret: float
    success: bool
    pos_dist: float = float("nan")
    rot_dist: float = float("nan")


def set_box_goal(env, goal) -> None:
    """Put box pushing's goal pose at ``goal = (x, y, yaw)`` (metres, radians about z), after a
    reset.

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
    last = {
        k: np.asarray(v).reshape(-1)[-1]
        for k, v in info.items()
        if k in ("is_success", "box_goal_pos_dist", "box_goal_rot_dist") and np.size(v)
    }
    return Outcome(
        float(ret),
        bool(last.get("is_success", False)),
        float(last.get("box_goal_pos_dist", math.nan)),
        float(last.get("box_goal_rot_dist", math.nan)),
    )


class Episodes:
    """Evaluates batches of weights on one task, in this process (``workers=1``) or spread over a
    pool of processes, each holding its own env."""

    def __init__(self, name: str, workers: int = 1, fast: bool = True) -> None:
        self.name = task_id(name)
        self.workers = int(workers)
        self.env = make_env(self.name, fast) if self.workers <= 1 else None
        self.pool = None
        if self.workers > 1:
            import multiprocessing as mp

            self.pool = mp.get_context("spawn").Pool(
                self.workers, initializer=_init_worker, initargs=(self.name, fast)
            )

    @property
    def num_weights(self) -> int:
        env = self.env or make_env(self.name, fast=False)
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


def _init_worker(name: str, fast: bool = True) -> None:
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    global _ENV
    _ENV = make_env(name, fast)


def _worker_episode(weights: np.ndarray, context: int, goal=None) -> Outcome:
    return run_episode(_ENV, weights, context, goal)
