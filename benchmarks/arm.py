"""Arm experiment speed, side by side in one run (on demand: ``python benchmarks/arm.py``).

1. Forward kinematics throughput (configurations per second) of the Panda for 10^4 and 10^5
   random configurations: all link frames through ``pytorch_kinematics`` (``ArmKinematics.frames``)
   and the compiled end-effector path (``ArmKinematics.ee_position``, what the costs use), in
   float64 and float32, on the CPU and, where ``torch.cuda.is_available()``, on CUDA.
2. The self-improvement loop with the experiment's settings, composed as ``python -m protorch
   experiment=arm_reach`` composes them (``benchmarks/configs.py``: labels, both classes per
   environment, PRO <= 50 x 100, beta = 200; more overrides after the flags) on ``--envs``
   environments (default 200), its time per environment and the extrapolation to the paper's
   2024; on CUDA too where available.

``--threads`` sets torch's intra-op threads (default 1, the experiment's setting). ``--quick``:
10^3 configurations for the kinematics, and a loop of 10 environments (B = 10, PRO <= 5 x 20, 60
priors, 4 demonstration environments, 10 held-out): a check that the benchmark runs, not a
measurement.
"""

from __future__ import annotations

import argparse

import torch
from _timing import best_s
from configs import arguments_of, experiment_settings

from protorch.experiments.arm_reach import prepare
from protorch.robots.kinematics import ArmKinematics

QUICK = [
    "settings.loop.batch_size=10",
    "optimizer.max_iter=5",
    "optimizer.num_samples=20",
    "task.priors=60",
    "task.demo_envs=4",
    "settings.test.num_envs=10",
]


def _rate(fn, q, device: str, repeats: int = 3) -> float:
    """Configurations per second of ``fn(q)``, the best of ``repeats`` calls after a small one."""
    fn(q[:100])  # warm-up
    sync = torch.cuda.synchronize if device == "cuda" else None
    return q.shape[0] / best_s(lambda: fn(q), repeats, warmup=0, sync=sync)


def fk_table(devices: list[str], sizes: tuple[int, ...] = (10**4, 10**5)) -> None:
    print("forward kinematics, configurations per second (best of 3)")
    cols = [f"{d} {dt}" for d in devices for dt in ("float64", "float32")]
    print(f"{'':<46}" + "".join(f"{c:>17}" for c in cols))
    gen = torch.Generator().manual_seed(0)
    for n in sizes:
        q0 = torch.rand(n, 7, generator=gen, dtype=torch.float64) * 2 - 1
        for name, method in (
            ("all 11 frames (pytorch_kinematics)", "frames"),
            ("end effector (compiled)", "ee_position"),
        ):
            row = []
            for d in devices:
                for dt in (torch.float64, torch.float32):
                    kin = ArmKinematics(dtype=dt, device=d)
                    row.append(_rate(getattr(kin, method), q0.to(device=d, dtype=dt), d))
            label = f"{name}, n = {n:.0e}"
            print(f"{label:<46}" + "".join(f"{r:>17.3g}" for r in row))


def loop_table(devices: list[str], envs: int, overrides: list[str]) -> None:
    overrides = [*overrides, f"settings.loop.num_envs={envs}", "settings.dynamic.episodes=0"]
    base = experiment_settings("arm_reach", overrides)
    opt, lp = base["optimizer"], base["loop"]
    classes = "both classes" if lp["labels"] and lp["each_label"] else "one class"
    print(
        f"\nself-improvement loop, {envs} environments, {opt['name'].upper()} <= {opt['max_iter']} "
        "x "
        f"{opt['num_samples']}, B = {lp['batch_size']}, labels {'on' if lp['labels'] else 'off'}, "
        f"{classes} per environment"
    )
    print(
        f"{'device':<8}{'loop s':>10}{'s / env':>10}{'2024 envs (extrap.)':>22}"
        f"{'tried success':>15}{'held-out success':>18}"
    )
    for d in devices:
        setup = prepare(
            **arguments_of(prepare, experiment_settings("arm_reach", [*overrides, f"device={d}"]))
        )
        res = setup.run_loop()
        per = res.seconds / max(len(res.tried), 1)
        print(
            f"{d:<8}{res.seconds:>10.1f}{per:>10.3f}{2024 * per:>20.0f} s{res.success_rate:>15.3f}"
            f"{res.metrics[-1]['eval_success']:>18.3f}"
        )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--envs",
        type=int,
        default=None,
        help="environments for the loop timing (default 200; --quick 10)",
    )
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    p.add_argument("--skip-loop", action="store_true", help="only the forward-kinematics table")
    p.add_argument(
        "--quick", action="store_true", help="a reduced run that checks the benchmark works"
    )
    p.add_argument(
        "overrides",
        nargs="*",
        help="more config overrides for the loop, as on the app's command line",
    )
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} thread(s), devices: {devices}"
        + ("" if "cuda" in devices else " (no CUDA here: the CUDA columns are skipped)")
    )
    fk_table(devices, (10**3,) if args.quick else (10**4, 10**5))
    if not args.skip_loop:
        envs = args.envs if args.envs is not None else (10 if args.quick else 200)
        loop_table(devices, envs, [*(QUICK if args.quick else []), *args.overrides])


if __name__ == "__main__":
    main()
