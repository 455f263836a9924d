"""Sec. IV-C of the paper: an arm (the robot setting: the Panda shipped with protorch by default,
or your own URDF, docs/your_own_robot.md) reaches a target on a table around a can, and switches
between passing it on the left and on the right on the fly.

1. Demonstrations: 20 environments x 3, hand-guided-like end-effector paths passing the can on
   alternating sides, turned into joint trajectories by inverse kinematics; one ProMP weight
   Gaussian per environment and side. Prior knowledge: 2004 environments on a grid (over the
   sampler's rectangles, or with ``task.prior_grid=table`` over the whole table within the arm's
   reach) with the straight end-effector path to the target (by IK) and the average demonstrated
   variance; with ``task.collision=volume`` only those clear of the can, plus detour priors on both
   sides (:mod:`protorch.tasks.arm.priors`).
   Every entry carries its homotopy class (:meth:`~protorch.tasks.ArmReachTask.side`) as label.
2. The self-improvement loop (:func:`protorch.loop.self_improve`, PRO) over 2024 random
   environments with the labeller: solutions are stored with their class, the GP map keeps the
   classes apart, a new environment starts from the class whose predicted mean has the lowest
   summed objectives. Checkpointed in ``<out_dir>/checkpoint`` (``protorch.load(out_dir)``),
   resumable.
3. Evaluation with the label-aware inference (the class whose mean passes the task's check,
   then the lowest summed objectives: :func:`~protorch.gp.model.label_aware_mean` with
   ``check=True``) on 200 held-out environments, and on 100
   episodes in which the can or the target is moved once or twice while the arm moves
   (:func:`protorch.control.arm.run_arm_episodes`: the map queried every control step, the arm
   switching classes when the objectives of the rest of the motion say so). When either
   ``task.prior_grid`` or ``task.region`` (where the loop's pool, the held-out test and the
   moving test draw; the demonstrations stay in the rectangles) is ``table``, the held-out test
   is also run on 200 environments drawn over the other region (``test.table`` or
   ``test.rectangles``). Baselines in the same run: ``labels_off``, the same learned data with
   the labels dropped (the GP averages neighbouring left and right solutions, as the paper's
   single map would), and
   ``labels_off_loop``, the whole loop run without labels (``<out_dir>/baselines/labels_off_loop``).
4. Figures: top view of both classes' end-effector paths around the can (and the labels-off
   average), a 3-D view of the arm along one trajectory, held-out success vs loop iteration,
   frames and a GIF of a moving episode in which the arm switches sides.
"""

from __future__ import annotations

import copy
from pathlib import Path

import torch

from ..checks import check_int
from ..control.arm import run_arm_episodes
from ..control.switches import geometric_switch_summary
from ..data.checkpoint import load
from ..data.demos import accept_demo_folder, read_marks
from ..data.recordings import Cleaning
from ..figures.arm import experiment_figures
from ..figures.recordings import recordings_figure
from ..gp.model import label_aware_mean
from ..loop import LoopResult, demonstration_dataset
from ..primitives.promp import resample
from ..robots import check_inertials, load_robot
from ..sim.scene import build_scene
from ..tasks.arm.demos import read_arm_demos
from ..tasks.arm.priors import check_detours, grid_priors
from ..tasks.arm.reach import LEFT, RIGHT, SIDES, ArmReachTask
from ..tasks.arm.workspace import REGIONS, check_reach, check_region
from .arm_physics import check_physics, physics_section
from .common import demo_source
from .loop_run import (
    DYNAMIC_SEED,
    TEST_SEED,
    Outcome,
    SelfImprovementExperiment,
    experiment_functions,
)

__all__ = [
    "run",
    "prepare",
    "check_robot",
    "Setup",
    "ArmReachExperiment",
    "TEST_SEED",
    "DYNAMIC_SEED",
]

_BASELINES = ("labels_off", "labels_off_loop")


