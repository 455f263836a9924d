"""Self-improvement loop time, the paper's sequential loop (B = 1) against the batched default,
side by side in one run (on demand: ``python benchmarks/loop.py [--envs 100] [--batch 1,100]``).

Both loops start from the same 30 x 3 synthetic demonstrations and try the same pool of random
environments with the point-particle experiment's settings (``conf/experiment/point_particle.yaml``:
PRO <= 200 iterations x 100 samples, beta = 20, alpha = 1e-3). For each batch size it prints the
loop's wall time, the time per environment and the extrapolation to the experiment's 1000
environments, the success rate of the optimised solutions (environments tried) and of the
resulting map on the experiment's 200 held-out environments.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from omegaconf import OmegaConf

from protorch.experiments.common import resolve_dtype
from protorch.experiments.point_particle import prepare

CONF = Path(__file__).resolve().parents[1] / "conf" / "experiment" / "point_particle.yaml"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", type=int, default=100, help="environments tried per loop (default 100)")
    p.add_argument("--batch", default="1,100", help="comma-separated batch sizes B (default 1,100)")
    p.add_argument("--demos", default="synthetic", help="'synthetic' or a folder of trajK.out / envK.out")
    p.add_argument("--method", default="pro", choices=["pro", "rwr"])
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    args = p.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    cfg = OmegaConf.to_container(OmegaConf.load(CONF), resolve=True)
    settings = cfg["settings"]
    setup = prepare(seed=0, dtype=resolve_dtype("float64"), optimizer=cfg["optimizer"],
                    task={**cfg["task"], "demos": args.demos}, gp=cfg["gp"], promp=settings["promp"],
                    loop={**settings["loop"], "num_envs": args.envs}, test=settings["test"], dynamic={"episodes": 0})
    default_b = settings["loop"]["batch_size"]
    print(f"point-particle loop, {args.envs} environments, {args.method.upper()} <= "
          f"{cfg['optimizer']['max_iter']} iterations x {cfg['optimizer']['num_samples']} samples, "
          f"torch threads {torch.get_num_threads()} (the experiment's default B = {default_b})")
    head = f"{'B':>5} {'loop s':>9} {'s / env':>9} {'1000 envs (extrap.)':>20} {'tried success':>14} {'held-out success':>17}"
    print(head)
    print("-" * len(head))
    for b in [int(x) for x in args.batch.split(",")]:
        res = setup.run_loop(args.method, batch_size=b)
        per_env = res.seconds / max(len(res.tried), 1)
        print(f"{b:>5} {res.seconds:>9.2f} {per_env:>9.4f} {1000 * per_env:>18.1f} s "
              f"{res.success_rate:>14.3f} {res.metrics[-1]['eval_success']:>17.3f}")


if __name__ == "__main__":
    main()
