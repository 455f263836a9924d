"""Self-improvement loop time, the paper's sequential loop (B = 1) against the batched default,
side by side in one run (on demand: ``python benchmarks/loop.py [--envs 100] [--batch 1,100]``).

Both loops start from the same 30 x 3 synthetic demonstrations and try the same pool of random
environments with the point-particle experiment's settings, composed as ``python -m protorch
experiment=point_particle`` composes them (``benchmarks/configs.py``; PRO <= 200 iterations x 100
samples, beta = 20, alpha = 1e-3; more overrides after the flags, e.g. ``optimizer=cem``). For
each batch size it prints the loop's wall time, the time per environment and the extrapolation to
the experiment's 1000 environments, the success rate of the optimised solutions (environments
tried) and of the resulting map on the experiment's 200 held-out environments.

``--quick``: 20 environments, B = 1 and 10, PRO <= 10 iterations x 20 samples, 10 held-out
environments: a check that the benchmark runs, not a measurement.
"""

from __future__ import annotations

import argparse

import torch
from configs import arguments_of, experiment_settings

from protorch.experiments.point_particle import prepare

QUICK = ["optimizer.max_iter=10", "optimizer.num_samples=20", "settings.test.num_envs=10"]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--envs",
        type=int,
        default=None,
        help="environments tried per loop (default 100; --quick 20)",
    )
    p.add_argument(
        "--batch", default=None, help="comma-separated batch sizes B (default 1,100; --quick 1,10)"
    )
    p.add_argument(
        "--demos", default="synthetic", help="'synthetic' or a folder of trajK.out / envK.out"
    )
    p.add_argument("--method", default="pro", choices=["pro", "rwr"])
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    p.add_argument(
        "--quick", action="store_true", help="a reduced run that checks the benchmark works"
    )
    p.add_argument(
        "overrides", nargs="*", help="more config overrides, as on the app's command line"
    )
    args = p.parse_args()
    envs = args.envs if args.envs is not None else (20 if args.quick else 100)
    batches = args.batch or ("1,10" if args.quick else "1,100")
    if args.threads:
        torch.set_num_threads(args.threads)
    overrides = [
        *(QUICK if args.quick else []),
        f"task.demos={args.demos}",
        f"settings.loop.num_envs={envs}",
        "settings.dynamic.episodes=0",
        *args.overrides,
    ]
    settings = experiment_settings("point_particle", overrides)
    setup = prepare(**arguments_of(prepare, settings))
    opt, default_b = settings["optimizer"], settings["loop"]["batch_size"]
    print(
        f"point-particle loop, {envs} environments, {args.method.upper()} <= "
        f"{opt['max_iter']} iterations x {opt['num_samples']} samples, "
        f"torch threads {torch.get_num_threads()} (the experiment's default B = {default_b})"
    )
    head = (
        f"{'B':>5} {'loop s':>9} {'s / env':>9} {'1000 envs (extrap.)':>20} "
        f"{'tried success':>14} {'held-out success':>17}"
    )
    print(head)
    print("-" * len(head))
    for b in [int(x) for x in batches.split(",")]:
        res = setup.run_loop(None if args.method == "pro" else "rwr", batch_size=b)
        per_env = res.seconds / max(len(res.tried), 1)
        print(
            f"{b:>5} {res.seconds:>9.2f} {per_env:>9.4f} {1000 * per_env:>18.1f} s "
            f"{res.success_rate:>14.3f} {res.metrics[-1]['eval_success']:>17.3f}"
        )


if __name__ == "__main__":
    main()