class ArmReachExperiment(SelfImprovementExperiment):
    """The arm's parts of the skeleton (:class:`SelfImprovementExperiment`): the labelled IK
    demonstrations and the grid priors, the labeller, the label-aware test, the moving can and
    target, the labels-off baselines, the figures, the per-phase timings. ``benchmarks/arm.py``
    times :meth:`run_loop`."""

    task_keys = frozenset(
        {
            "_target_",
            "demos",
            "demo_envs",
            "demos_per_env",
            "priors",
            "cost_steps",
            "margin",
            "goal_tol",
            "start_tol",
            "can_radius",
            "can_height",
            "clearance",
            "deviation",
            "collision",
            "can_objective",
            "prior_clear",
            "prior_detours",
            "plan_margin",
            "prior_grid",
            "region",
            "reach",
            "can_box",
            "goal_box",
            "table",
            "recordings",
        }
    )
    loop_keys = frozenset({"labels", "each_label"})
    dynamic_keys = frozenset(
        {
            "seed",
            "episodes",
            "duration",
            "hold",
            "dt",
            "kp",
            "moves",
            "move_window",
            "place_clearance",
            "switch_margin",
            "check",
            "switch_clearance",
        }
    )
    gp_defaults = {"alpha": 30.0, "var_floor": 1e-3, "nearest_k": 30}
    num_envs = 2024
    baseline_names = _BASELINES
    loop_baselines = frozenset({"labels_off_loop"})

    def __init__(self, *, physics: dict | None = None, robot=None, **settings) -> None:
        self.robot = load_robot(robot)  # the arm (robot.* settings; None: the Panda)
        super().__init__(**settings)
        self.physics_cfg = check_physics(physics, self.dyn_cfg)
        self.last_moving, self.out_dir, self.plot = None, None, True

    def run(self, out_dir: Path, **kw) -> dict:
        """The skeleton's run; remembers where, for the physics section's files."""
        self.out_dir, self.plot = Path(out_dir), kw.get("plot", True)
        return super().run(out_dir, **kw)

    def extra_tests(self, model) -> dict:
        """The physics section (:mod:`protorch.experiments.arm_physics`): the trained map's motions
        in MuJoCo."""
        out = {"physics": physics_section(self, model, self.out_dir, self.plot)}
        for key in ("seconds", "render_seconds"):
            if key in out["physics"]:
                self.seconds["physics" if key == "seconds" else "physics_render"] = out["physics"][
                    key
                ]
        return out

    def configure(self, task_cfg: dict, loop_cfg: dict) -> None:
        self.labels, self.each_label = (
            loop_cfg.get("labels", True),
            loop_cfg.get("each_label", True),
        )
        for name, v in (("labels", self.labels), ("each_label", self.each_label)):
            if not isinstance(v, bool):
                raise ValueError(f"loop.{name} must be true or false, got {v!r}")
        self.source = demo_source(task_cfg.pop("demos", "synthetic"))
        self.cleaning = Cleaning.from_config(task_cfg.pop("recordings", None))
        self.demo_envs_n = check_int(task_cfg.pop("demo_envs", 20), "task.demo_envs", 1)
        self.per_env = check_int(task_cfg.pop("demos_per_env", 3), "task.demos_per_env", 2)
        self.n_priors = check_int(task_cfg.pop("priors", 2004), "task.priors", 0)
        self.prior_over = check_region(task_cfg.pop("prior_grid", "rectangles"), "task.prior_grid")
        self.prior_clear = task_cfg.pop("prior_clear", "auto")
        if self.prior_clear not in (True, False, "auto"):
            raise ValueError(
                f"task.prior_clear must be true, false or auto, got {self.prior_clear!r}"
            )
        detours = task_cfg.pop("prior_detours", "auto")
        plan_margin = task_cfg.pop("plan_margin", None)
        check_region(task_cfg.get("region", "rectangles"), "task.region")
        self.nearest_k = self.map_options.get("nearest_k")
        task_cfg.pop("_target_", None)
        self.task = ArmReachTask(robot=self.robot, **task_cfg).to(self.device)
        if self.prior_clear == "auto":
            self.prior_clear = self.task.collision == "volume"
        self.prior_detours = check_detours(detours, self.task.collision)
        if (
            plan_margin is not None
        ):  # the loop accepts a solution only this far from the can; the tests keep `margin`
            if (
                isinstance(plan_margin, bool)
                or not isinstance(plan_margin, (int, float))
                or not plan_margin >= 0
            ):
                raise ValueError(
                    f"task.plan_margin must be null or a distance >= 0 (m), got {plan_margin!r}"
                )
            self.loop_task = copy.copy(self.task)
            self.loop_task.margin = float(plan_margin)

    def make_demonstrations(self) -> None:
        """The demonstrated environments are drawn over the rectangles whatever ``task.region``;
        or the folder ``task.demos`` (:func:`~protorch.tasks.arm.demos.read_arm_demos`)."""
        if self.source != "synthetic":
            folder, self.demo_labels = read_arm_demos(self.task, self.source, self.cleaning)
            accept_demo_folder(folder, self.demo_labels, label_names=SIDES)
            self.demos, self.demo_envs, self.demo_marked = (
                folder.demos,
                folder.envs,
                len(read_marks(self.source)),
            )
            self.recordings = folder
            return
        self.demo_marked, self.recordings = 0, None
        gen = self.demo_generator()
        envs = self.task.sample_envs(self.demo_envs_n, gen, region="rectangles")
        self.demos, self.demo_envs, self.demo_labels = self.task.demonstrations(
            envs, self.per_env, gen
        )

    def make_priors(self) -> None:
        self.prior_envs, self.prior_mean, self.prior_labels, self.prior_report = grid_priors(
            self.task,
            self.promp,
            self.n_priors,
            self.prior_over,
            clear=self.prior_clear,
            detours=self.prior_detours,
        )

    def build(self) -> "ArmReachExperiment":
        """The skeleton's build, plus the held-out environments of the other region when either
        the priors' grid or the task's region is the table (drawn with the same test seed)."""
        super().build()
        others = (
            [r for r in REGIONS if r != self.task.region]
            if "table" in (self.prior_over, self.task.region)
            else []
        )
        self.region_tests = {
            r: self.task.sample_envs(
                self.test_n,
                torch.Generator().manual_seed(self.test_seed),
                dtype=self.dtype,
                region=r,
            ).to(self.device)
            for r in others
        }
        return self

    def loop_options(self) -> dict:
        return {"sample_steps": self.task.cost_steps}

    def initial_data(self, labels: bool | None = None):
        """A fresh data set: the demonstrations (one entry per environment and side) and the
        priors (average demonstrated variance); every label 0 with ``labels=False``."""
        labels = self.labels if labels is None else labels
        ds = demonstration_dataset(
            self.promp,
            self.demos,
            self.demo_envs,
            task_name=self.task.name,
            var_floor=self.var_floor,
            dtype=self.promp.basis.dtype,
            labels=self.demo_labels if labels else None,
            lone="pool",
        )
        if self.prior_envs.shape[0]:
            vbar = ds.var.mean(0).expand_as(
                self.prior_mean
            )  # (P, N) the average demonstrated variance
            ds.append(
                self.prior_envs,
                self.prior_mean,
                vbar,
                label=self.prior_labels if labels else 0,
                origin="prior",
                converged=True,
            )
        return ds

    def loop_arguments(self, variant: str | None) -> dict:
        """PRO with the labeller, or ``variant="labels_off_loop"``: the same loop without labels."""
        labels = self.labels and variant != "labels_off_loop"
        cls, kwargs = self.optimizer
        return {
            "optimizer": cls,
            "optimizer_kwargs": kwargs,
            "dataset": self.initial_data(labels),
            "labeler": self.task.side if labels else None,
            "each_label": labels and self.each_label,
        }

    def describe(self) -> dict:
        lk, opt, data0 = self.loop, self.optimizer_cfg, self.initial_data()
        return {
            "robot": self.robot.summary(),
            "demos": {
                "source": str(self.source),
                "marked": self.demo_marked,
                "count": len(self.demos),
                "envs": int(self.demo_envs.unique(dim=0).shape[0]),
                "entries": int((data0.origin == 0).sum()),
                "left": int((self.demo_labels == LEFT).sum()),
                "right": int((self.demo_labels == RIGHT).sum()),
                "success_rate": self.demo_success(),
                **(
                    {"recordings": self.recordings.report}
                    if self.recordings and self.recordings.report
                    else {}
                ),
            },
            "priors": {
                "count": int(self.prior_envs.shape[0]),
                "left": int((self.prior_labels == LEFT).sum()),
                "right": int((self.prior_labels == RIGHT).sum()),
                "grid": self.prior_report,
            },
            "settings": {
                "num_envs": lk.num_envs,
                "batch_size": lk.batch_size,
                "add_only": lk.add_only,
                "choice": lk.choice,
                "alpha": self.alpha,
                "nearest_k": self.nearest_k,
                "beta": None if opt.get("beta") is None else float(opt["beta"]),
                "var_floor": self.var_floor,
                "labels": self.labels,
                "each_label": self.each_label,
                "max_iter": opt.get("max_iter"),
                "num_samples": opt.get("num_samples"),
                "threads": torch.get_num_threads(),
                "optimizer": opt.get("name", "pro"),
                "prior_grid": self.prior_over,
                "region": self.task.region,
            },
        }

    def demo_success(self) -> float:
        """Success of the demonstrations themselves (resampled to the ProMP's steps)."""
        traj = torch.stack([resample(d, self.promp.num_steps) for d in self.demos]).to(
            self.promp.basis
        )
        return float(self.task.success(traj, self.demo_envs.to(traj)).double().mean())

    def test_metrics(self, model) -> dict:
        """The held-out test over the task's region, and under the other region's name its test
        over that region (only when the table is involved, :meth:`build`)."""
        out = _test(self.task, model, self.test_envs, self.test_seed)
        if self.region_tests:
            out["region"] = self.task.region
        for region, envs in self.region_tests.items():
            out[region] = _test(self.task, model, envs, self.test_seed)
        return out

    def moving_test(self, model) -> tuple[dict, object]:
        """The can or the target moved while the arm moves
        (:func:`protorch.control.arm.run_arm_episodes`)."""
        if self.dyn_env0.shape[0] == 0:
            return {"success_rate": float("nan"), "episodes": 0, "switches": 0}, None
        res = run_arm_episodes(
            model,
            self.task,
            self.dyn_env0,
            generator=torch.Generator().manual_seed(self.dyn_seed),
            **self.dyn_cfg,
        )
        self.last_moving = res  # the physics section replays the trained map's episodes
        geometric = geometric_switch_summary(res, self.task) if res.weights is not None else {}
        return {**res.summary(), **geometric, "seed": self.dyn_seed}, res

    def loop_metrics(self, res: LoopResult) -> dict:
        learned = res.dataset.origin == 2
        lab = res.dataset.label[learned]
        return {
            **super().loop_metrics(res),
            "added": int(learned.sum()),
            "added_left": int((lab == LEFT).sum()),
            "added_right": int((lab == RIGHT).sum()),
        }

    def baseline(self, name: str, out_dir: Path, model) -> tuple[dict, object]:
        """``labels_off``: the trained map's data with every label 0 (left and right averaged)."""
        if name != "labels_off":
            return super().baseline(name, out_dir, model)
        off_model = load(out_dir, device=self.device, dtype=self.dtype)
        em = off_model.env_map
        em.fit(em.E, em.MU, em.VAR)
        test_m, dyn_m, _ = self.evaluate(off_model)
        return self.entry(test_m, dyn_m), off_model

    def figures(self, out_dir: Path, outcome: Outcome, metrics: dict) -> None:
        if self.recordings is not None and self.recordings.stages:
            recordings_figure(
                out_dir / "recordings.png", self.recordings, self.task.kinematics.joint_names
            )
        experiment_figures(
            out_dir,
            self.task,
            outcome.model,
            outcome.baselines.get("labels_off"),
            self.test_envs,
            outcome.result,
            outcome.baselines.get("labels_off_loop"),
            outcome.episodes,
            metrics,
        )

    def seconds_metrics(self) -> dict:
        return dict(self.seconds)


