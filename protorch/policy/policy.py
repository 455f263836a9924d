"""A trained run as a policy for a control loop: environment and time -> reference joints.

``policy = protorch.load(run)`` gives a :class:`Policy`; at every tick of a control loop
``q_r, qd_r, qdd_r, label = policy.reference(env, t, q, qd)`` gives the reference position,
velocity and acceleration at time ``t`` (seconds since the motion started) for the environment
measured now. What it computes, per call:

1. **The map's answer for every class** (homotopy label) at ``env``: Eq. 7 of the environment
   map (:class:`ClassMeans`: with ``nearest_k`` each class keeps its neighbour set from call to
   call, a new set solved by rank-2 updates of the last set's inverse or the map's own
   :func:`~protorch.gp.kernels.posdef_cholesky`, and cached). Between decisions only the tracked
   class's mean is computed (one kernel vector, one product); the other classes' sets are brought
   up to date every ``decision_dt / 4`` and before a decision, which then rarely solves. Without
   ``nearest_k``
   (torch backend) the map's own cached solve is used; other maps through ``predict_mean``.
2. **The class choice with hysteresis of the moving test** (:mod:`protorch.control.arm_choice`,
   the same functions): every ``decision_dt`` seconds (the run's ``settings.dynamic.dt``) each
   class is scored and the current class is kept unless another one is better by more than
   ``switch_margin``. The arm's score: :func:`~protorch.control.arm_choice.rest_scores`, the
   objectives of the rest of the motion from the end effector of ``q`` (one pass of
   :class:`~protorch.policy.means.EndEffector`; ``q=None``: each class's own mean at
   ``t``); with ``check`` the plan check from ``q, qd``
   (:func:`~protorch.control.arm_choice.checked_choice`;
   a plan that bounds carried from the last full checks show clear is passed without placing the
   arm's capsules, :class:`~protorch.control.plan_memo.ClearanceMemo`: the same verdict).
   A user's own task: the summed objectives of each class's whole mean trajectory
   (:func:`~protorch.gp.model.label_aware_mean`). A map with one class has no choice to make.
3. **The reference**: the chosen class's mean at the phase ``z = min(t / duration, 1)`` and its
   exact time derivatives (basis values and derivatives computed in closed form); after
   ``duration`` the last point is held (velocity and acceleration 0).
4. **Continuity**: when the class or the environment changes, the mean jumps; the reference
   does not. The jump of the mean (position and velocity) is added to an offset that decays as a
   critically damped second-order system at rate ``blend`` (1/s): ``d(t) = (d0 + (v0 + w d0) s)
   exp(-w s)``, so ``q_r`` and ``qd_r`` are continuous and return to the mean within a few
   ``1 / blend`` seconds. The first call of a motion with the measured ``q`` starts the
   reference there the same way. At ``duration`` the velocity steps to 0 as the mean's does (the
   moving test's hold). At a fixed environment no offset arises: the reference is the mean.

:meth:`Policy.reset` starts a new motion (class, offset and time forgotten). ``t`` must not go
backwards within a motion (a smaller ``t`` than the last is taken as the last).

That is ``planner="inline"``: every call does items 1-4. With ``planner="thread"`` items 1-2 run
on a planner thread beside the caller and the call tracks the newest plan (items 3-4 in NumPy,
:mod:`protorch.policy.two_rate`), the reference held to the robot's velocity, acceleration and
jerk limits by default (``limits="auto"``, :mod:`protorch.policy.limits`; ``limits=False``: not).
"""

from __future__ import annotations

import gc
import math
from pathlib import Path

import torch
from torch import Tensor

from ..control.arm import arm_follow
from ..control.arm_choice import Follow
from ..control.episodes import check_timing
from ..control.plan_memo import ClearanceMemo, point_reach
from ..gp.model import EnvToProMP
from .choice import ClassChoice
from .export import write_program
from .limits import make_limiter
from .means import ClassMeans, EndEffector, basis3, decay_matrix
from .process_planner import ProcessPlanner
from .programs import write_programs
from .reference import MotionState, Reference
from .two_rate import Planner, Tracker, TwoRatePolicy

