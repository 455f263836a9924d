"""The point-particle self-improvement loop with each optimiser, side by side in one run
(on demand: ``python benchmarks/studies/loop_optimizers.py [--envs 1000] [--methods
pro,epro,rwr,cem,cmaes]``).

Every loop starts from the same 30 x 3 synthetic demonstrations, tries the same pool of random
environments with the experiment's settings (``experiment=point_particle`` as the app composes
it, ``benchmarks/configs.py``: B = 100, beta = 20, alpha = 1e-3, the authors' acceptance check) and
is evaluated by the experiment's own function on its 200 held-out environments and 100
moving-environment episodes. Only the optimiser changes (at most 200 iterations each, the
contract's convergence rule):

- ``pro``: the experiment's PRO (100 relevance probes + 3 x 100 samples per iteration);
- ``epro``: :class:`~protorch.optim.EPRO` at its defaults (20 samples per iteration);
- ``rwr``: the experiment's RWR (100 samples, beta = 20);
- ``cem``: CEM, 100 samples, 10 % elites;
- ``cmaes``: CMA-ES, pycma's default population ``4 + 3 ln N`` (17 for N = 20).

Columns: held-out success of the final map's mean, moving-environment success, loop seconds
(load-dependent) and rollouts: every weight sample asked for a problem still moving (what the
loop evaluates; converged problems' columns are not rolled out).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/configs.py
from configs import arguments_of, experiment_settings  # noqa: E402

from protorch.experiments.point_particle import prepare
from protorch.gp.model import EnvToProMP
from protorch.optim import CEM, CMAES, EPRO


def counting(cls: type, counter: list) -> type:
    """``cls`` whose ``ask`` adds the samples asked for still-moving problems to ``counter[0]``."""

    class Counted(cls):
        def ask(self):
            w = super().ask()  # (B, S, N)
            counter[0] += int(self.active.sum()) * w.shape[-2]
            return w

    Counted.__name__ = cls.__name__
    return Counted


def optimizers(setup, cfg: dict) -> dict:
    common = {k: cfg["optimizer"][k] for k in ("max_iter", "tol", "window")}
    num_weights = setup.promp.num_weights
    return {
        "pro": setup.optimizers["pro"],
        "epro": (EPRO, dict(common)),
        "rwr": setup.optimizers["rwr"],
        "cem": (CEM, {**common, "num_samples": 100, "elite_frac": 0.1}),
        "cmaes": (CMAES, {**common, "num_samples": 4 + int(3 * math.log(num_weights))}),
    }


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--envs", type=int, default=1000, help="environments tried per loop (default 1000)"
    )
    p.add_argument("--methods", default="pro,epro,rwr,cem,cmaes")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    # composed as `python -m protorch experiment=point_particle` composes it (the experiment's yaml
    # alone lacks the optimizer, task and gp groups and their experiment-specific values)
    cfg = experiment_settings("point_particle", [f"settings.loop.num_envs={args.envs}"])
    setup = prepare(**arguments_of(prepare, cfg))
    table = optimizers(setup, cfg)
    print(
        f"point-particle loop, {args.envs} environments, B = {cfg['loop']['batch_size']}, torch "
        "threads "
        f"{torch.get_num_threads()}"
    )
    print("| optimiser | held-out success | moving success | loop s | rollouts | tried success |")
    print("|---|---|---|---|---|---|")
    for name in args.methods.split(","):
        counter = [0]
        cls, kwargs = table[name]
        setup.optimizers[name] = (counting(cls, counter), kwargs)
        t0 = time.perf_counter()
        res = setup.run_loop(name)
        loop_s = time.perf_counter() - t0
        test, dyn = setup.evaluate(EnvToProMP(setup.promp, res.env_map, setup.task.name))[:2]
        print(
            f"| {cls.__name__} | {test['success_rate']:.3f} | {dyn['success_rate']:.3f} | "
            f"{loop_s:.1f} "
            f"| {counter[0]:,} | {res.success_rate:.3f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
