"""protorch's optimisers on fancy_gym's ProMP tasks, through the ask / tell contract.

Set up once (its own venv; fancy_gym pins mujoco 2.3.3): ``bash
benchmarks/studies/external/setup.sh``, then

    benchmarks/studies/external/.venv/bin/python benchmarks/studies/external/run.py \\
        --tasks hole_reacher --optimizers EPRO,CMAES --contexts 1,2,3,4,5 --seeds 0,1 \\
        --episodes 1600 --json benchmarks/studies/results/external/hole_1600.json

Every run is one (task, optimiser, context, seed): the optimiser starts from ``N(0, start_std^2 I)``
over the task's ProMP weights, asks ``--samples`` weights an iteration (20), each evaluated as one
episode after ``env.reset(seed=context)`` (the same box goal pose / hole / via point every episode
of the run), costs ``-return`` (one objective), until the next ask would pass ``--episodes``.
Every ``--eval-every`` episodes (and at the end) the current mean is run once more (not counted
as an episode): the curve holds its return and success and, over the samples so far, the best
sample's return and whether any sample succeeded. ``tol = 0``: no optimiser stops on the
contract's convergence rule (pycma's own ``stop()`` still applies: the mean then stays as it is).

Optimisers (``--optimizers``): ``EPRO`` (its defaults; ``--epro KEY=VALUE`` overrides, repeatable),
``CMAES`` (pycma, ``popsize = samples``), ``CEM`` (10 % elites), ``PRO`` (the paper's, ``samples``
per objective plus ``samples`` relevance probes an iteration, ``beta = --pro-beta`` on the costs,
noise floor 3), any ``EPRO:NAME`` registered in :data:`VARIANTS` and ``CMAES:diag`` (separable
CMA-ES: a diagonal covariance, pycma's ``CMA_diagonal``), for the diagnosis.

Results: ``--json``, written atomically after every check of the mean (a run still going or cut
short is there with ``"partial": true`` and the episodes it reached):
``meta`` (command, commit, versions, settings) and ``runs``, one per run with its ``curve`` and the
commit it ran at. ``--resume`` keeps the finished runs of an existing ``--json`` (same settings)
and runs only the others (a run cut short starts again from its first episode).
``python benchmarks/studies/external/table.py FILES...`` turns them into the tables of
docs/external.md.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(
        _var, "1"
    )  # one thread: pycma's numpy and torch otherwise fight over cores

import argparse
import json
import math
import shlex
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from protorch.data.files import atomic_write_bytes
from protorch.optim import CEM, CMAES, EPRO, PRO

ROOT = Path(__file__).resolve().parents[3]
OPTIMIZERS = ("EPRO", "CMAES", "CEM", "PRO")
VARIANTS: dict[
    str, dict
] = {  # EPRO:NAME -> EPRO keyword arguments (the diagnosis of docs/external.md)
    "nogate": {"evidence_level": None},  # no read-weight test, no trust region: relevance alone
    "nofloor": {"noise_floor": None, "variance_floor": None},
    "nogate_nofloor": {"evidence_level": None, "noise_floor": None, "variance_floor": None},
    "ess05": {"ess": 0.5},
    "wide_trust": {"trust_radius": 1e6},
}


def parse_overrides(items: list[str]) -> dict:
    """``KEY=VALUE`` strings -> keyword arguments (values parsed as JSON, else kept as strings)."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise SystemExit(f"--epro expects KEY=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def make_optimizer(
    name: str,
    n: int,
    start_std: float,
    samples: int,
    seed: int,
    *,
    epro: dict | None = None,
    pro_beta: float = 0.05,
):
    """One optimiser over ``n`` weights from ``N(0, start_std^2 I)``, unbatched, ``tol = 0``."""
    mean = torch.zeros(n, dtype=torch.float64)
    var = torch.full((n,), float(start_std) ** 2, dtype=torch.float64)
    common = {"num_samples": samples, "max_iter": 10**9, "tol": 0.0, "seed": seed}
    base, _, variant = name.partition(":")
    if base == "EPRO":
        if variant and variant not in VARIANTS:
            raise SystemExit(f"unknown EPRO variant {variant!r}; choose one of {sorted(VARIANTS)}")
        return EPRO(mean, var, **{**common, **(epro or {}), **VARIANTS.get(variant, {})})
    if base == "CMAES":
        if variant not in ("", "diag"):
            raise SystemExit(f"unknown CMAES variant {variant!r}; CMAES:diag is separable CMA-ES")
        return CMAES(mean, var, cma_options={"CMA_diagonal": True} if variant else None, **common)
    if base == "CEM":
        return CEM(mean, var, elite_frac=0.1, **common)
    if base == "PRO":
        return PRO(mean, var, beta=pro_beta, relevance_samples=samples, noise_floor=3.0, **common)
    raise SystemExit(
        f"unknown optimizer {name!r}; choose from {OPTIMIZERS}, EPRO:<variant> or CMAES:diag"
    )