Setup = ArmReachExperiment  # what prepare() returns


_RUN_DOC = """Run the experiment into ``out_dir``; return the metrics (module docstring).

    ``task``: ``demos`` (``synthetic``, or a folder of ``trajK.out`` joint-angle rows and
    ``envK.out``
    ``can_x can_y goal_x goal_y`` files, e.g. written by ``python -m protorch.view --teach
    arm_reach``), ``demo_envs``, ``demos_per_env`` (synthetic only), ``priors`` (number of grid
    priors), ``prior_clear`` (keep only the priors that succeed under ``collision``; ``auto``: with
    ``volume``), ``prior_detours`` (distances of the detour priors,
    :mod:`~protorch.tasks.arm.priors`;
    ``auto``: 0.18 and 0.24 m with ``volume``, none with the skeleton), ``prior_grid``
    (``rectangles`` or ``table``: the region the priors' grid spans) and the
    :class:`~protorch.tasks.ArmReachTask` options (``cost_steps``, ``margin``, ``goal_tol``,
    ``region``, ``reach``, ...).
    ``gp``: ``backend``, ``alpha``, ``var_floor``, ``nearest_k``. ``loop``: ``num_envs``,
    ``batch_size``, ``add_only``, ``choice``, ``checkpoint_every``, ``eval_dtype``, ``min_var``,
    ``labels`` (the label-aware map; false runs the paper's single map). ``test``: ``num_envs``,
    ``seed``. ``dynamic``: ``episodes`` plus :func:`~protorch.control.arm.run_arm_episodes`
    options. ``physics``: ``run`` (auto, always, never), ``timestep``, ``kp``, ``kd``,
    ``mass_scale``, ``render`` (:mod:`protorch.experiments.arm_physics`). ``robot``: the arm, a
    shipped robot's name or a dict of ``robot.*`` settings (:func:`protorch.robots.load_robot`;
    ``None``: the Panda). ``baselines``: any of
    ``labels_off``, ``labels_off_loop``. ``resume``: continue the
    loops from the checkpoints in ``out_dir``. ``threads``: torch's intra-op threads for the run
    (restored afterwards; ``None``, the default, keeps the setting around the call: the app's
    top-level ``threads``, :mod:`protorch.threads`). Every setting is validated before any work
    starts.
    """
