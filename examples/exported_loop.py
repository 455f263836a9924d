"""A control loop driven by a policy's two exported programs, in a process that has only torch
(no protorch): the tracker every 1 ms tick, the planner every ``--plan-every`` ticks (the
decision interval by default), each program's state passed in and taken back at every call.

    python -c "import protorch; protorch.load('runs/arm', planner='thread').export('arm_programs')"
    python examples/exported_loop.py arm_programs --inputs inputs.pt --out out.pt

``--inputs``: a ``torch.save``'d dict with ``env (T, env_dim)`` (one environment per tick) and
``q0, qd0 (D,)`` (the arm at the start); ``--out``: the reference of every tick, ``q, qd, qdd
(T, D)``, ``label (T,)`` and ``plan_t (T,)``, and the tracker's wall and CPU time per call
``tracker_s, tracker_cpu_s (T,)``. Without ``--inputs`` the environment stays at ``--env``
(comma separated).

The arm is taken to follow the reference exactly (the measured ``q, qd`` handed to both
programs are the last tick's reference); a robot's loop hands over what it measures. With the
run's jerk limits (``programs.json``'s ``limits``) a C++ loop applies Ruckig to the tracker's
output (``protorch.policy.limits.JerkLimiter`` is the Python side of it); this script does not.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

F64 = torch.float64


def load_programs(folder: Path) -> tuple:
    """``(planner, tracker, meta)``: the programs of ``folder`` as callables (AOTInductor
    packages where ``programs.json`` says ``aoti``) and its ``programs.json``."""
    meta = json.loads((folder / "programs.json").read_text())

    def load(name: str):
        if meta["aoti"][name]:
            return torch._inductor.aoti_load_package(str(folder / f"{name}.pt2"))
        return torch.export.load(folder / f"{name}.pt2").module()

    return load("planner"), load("tracker"), meta


def run_loop(planner, tracker, meta: dict, envs: torch.Tensor, q0, qd0, plan_every: int) -> dict:
    """``T = envs.shape[0]`` ticks of 1 ms (module docstring): the planner at every
    ``plan_every``-th tick (before that tick's tracker call, on that tick's inputs), the tracker
    at every tick."""
    d, kb = meta["dof"], meta["num_basis"]
    # the planner's state: the class row (-1: none yet) and the decision slot
    current, slot = torch.tensor(-1), torch.tensor(-1)
    # the tracker's state: the last plan's weights, the last time, the offset, started
    state = (torch.zeros(kb, d, dtype=F64), torch.zeros((), dtype=F64))
    state += (torch.zeros(2, d, dtype=F64), torch.zeros((), dtype=F64))
    q, qd = q0.to(F64), qd0.to(F64)
    W = label = plan_t = None
    keys = ("q", "qd", "qdd", "label", "plan_t", "tracker_s", "tracker_cpu_s")
    out: dict[str, list] = {k: [] for k in keys}
    for i in range(envs.shape[0]):
        t = torch.tensor(i * meta["tick"], dtype=F64)
        if i % plan_every == 0:
            W, label, current, slot, plan_t = planner(envs[i], t, q, qd, current, slot)
        c0, t0 = time.thread_time(), time.perf_counter()
        q_r, qd_r, qdd_r, *state = tracker(t, W, q, qd, *state)
        out["tracker_s"].append(time.perf_counter() - t0)
        out["tracker_cpu_s"].append(time.thread_time() - c0)
        q, qd = q_r, qd_r  # the arm on its reference
        for k, v in (("q", q_r), ("qd", qd_r), ("qdd", qdd_r), ("label", label)):
            out[k].append(v)
        out["plan_t"].append(plan_t)
    res = {k: torch.stack(v) for k, v in out.items() if not k.startswith("tracker")}
    for k in ("tracker_s", "tracker_cpu_s"):
        res[k] = torch.tensor(out[k], dtype=F64)
    return res


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--inputs", type=Path)
    ap.add_argument("--env", default="")
    ap.add_argument("--ticks", type=int, default=3000)
    ap.add_argument("--plan-every", type=int, default=0, help="ticks (0: the decision interval)")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--threads", type=int, default=1, help="torch's intra-op threads")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)  # a pool's workers only compete with the loop for cores
    planner, tracker, meta = load_programs(args.folder)
    if args.inputs is not None:
        data = torch.load(args.inputs, weights_only=True)
        envs, q0, qd0 = data["env"].to(F64), data["q0"], data["qd0"]
    else:
        if not args.env:
            sys.exit("give --inputs or --env")
        env = torch.tensor([float(x) for x in args.env.split(",")], dtype=F64)
        envs = env.expand(args.ticks, -1)
        q0 = qd0 = torch.zeros(meta["dof"], dtype=F64)
    every = args.plan_every or max(1, round(meta["decision_dt"] / meta["tick"]))
    res = run_loop(planner, tracker, meta, envs, q0, qd0, every)
    ms = sorted((res["tracker_s"] * 1e3).tolist())
    cpu = sorted((res["tracker_cpu_s"] * 1e3).tolist())
    n = len(ms)
    p99 = min(n - 1, int(0.99 * n))
    print(
        f"{n} ticks, a plan every {every}: tracker wall median {ms[n // 2]:.4f} ms, p99 "
        f"{ms[p99]:.4f} ms, max {ms[-1]:.4f} ms; CPU median {cpu[n // 2]:.4f} ms, p99 "
        f"{cpu[p99]:.4f} ms, max {cpu[-1]:.4f} ms; classes "
        f"{sorted(set(res['label'].tolist()))}; protorch imported: "
        f"{any(m.split('.')[0] == 'protorch' for m in sys.modules)}"
    )
    if args.out is not None:
        torch.save(res, args.out)


if __name__ == "__main__":
    main()