def diagnostics(opt) -> dict:
    """What the search distribution looks like: median std, and for EPRO the read weights."""
    out = {
        "std_median": float(opt.var[0].sqrt().median()),
        "std_max": float(opt.var[0].sqrt().max()),
    }
    if isinstance(opt, EPRO):
        out["read"] = int(opt.read[0].sum())
    return out


def run_one(
    optimizer,
    evaluate: Callable,
    context: int,
    budget: int,
    eval_every: int,
    progress: Callable[[dict], None] | None = None,
) -> dict:
    """One optimiser against ``evaluate(weights (S, N), context) -> outcomes`` until the next ask
    would pass ``budget`` episodes; the mean is evaluated every ``eval_every`` episodes and at the
    end.
    ``progress(partial)`` gets the run so far (``"partial": True``) after every check of the
    mean."""
    episodes, best_ret, best_at, first_success = 0, -math.inf, None, None
    best = None
    curve = []
    next_eval = 0
    t0, c0 = time.perf_counter(), time.process_time()

    def summary() -> dict:
        last = curve[-1]
        return {
            "episodes": episodes,
            "iterations": optimizer.iteration,
            "seconds": time.perf_counter() - t0,
            "cpu_seconds": time.process_time()
            - c0,  # this process's CPU (workers=1: the episodes' too)
            "final_return": last["mean_return"],
            "final_success": last["mean_success"],
            "final_pos_dist": last["mean_pos_dist"],
            "final_rot_dist": last["mean_rot_dist"],
            "best_return": best_ret,
            "best_at": best_at,
            "first_success": first_success,
            "best_pos_dist": None if best is None else best.pos_dist,
            "best_rot_dist": None if best is None else best.rot_dist,
            "stopped": optimizer.stop_reason(),
            "curve": curve,
        }

    def checkpoint(final: bool = False):
        m = evaluate(optimizer.mean[0].numpy()[None], context)[
            0
        ]  # not counted: a check of the mean
        curve.append(
            {
                "episodes": episodes,
                "mean_return": m.ret,
                "mean_success": m.success,
                "mean_pos_dist": m.pos_dist,
                "mean_rot_dist": m.rot_dist,
                "best_return": best_ret,
                "any_success": first_success is not None,
                **diagnostics(optimizer),
            }
        )
        if progress is not None and not final:
            progress({**summary(), "partial": True})

    while not optimizer.stop():
        if episodes >= next_eval and optimizer._next is None:  # between iterations
            checkpoint()
            next_eval = episodes + eval_every
        w = optimizer.ask()  # (S, N)
        if episodes + w.shape[0] > budget:
            break
        outcomes = evaluate(w.numpy(), context)
        for k, o in enumerate(outcomes):
            if o.success and first_success is None:
                first_success = episodes + k + 1
            if o.ret > best_ret:
                best_ret, best_at, best = o.ret, episodes + k + 1, o
        episodes += w.shape[0]
        returns = torch.tensor([o.ret for o in outcomes], dtype=torch.float64)  # (S,)
        optimizer.tell(-returns[:, None])  # (S, 1): cost = -return
    if optimizer._asked is not None:  # the ask that would pass the budget: drop it
        optimizer._asked = None
    checkpoint(final=True)
    return summary()


def commit() -> str:
    try:
        out = subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=False,
        )
        dirty = subprocess.run(
            [
                "git",
                "-C",
                str(ROOT),
                "status",
                "--porcelain",
                "--",
                "protorch",
                "benchmarks/studies/external",
            ],
            capture_output=True,
            text=True,
            check=False,
        ).stdout.strip()
        return out.stdout.strip() + ("+dirty" if dirty else "")
    except OSError:
        return "unknown"


def ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x.strip()]


SETTINGS = (
    "episodes",
    "samples",
    "start_std",
    "epro",
    "pro_beta",
    "eval_every",
)  # what a resumed file must share