prepare, run = experiment_functions(
    ArmReachExperiment, baselines=_BASELINES, progress=True, run_doc=_RUN_DOC, threads=True
)


def check_robot(robot, task_cfg: dict, physics_runs: bool):
    """The robot setting checked before any work (each a ``ValueError`` of one line naming the
    setting): the description (:func:`~protorch.robots.load_robot`: the URDF parses, the end
    link exists, at least 6 joints, the home pose's length and limits), the inertials where the
    physics test will run (and MuJoCo compiling its scene), and the workspace within the arm's
    reach (:func:`~protorch.tasks.arm.workspace.check_reach`). Returns the task."""
    robot = load_robot(robot)
    if physics_runs:
        check_inertials(robot)
    keys = ArmReachExperiment.task_keys - {
        "_target_",
        "demos",
        "recordings",
        "demo_envs",
        "demos_per_env",
        "priors",
        "prior_clear",
        "prior_detours",
        "prior_grid",
        "plan_margin",
    }
    task = ArmReachTask(robot=robot, **{k: v for k, v in task_cfg.items() if k in keys})
    check_reach(task, check_region(task_cfg.get("prior_grid", "rectangles"), "task.prior_grid"))
    if physics_runs:
        if not robot.capsule_list():
            raise ValueError(
                f"robot.capsules: the {robot.name} arm has no collision volumes, which the MuJoCo "
                "test "
                "collides with the can and the table; give robot.capsules (or auto) or set "
                "settings.physics.run=never"
            )

        try:
            build_scene(task)
        except Exception as exc:  # MuJoCo's own compiler errors
            raise ValueError(
                f"robot: MuJoCo cannot build the scene of robot.urdf={robot.urdf}: {exc}"
            ) from None
    return task


