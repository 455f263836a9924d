"""Beam-through-a-window speed, side by side in one run (``python benchmarks/beam_window.py``).

1. The task's costs for one PRO ask (200 samples, T = 250) in float64 and float32 (the
   experiment's ``eval_dtype``), their ratio and the largest difference between the two.
2. The experiment's parts at the paper's budget: position PRO and orientation PRO (150 x 200),
   the 1000-sample collision check and 100 assisted trials.

Set ``OMP_NUM_THREADS`` to compare thread counts (on a shared machine 1 thread is often faster).
"""

from __future__ import annotations

import argparse

import torch
from _timing import median_s

from protorch.control.guidance import HapticGuidance
from protorch.experiments.beam_window import optimize_pose_promp
from protorch.primitives.pose import PoseProMP
from protorch.tasks.beam_window import BeamWindowTask, SimulatedOperator


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--no-experiment", action="store_true", help="only the cost timings")
    args = parser.parse_args()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} thread(s)")
    task, person = BeamWindowTask(), SimulatedOperator()
    demos = person.trials(task, 10, torch.Generator().manual_seed(101))
    model = PoseProMP(10, 250).fit(
        demos, reference=torch.tensor(task.start_quaternion, dtype=torch.float64)
    )
    phases = torch.tensor([0.0, 0.45, 0.58, 1.0], dtype=torch.float64)
    print("\n1. costs of one ask (200 samples, T = 250)")
    print(
        f"{'':14s}{'float64 (ms)':>14s}{'float32 (ms)':>14s}{'ratio':>8s}{'max |difference|':>18s}"
    )
    w_pos, w_rot = model.sample(200, generator=torch.Generator().manual_seed(0))
    for name, cost in (
        ("position", lambda m, d: task.position_costs(m.position.trajectory(w_pos.to(d)))),
        (
            "orientation",
            lambda m, d: task.orientation_costs(
                m.orientation.trajectory(w_rot.to(d)), phases.to(d)
            ),
        ),
    ):
        m32 = model.copy().to(torch.float32)
        t64 = median_s(lambda: cost(model, torch.float64), args.repeats) * 1e3
        t32 = median_s(lambda: cost(m32, torch.float32), args.repeats) * 1e3
        diff = float((cost(model, torch.float64) - cost(m32, torch.float32).double()).abs().max())
        print(f"{name:14s}{t64:14.2f}{t32:14.2f}{t64 / t32:8.1f}{diff:18.2e}")
    if args.no_experiment:
        return
    print("\n2. the experiment's parts at the paper's budget, s")
    opt = dict(
        beta=200.0,
        num_samples=200,
        max_iter=150,
        tol=0.0,
        pro=dict(relevance_samples=200, relevance_var=1e-5, noise_floor=3.0),
    )
    stages = optimize_pose_promp(task, model, optimizer=opt, seed=0)
    samples = model.trajectory(*model.sample(1000, generator=torch.Generator().manual_seed(1)))
    t_col = median_s(lambda: task.collides(samples), 1)
    intended, lengths = person.intentions(task, 100, torch.Generator().manual_seed(303))
    guide = HapticGuidance(model)
    t_assist = median_s(lambda: guide.assist(intended, lengths=lengths), 1)
    print(
        f"position PRO {stages['position']['seconds']:.2f}, orientation PRO "
        f"{stages['orientation']['seconds']:.2f}, "
        f"collision check of 1000 samples {t_col:.2f}, 100 assisted trials {t_assist:.2f}"
    )


if __name__ == "__main__":
    main()