def resumed(path: str, meta: dict) -> list[dict]:
    """The finished runs of ``path`` (each stamped with its file's commit if it has none), after
    checking the file was made with the same settings as ``meta``; [] if there is no such file."""
    if not Path(path).exists():
        return []
    old = json.loads(Path(path).read_text())
    differ = [k for k in SETTINGS if k in old["meta"] and old["meta"][k] != meta[k]]
    if differ:
        was = ", ".join(f"{k}={old['meta'][k]!r}" for k in differ)
        raise SystemExit(f"--resume: {path} was run with other settings ({was})")
    return [
        {**r, "commit": r.get("commit", old["meta"].get("commit", "unknown"))}
        for r in old["runs"]
        if not r.get("partial")
    ]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--tasks", default="hole_reacher", help="comma-separated short names or fancy_gym ids"
    )
    ap.add_argument(
        "--optimizers",
        default="EPRO,CMAES",
        help=f"comma-separated, of {OPTIMIZERS} or EPRO:<variant>",
    )
    ap.add_argument("--contexts", default="1,2,3,4,5", help="env.reset seeds (one context each)")
    ap.add_argument("--seeds", default="0,1", help="optimiser seeds")
    ap.add_argument("--episodes", type=int, default=1600, help="episode budget of a run")
    ap.add_argument(
        "--samples", type=int, default=20, help="samples per iteration (CMA-ES popsize)"
    )
    ap.add_argument("--start-std", type=float, default=1.0, help="the start is N(0, start_std^2 I)")
    ap.add_argument(
        "--eval-every", type=int, default=100, help="episodes between checks of the mean"
    )
    ap.add_argument(
        "--epro", action="append", default=[], metavar="KEY=VALUE", help="EPRO settings"
    )
    ap.add_argument("--pro-beta", type=float, default=0.05, help="PRO's temperature on -return")
    ap.add_argument("--workers", type=int, default=1, help="processes the episodes are spread over")
    ap.add_argument("--json", required=True, help="results file (rewritten after every run)")
    ap.add_argument("--note", default="", help="free text stored in meta")
    ap.add_argument(
        "--resume", action="store_true", help="keep the finished runs of --json, run the others"
    )
    args = ap.parse_args(argv)
    import fancy_gym
    import mujoco
    from tasks import Episodes, short_name, task_id

    torch.set_num_threads(1)
    epro = parse_overrides(args.epro)
    meta = {
        "command": "python benchmarks/studies/external/run.py "
        + shlex.join(sys.argv[1:] if argv is None else argv),
        "commit": commit(),
        "fancy_gym": getattr(fancy_gym, "__version__", "0.3.0"),
        "mujoco": mujoco.__version__,
        "episodes": args.episodes,
        "samples": args.samples,
        "start_std": args.start_std,
        "epro": epro,
        "pro_beta": args.pro_beta,
        "eval_every": args.eval_every,
        "note": args.note,
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
    }
    out = {"meta": meta, "runs": resumed(args.json, meta) if args.resume else []}
    done = {(r["task"], r["optimizer"], r["context"], r["seed"]) for r in out["runs"]}
    for task in args.tasks.split(","):
        tid = task_id(task.strip())
        ev = Episodes(tid, args.workers)
        n = ev.num_weights
        try:
            for name in args.optimizers.split(","):
                for context in ints(args.contexts):
                    for seed in ints(args.seeds):
                        if (short_name(tid), name.strip(), context, seed) in done:
                            continue
                        opt = make_optimizer(
                            name.strip(),
                            n,
                            args.start_std,
                            args.samples,
                            seed,
                            epro=epro,
                            pro_beta=args.pro_beta,
                        )
                        key = {
                            "task": short_name(tid),
                            "optimizer": name.strip(),
                            "context": context,
                            "seed": seed,
                            "commit": meta["commit"],
                        }

                        def progress(
                            partial, key=key
                        ):  # the run so far, so a run cut short keeps its curve
                            atomic_write_bytes(
                                args.json,
                                json.dumps(
                                    {**out, "runs": [*out["runs"], {**key, **partial}]}, indent=1
                                ).encode(),
                            )

                        res = run_one(opt, ev, context, args.episodes, args.eval_every, progress)
                        out["runs"].append({**key, **res})
                        print(
                            f"{short_name(tid)} {name} context {context} seed {seed}: final return "
                            f"{res['final_return']:.2f} success {res['final_success']}, best "
                            f"{res['best_return']:.2f} "
                            f"first success {res['first_success']} ({res['seconds']:.0f} s)",
                            flush=True,
                        )
                        atomic_write_bytes(args.json, json.dumps(out, indent=1).encode())
        finally:
            ev.close()


if __name__ == "__main__":
    main()