# ----------------------------------------------------------------------------- evaluation
def _test(task: ArmReachTask, model, envs: torch.Tensor, seed: int) -> dict:
    """Success of the label-aware mean trajectories on the held-out environments."""
    with torch.no_grad():
        best = label_aware_mean(
            model.env_map, model.promp, task, envs, dtype=model.promp.basis.dtype, check=True
        )
        traj = model.promp.trajectory(best.mean)  # (Q, T, 7)
        ok = task.success(traj, envs)  # (Q,)
        c = task.costs(traj, envs)  # (Q, 3)
        clear = task.can_gap(traj, envs) > task.margin
        ee = task.ee_path(traj[:, -1])
        goal_err = (ee - task.goal_point(envs)).norm(dim=-1)
        side = task.side(traj, envs)  # (Q,) the side the chosen mean actually passes on
    return {
        "success_rate": float(ok.double().mean()),
        "num_envs": int(envs.shape[0]),
        "seed": int(seed),
        "collision_rate": float((~clear).double().mean()),
        "limit_violation_rate": float(
            (~task.kinematics.within_limits(traj).all(-1)).double().mean()
        ),
        "goal_error_median": float(goal_err.median()),
        "goal_reached_rate": float((goal_err <= task.goal_tol).double().mean()),
        "left": int((side == LEFT).sum()),
        "right": int((side == RIGHT).sum()),
        "cost_median": float(c.sum(-1).median()),
    }