__all__ = ["DEFAULT_BLEND", "ClassMeans", "Policy", "Reference"]

DEFAULT_BLEND = 10.0  # 1/s, the offset's decay rate (the moving test's velocity-command gain)


class Policy(ClassChoice, TwoRatePolicy, EnvToProMP):
    """A trained run for a control loop (module docstring): an
    :class:`~protorch.gp.model.EnvToProMP` (``policy(env)``, ``policy.mean_trajectory(env)``)
    that also knows its task, the motion's duration and the class choice's settings.

    Args:
        promp, env_map, task_name: the trained map (as :class:`EnvToProMP`).
        task: the run's task (``None``: only a map with one class can give references).
        duration: seconds from phase 0 to phase 1 (the run's ``settings.dynamic.duration``).
        switch_margin: the class choice's hysteresis (summed objectives).
        decision_dt: seconds between class decisions (the run's control step
        ``settings.dynamic.dt``).
        check: pass over an arm class whose plan for the rest of the motion touches the can while
            another's is clear (the run's ``settings.dynamic.check``;
            :func:`~protorch.control.arm_choice.rest_blocked`).
        blend: decay rate (1/s) of the offset that keeps the reference continuous (``inf``: no
            offset, the reference is the chosen mean itself and jumps with it).
        kp, max_acceleration: the moving test's velocity command (gain 1/s; limit, ``None``: the
            robot's) that the plan check rolls out from the measured joints (the run's settings).
        warm_up: call :meth:`reference` a few times now so that the first real call is not slower,
        then
            collect Python's garbage: a full collection (~0.1 s over what torch's import leaves)
            now, not in a call.
        planner: ``"inline"`` (every call makes its own class choice: the moving test's, exactly) or
            ``"thread"`` (a planner thread beside the caller makes them every ``plan_period``
            seconds,
            ``decision_dt / 4`` by default, and :meth:`reference` tracks its newest plan:
            :mod:`protorch.policy.two_rate`) or ``"process"`` (the same planner in a forked child
            process, inputs and plans in shared memory: no GIL shared with the caller;
            :mod:`protorch.policy.process_planner`).
        limits: keep the reference within the robot's velocity, acceleration and jerk limits at
            every call (``planner="thread"`` or ``"process"``): ``"auto"`` (the default),
            :class:`~protorch.policy.limits.JointwiseLimiter` for the two-rate planners where the
            robot states its limits, none inline (the moving test's reference, unlimited, exactly)
            or without a robot; ``True`` or ``"joint"``,
            :class:`~protorch.policy.limits.JointwiseLimiter` (a Ruckig hand-over per joint where
            the wanted reference leaves the limits, each joint back on it as soon as it can);
            ``"together"``, :class:`~protorch.policy.limits.JerkLimiter` (one hand-over of all
            joints, time-synchronised: every joint as slow as the slowest, which costs the moving
            test 0.05-0.10 of its success, docs/control_loop_moving.md); ``False``: none
            (:func:`~protorch.policy.limits.make_limiter`).
            ``max_velocity``, ``max_jerk`` (and
            ``max_acceleration``): the limits, ``None``: the robot's
            (:func:`~protorch.policy.limits.robot_limits`).
    """

    def __init__(
        self,
        promp,
        env_map,
        task_name: str = "",
        *,
        task=None,
        duration: float = 3.0,
        switch_margin: float = 0.0,
        decision_dt: float = 0.02,
        blend: float = DEFAULT_BLEND,
        warm_up: bool = True,
        experiment: str = "",
        check: bool = False,
        kp: float = 10.0,
        max_acceleration=None,
        switch_clearance: float = 0.0,
        planner: str = "inline",
        limits: bool | str = "auto",
        max_velocity=None,
        max_jerk=None,
        plan_period: float | None = None,
    ) -> None:
        super().__init__(promp, env_map, task_name)
        if planner not in ("inline", "thread", "process"):
            raise ValueError(f"planner must be 'inline', 'thread' or 'process', got {planner!r}")
        for name, v in (("duration", duration), ("decision_dt", decision_dt), ("blend", blend)):
            if not (
                isinstance(v, (int, float)) and (math.isfinite(v) or name == "blend") and v > 0
            ):
                raise ValueError(f"{name} must be a finite number > 0 (blend: or inf), got {v!r}")
        for name, v in (("switch_margin", switch_margin), ("switch_clearance", switch_clearance)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        self.task, self.experiment = task, experiment
        self.duration, self.switch_margin = float(duration), float(switch_margin)
        self.decision_dt, self.blend = float(decision_dt), float(blend)
        self.check, self.switch_clearance = bool(check), float(switch_clearance)
        self.means = ClassMeans(env_map)
        self._env_dim = self.env_dim
        self.labels = self.means.labels  # (K,)
        kw = {"dtype": torch.float64, "device": promp.basis.device}
        self._P = promp.to(torch.float64) if promp.basis.dtype != torch.float64 else promp
        self._d, self._kb = promp.num_dof, promp.num_basis
        self._device = promp.basis.device
        arm = (
            task is not None
            and callable(getattr(task, "ee_path", None))
            and callable(getattr(task, "path_costs", None))
        )
        self._follow, self._arm = None, arm
        if arm:
            self._grid = self._P.phase[task.cost_indices(promp.num_steps)].to(
                **kw
            )  # (P,) the objectives' phases
            self._grid_list = self._grid.tolist()
            self._phi_grid = self._P.basis_at(self._grid).to(
                **kw
            )  # (P, K) the basis there, for every decision
            kin = getattr(task, "kinematics", None)
            fold = callable(getattr(task, "ee_from_kinematics", None)) and task.ee_from_kinematics()
            self._ee = (
                EndEffector(kin, device=self._device) if fold else task.ee_path
            )  # (P, J) -> (P, 3)
            robot_amax = getattr(getattr(task, "robot", None), "max_acceleration", None)
            if kin is not None and (
                max_acceleration is not None or robot_amax is not None
            ):  # the moving test's
                timing = check_timing(
                    self.decision_dt, self.duration, 0.0
                )  # velocity command, for the check's rollout
                self._follow = arm_follow(task, kp, max_acceleration, timing, tables={}, **kw)
        self._label_list = self.labels.tolist()
        plan = (
            getattr(task, "capsule_plan", None) if arm else None
        )  # the plan check's bounds carried between decisions
        self._memo = ClearanceMemo(point_reach(task.kinematics, plan)) if plan is not None else None
        # the other classes' neighbour sets are kept fresh between decisions (a decision then
        # rarely has a new set to solve): every refresh_dt seconds, on calls that solved nothing
        self._refresh_dt = self.decision_dt / 4
        # the basis and its derivatives at every whole millisecond of the motion (a 1 kHz loop's
        # calls), scaled to time derivatives: (T_ms + 1, 3, K)
        ms = torch.arange(math.floor(self.duration * 1000) + 1, **kw) * 1e-3
        self._scale = torch.tensor([1.0, 1.0 / self.duration, 1.0 / self.duration**2], **kw)[
            :, None
        ]  # (3, 1)
        self._phi_ms = basis3(self._P, ms / self.duration) * self._scale
        self._phi_end = basis3(self._P, 1.0)  # (3, K)
        self._phi_end[1:] = 0.0  # held: no velocity, no acceleration
        self._decays: dict = {}
        self._at_jump = self._decay(0.0) if math.isfinite(self.blend) else None  # (3, 2)
        robot = getattr(task, "robot", None)
        self.planner = planner
        given = dict(
            max_velocity=max_velocity, max_acceleration=max_acceleration, max_jerk=max_jerk
        )
        self._limiter = make_limiter(limits, planner, robot, self._d, **given)
        # the limits of the two halves (planner="thread"), written beside the exported programs
        self._halves_limiter = (
            self._limiter
            if planner != "inline"
            else make_limiter(limits, "thread", robot, self._d, **given)
        )
        self._planner = self._tracker = None
        if planner != "inline" and task is None and self.labels.numel() > 1:
            raise ValueError(
                f"planner={planner!r} on a map with several classes needs the run's task"
            )
        self._motion = 0
        self.reset()
        if warm_up and (task is not None or self.labels.numel() == 1):
            self._warm_up()  # the inline path, which the planner runs
        if planner != "inline":
            self._tracker = Tracker(
                self._phi_ms.cpu().numpy(),
                self._P.centers.to(torch.float64).cpu().numpy(),
                float(self._P.width),
                self.duration,
                self.blend,
                self._limiter,
            )
            period = self.decision_dt / 4 if plan_period is None else float(plan_period)
            if planner == "process":
                self._planner = ProcessPlanner(self, period)
            else:
                self._planner = Planner(self._plan, period)
            self.reset()

    # ----------------------------------------------------------------- state
    def reset(self, env=None, q=None, qd=None) -> None:
        """Start a new motion: no class chosen, no offset, no time. With ``planner="thread"`` and
        ``env`` given (``q``, ``qd`` optional, as :meth:`reference`'s), the motion's first plan is
        made now, at ``t = 0``, so that the first call of the loop does not make it."""
        if self._planner is None:
            self._reset_choice()
            return
        self._tracker.reset()
        self._motion = self._planner.new_motion(self._reset_choice)
        if env is not None:
            env, _, q, qd = self._check_np(env, 0.0, q, qd)
            if self.planner == "process":  # the child makes it (its class choice is its own)
                self._planner.inbox = (self._motion, env, 0.0, q, qd)
                self._planner.wait_plan(self._motion)
                return
            with self._planner.lock:
                self._planner.plan = self._plan(self._motion, env, 0.0, q, qd)

    def _reset_choice(self) -> None:
        self._m = MotionState()
        if self._memo is not None:
            self._memo.reset()
        if self.means.mode == "nearest":
            self.means.reset()

    def close(self) -> None:
        """Stop the planner thread (``planner="thread"``; nothing otherwise)."""
        if self._planner is not None:
            self._planner.close()

    @property
    def current(self) -> int | None:
        """The row (into :attr:`labels`) of the class tracked now (``None`` before the
        first call)."""
        return self._m.current

    def _warm_up(self) -> None:
        gen = torch.Generator().manual_seed(0)
        sample = getattr(self.task, "sample_envs", None)
        envs = sample(3, gen) if callable(sample) else self.env_map.E[:3]
        envs = envs.to(torch.float64)
        for e in envs:
            for t in (0.0, 0.5 * self.duration, 2 * self.decision_dt):
                self.reference(e, t)
            self.reset()
        for i in range(41):  # a walk from one to the next: neighbour sets swapped, decisions made
            self.reference(envs[0] + (envs[1] - envs[0]) * (i / 40), i * 1e-3)
        self.reset()
        # the full collection now, not in the loop's first seconds (its counts start afresh)
        gc.collect()

    # ----------------------------------------------------------------- checks
    def _joints(self, x, name: str, like: Tensor) -> Tensor | None:
        if x is None:
            return None
        if not isinstance(x, Tensor):
            x = torch.as_tensor(x, dtype=torch.float64)
        if x.shape != (self._d,):
            raise ValueError(
                f"{name} must be ({self._d},) joint values, got shape {tuple(x.shape)}"
            )
        if x.dtype != like.dtype or x.device != like.device:
            x = x.to(like)
        if not all(map(math.isfinite, x.tolist())):
            raise ValueError(f"{name} holds NaN or inf: {x.tolist()}")
        return x

    def _check(self, env, t, q, qd=None) -> tuple[Tensor, float, Tensor | None, Tensor | None]:
        d = self.env_dim
        if not isinstance(env, Tensor):
            env = torch.as_tensor(env, dtype=torch.float64)
        if env.shape != (d,):
            raise ValueError(
                f"env must be ({d},) for task {self.task_name!r} (env_dim {d}), got shape "
                f"{tuple(env.shape)}"
            )
        if env.dtype != torch.float64 or env.device != self._device:
            env = env.to(dtype=torch.float64, device=self._device)
        point = env.tolist()
        if not all(map(math.isfinite, point)):
            raise ValueError(f"env holds NaN or inf: {point}")
        t = float(t)
        if not math.isfinite(t) or t < 0:
            raise ValueError(
                f"t must be a finite time >= 0 (seconds since the motion started), got {t!r}"
            )
        return env, t, self._joints(q, "q", env), self._joints(qd, "qd", env), point

    # ----------------------------------------------------------------- the reference
    def reference(self, env, t, q=None, qd=None) -> Reference:
        """The reference at time ``t`` for the environment ``env`` (module docstring).

        Args:
            env: ``(env_dim,)`` the environment measured now (float64 is used).
            t: seconds since the motion started (:meth:`reset`), ``>= 0``; past ``duration`` the
                last point of the mean is held (velocity and acceleration 0).
            q: ``(D,)`` the measured joints (the arm's class choice scores the rest of the motion
            from
                their end effector, as the moving test); ``None``: the arm taken to be on each
                class's mean.
            qd: ``(D,)`` the measured joint velocities (``None``: 0; the plan check rolls the arm
            out from
                ``q, qd``). A motion's first call with ``q`` starts the reference at ``q, qd`` (the
                gap
                decays as the continuity offset does).
        Returns:
            :class:`Reference` ``(q, qd, qdd (D,), label)``.
        """
        if self._planner is not None:
            return self._track(env, t, q, qd)
        env, t, q, qd, point = self._check(env, t, q, qd)
        m = self._m
        t = max(t, m.t)
        with (
            torch.inference_mode()
        ):  # cheaper per operation than no_grad (no version counters, no views tracked)
            phi = self.basis_at(t)  # (3, K)
            c, w = self.choose(env, t, q, point, phi, qd)  # w (1, N)
            state = torch.mm(
                phi, w.view(self._d, self._kb).T
            )  # (3, D) position, velocity, acceleration
            if self.blend < math.inf:
                jump = None
                if (
                    m.w is not None
                ):  # the mean's change since the last call (0 at a fixed environment)
                    jump = torch.mm(phi[:2], (m.w - w).view(self._d, self._kb).T)  # (2, D)
                elif q is not None:  # start where the arm is
                    v = torch.zeros_like(q) if qd is None else qd
                    jump = torch.stack([q - state[0], v - state[1]])  # (2, D)
                off = m.off
                if off is not None:  # the offset decays from the last call to now, the jump added
                    dec = self._decay(t - m.t, 2)  # (2, 2)
                    off = torch.mm(dec, off) if jump is None else torch.addmm(jump, dec, off)
                else:
                    off = jump
                if off is not None:
                    m.off = off
                    state = torch.addmm(
                        state, self._at_jump, off
                    )  # (3, D) the offset now and its acceleration
            m.w, m.t = w, t
        state = (
            state.clone()
        )  # an ordinary tensor for the caller (inference tensors refuse in-place updates)
        return Reference(state[0], state[1], state[2], self._label_list[c], t)

    def basis_at(self, t: float) -> Tensor:
        """The basis and its time derivatives at ``t``: ``(3, K)`` (d/dt = d/dz / duration; from
        the table at a whole millisecond; past ``duration`` the last point, held)."""
        if t / self.duration >= 1.0:
            return self._phi_end
        i = round(t * 1000.0)
        if i < self._phi_ms.shape[0] and i * 1e-3 == t:
            return self._phi_ms[i]
        return basis3(self._P, t / self.duration) * self._scale

    def _decay(self, s: float, rows: int = 3) -> Tensor:
        """The critically damped decay (module docstring, item 4) as a matrix: ``(rows, 2)``
        maps an offset ``(d0, v0) (2, D)`` to its position, velocity (and acceleration) ``s``
        seconds later (the few intervals of a fixed-rate loop are kept)."""
        key = (s, rows)
        hit = self._decays.get(key)
        if hit is None:
            if len(self._decays) >= 64:
                self._decays.clear()
            hit = self._decays[key] = decay_matrix(self.blend, s, rows, self._device)
        return hit

    @property
    def follow(self) -> Follow | None:
        """The moving test's velocity command the plan check rolls out (gain, the joints' velocity
        and acceleration limits, the control step; ``None`` for a task without them)."""
        return self._follow

    # ----------------------------------------------------------------- out of Python
    def export(self, path, *, aoti: bool | str = False) -> Path:
        """A folder (``path`` not ending in ``.pt2``): both halves of ``planner="thread"`` as
        programs, ``planner.pt2`` and ``tracker.pt2``, with the state each keeps between calls
        passed in and out (:mod:`~protorch.policy.programs`; ``aoti=True``: AOTInductor
        packages, ``aoti="tracker"``: the tracker only). A ``.pt2`` file: the one-call program
        below.

        Write the per-call computation as a ``torch.export`` program (``.pt2``) that runs
        without protorch: ``torch.export.load(path).module()(env, t)`` (``env`` a float64
        ``(env_dim,)`` tensor, ``t`` a float64 0-d tensor) returns ``(q, qd, qdd (D,), label (0-d
        int64))``, what :meth:`reference` returns right after :meth:`reset` with ``q=None``: the
        class chosen afresh at every call (the hysteresis and the continuity offset, which need the
        last call, stay with the caller). Inside: the map's data (with ``nearest_k`` each call finds
        the neighbours and solves, without the jitter retry of a failing factor), the ProMP's basis
        and, for the arm, the objectives of the rest of the motion for every slot of the
        objectives' grid. Inputs are not checked by the program. Written atomically.

        ``aoti=True``: the program compiled ahead of time by AOTInductor into a package (minutes
        for an arm map) that ``torch._inductor.aoti_load_package(path)`` runs from Python, and
        libtorch's ``torch::inductor::AOTIModelPackageLoader`` from C++, on a machine of this
        one's kind (:func:`~protorch.policy.export.write_program`)."""
        if self.labels.numel() > 1 and self.task is None:
            raise ValueError(
                "this map has several classes: exporting the class choice needs the run's task"
            )
        path = Path(path)
        if path.suffix != ".pt2":
            return write_programs(self, path, aoti=aoti)
        return write_program(self, path, aoti=bool(aoti))

    # ----------------------------------------------------------------- whole trajectories
    def mean_trajectory(self, env: Tensor, labels=None) -> Tensor:
        """``(B, d)`` -> mean trajectories ``(B, T, D)``, or ``(d,)`` -> ``(T, D)``; with several
        classes and ``labels=None`` each environment's class is the one :meth:`reference` tracks
        at that fixed environment right after :meth:`reset` (:meth:`first_class`: the moving
        test's first decision, ``q=None``), so that the two give one answer. The held-out test's
        label-aware inference (the lowest summed objectives of each class's whole mean, its plan
        check first) can differ from it at a few environments:
        :func:`~protorch.gp.model.label_aware_mean` gives that one."""
        single = isinstance(env, Tensor) and env.dim() == 1
        if single:
            env = env[None]
            labels = None if labels is None else torch.as_tensor(labels).reshape(1)
        if labels is None and self.labels.numel() > 1:
            if self.task is None:
                raise ValueError(
                    f"the data has several labels {self.labels.tolist()}: pass labels=, or load "
                    "the "
                    "run folder (with its config.yaml) so that the class is chosen by its task"
                )
            labels = self.labels[[self.first_class(e) for e in env]].to(env.device)
        out = super().mean_trajectory(env, labels)
        return out[0] if single else out

    def extra_repr(self) -> str:
        return (
            f"{super().extra_repr()}, experiment={self.experiment!r}, classes="
            f"{self.labels.tolist()}, "
            f"duration={self.duration:g}, switch_margin={self.switch_margin:g}, decision_dt="
            f"{self.decision_dt:g}, "
            f"check={self.check}, switch_clearance={self.switch_clearance:g}"
        )
