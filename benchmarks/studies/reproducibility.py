"""Which CPU paths change a run's numbers (on demand: ``python benchmarks/studies/reproducibility.py
[--experiments arm_reach point_particle] [--variants ...] [--ops]``).

Each variant runs in a fresh Python process with its environment: ``t=N`` torch threads,
``ATEN_CPU_CAPABILITY`` (``avx512``, ``avx2``, ``default``: ATen's vectorised kernels of another
CPU on this one) and ``MKL_CBWR`` (MKL's code path: ``AVX2``, ``COMPATIBLE``, or unset: MKL picks
by CPU). A run is a small ``arm_reach`` / ``point_particle`` (``tests/small_runs.py``): every
metric but the timings, and a hash of each loop's data set, bit for bit. It prints, per variant,
how many entries differ from the first variant's and the first few of them.

``--speed`` times MKL's own choice, its AVX2 branch and its SSE2 branch (``COMPATIBLE``) on the
GP map's work (Cholesky, a solve and a product at 30 to 1,000 environments in float64, 1
thread), alternating the three in fresh processes, 3 rounds.

``--fingerprint`` prints every entry of the first variant and one digest of them all: run
``python benchmarks/studies/reproducibility.py --ops --fingerprint --variants
t=1,MKL_CBWR=COMPATIBLE``
on two machines and compare (docs/reproducibility.md lists this one's).

``--ops`` instead prints which single operations (random draws, matmul, reductions,
transcendental functions, Cholesky and solves, the arm's costs) give other bits under each
variant than under the first: the depth at which a difference starts (docs/reproducibility.md).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
VARIANTS = [
    "t=1",
    "t=2",
    "t=1,ATEN_CPU_CAPABILITY=avx2",
    "t=1,ATEN_CPU_CAPABILITY=default",
    "t=1,MKL_CBWR=AVX2",
    "t=1,MKL_CBWR=AVX2,ATEN_CPU_CAPABILITY=avx2",
    "t=2,MKL_CBWR=AVX2",
    "t=1,MKL_CBWR=COMPATIBLE",
]


def _ops() -> dict:
    """Fingerprints of single operations on fixed inputs (this process's CPU paths)."""
    import torch

    from protorch.primitives.promp import ProMP
    from protorch.tasks import ArmReachTask

    def fp(t) -> str:
        return hashlib.sha256(t.detach().contiguous().cpu().numpy().tobytes()).hexdigest()[:12]

    g = torch.Generator().manual_seed(0)
    out = {}
    for dt in (torch.float32, torch.float64):
        n = str(dt).split(".")[1]
        a = torch.randn(
            20, 100, 70, generator=torch.Generator().manual_seed(1), dtype=torch.float64
        ).to(dt)
        b = torch.randn(
            70, 100, generator=torch.Generator().manual_seed(2), dtype=torch.float64
        ).to(dt)
        m = (
            torch.randn(70, 70, generator=torch.Generator().manual_seed(3), dtype=torch.float64) / 8
        ).to(dt)
        spd = m @ m.T + torch.eye(70, dtype=dt)  # (70, 70) from one small matmul
        out.update(
            {
                f"randn {n}": fp(torch.randn(20, 100, 70, generator=g, dtype=dt)),
                f"matmul {n}": fp(a @ b),
                f"sum {n}": fp(a.sum(-1)),
                f"sum of 140k {n}": fp(a.sum()),
                f"norm {n}": fp(a.norm(dim=-1)),
                f"exp {n}": fp(a.exp()),
                f"sin {n}": fp(a.sin()),
                f"atan2 {n}": fp(torch.atan2(a, a.flip(-1))),
                f"sigmoid {n}": fp(a.sigmoid()),
                f"cdist {n}": fp(torch.cdist(a[0], a[1])),
                f"cholesky {n}": fp(torch.linalg.cholesky(spd)),
                f"solve {n}": fp(torch.linalg.solve(spd, a[0, :70])),
            }
        )
    task, promp = ArmReachTask(), ProMP(7, 10, 100, dtype=torch.float32)
    traj = promp.trajectory(0.3 * torch.randn(20, 50, 70, generator=g))  # (20, 50, T, 7) float32
    env = task.sample_envs(20, g, dtype=torch.float32)[:, None]  # (20, 1, 4)
    out.update(
        {
            "ProMP trajectories float32": fp(traj),
            "arm costs float32": fp(task.costs(traj, env)),
            "arm success": fp(task.success(traj, env)),
        }
    )
    return out


def _speed() -> dict:
    """CPU seconds of Cholesky + solve + a product at each size (this process's MKL setting)."""
    import time

    import torch

    g, out = torch.Generator().manual_seed(0), {}
    for m in (30, 100, 300, 1000):
        a = torch.randn(m, m, generator=g, dtype=torch.float64)
        a = a @ a.T + m * torch.eye(m, dtype=torch.float64)  # (m, m)
        b = torch.randn(m, 70, generator=g, dtype=torch.float64)  # (m, N)
        c = torch.randn(m, 100, generator=g, dtype=torch.float64)  # (m, 100)
        t = time.process_time()
        for _ in range(max(1, 3000 // m)):
            torch.cholesky_solve(b, torch.linalg.cholesky(a))
            a @ c
        out[str(m)] = time.process_time() - t
    return out


def _run(variant: str, what: list[str]) -> dict:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("MKL_CBWR", "ATEN_CPU_CAPABILITY", "OMP_NUM_THREADS")
    }
    threads = 1
    for item in variant.split(","):
        key, _, value = item.partition("=")
        if key == "t":
            threads = int(value)
        else:
            env[key] = value
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    out = {}
    for name in what:
        cmd = (
            [sys.executable, __file__, f"--{name}-here", str(threads)]
            if name in ("ops", "speed")
            else [sys.executable, "-m", "tests.small_runs", name, str(threads)]
        )
        proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, check=True)
        out.update(
            {f"{name}: {k}": v for k, v in json.loads(proc.stdout.strip().splitlines()[-1]).items()}
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--experiments", nargs="+", default=["arm_reach", "point_particle"])
    ap.add_argument("--variants", nargs="+", default=VARIANTS)
    ap.add_argument("--ops", action="store_true", help="single operations instead of runs")
    ap.add_argument(
        "--speed", action="store_true", help="MKL_CBWR=AVX2 against MKL's own choice, timed"
    )
    ap.add_argument(
        "--fingerprint",
        action="store_true",
        help="print every entry of the first variant and one "
        "digest of them all, to compare with another machine's (docs/reproducibility.md)",
    )
    ap.add_argument("--ops-here", type=int, help=argparse.SUPPRESS)  # the child processes
    ap.add_argument("--speed-here", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.ops_here is not None or args.speed_here is not None:
        import torch

        torch.set_num_threads(args.ops_here or args.speed_here)
        print(json.dumps(_ops() if args.ops_here is not None else _speed()))
        return
    import torch

    print(
        f"torch {torch.__version__}, this CPU's ATen capability "
        f"{torch.backends.cpu.get_cpu_capability()}"
    )
    if args.speed:
        for r in range(3):
            own, pinned = _run("t=1", ["speed"]), _run("t=1,MKL_CBWR=AVX2", ["speed"])
            compatible = _run("t=1,MKL_CBWR=COMPATIBLE", ["speed"])
            print(
                f"round {r + 1}: CPU time of Cholesky + solve + product (s), MKL's own / AVX2 / "
                "COMPATIBLE: "
                + ", ".join(
                    f"{k.split(': ')[1]} envs {own[k]:.3f} / {pinned[k]:.3f} / {compatible[k]:.3f} "
                    f"(COMPATIBLE / AVX2 {compatible[k] / pinned[k]:.2f}x)"
                    for k in own
                )
            )
        return
    what = ["ops"] if args.ops else args.experiments
    first, base = args.variants[0], None
    for variant in args.variants:
        res = _run(variant, what)
        if base is None:
            base = res
            print(f"{variant}: {len(res)} entries (the reference)")
            if args.fingerprint:
                for k, v in res.items():
                    print(f"    {k}: {v}")
                digest = hashlib.sha256(json.dumps(res, sort_keys=True).encode()).hexdigest()[:16]
                print(f"fingerprint of {', '.join(what)} at {variant}: {digest}")
            continue
        diff = [k for k in base if res.get(k) != base[k]]
        print(f"{variant}: {len(diff)} of {len(base)} differ from {first}" + (": " if diff else ""))
        for k in diff[:12]:
            print(f"    {k}: {base[k]} -> {res.get(k)}")


if __name__ == "__main__":
    main()
