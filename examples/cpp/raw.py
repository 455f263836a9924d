"""The raw files of ``examples/cpp/exported_loop.cpp`` (torch and numpy only, no protorch):
native-endian float64 / int64, row-major, no header.

    python examples/cpp/raw.py inputs inputs.pt raw_in    # exported_loop.py's --inputs -> raw
    python examples/cpp/raw.py outputs raw_out out.pt --dof 7   # the C++ outputs -> a .pt

``raw_in``: ``env.f64 (T, env_dim)``, ``q0.f64, qd0.f64 (D,)``. ``raw_out``: ``q.f64, qd.f64,
qdd.f64 (T, D)``, ``label.i64 (T,)``, ``plan_t.f64, tracker_s.f64, tracker_cpu_s.f64 (T,)`` (the
keys of ``examples/exported_loop.py``'s ``--out``) and ``planner_s.f64`` (one per plan).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np
import torch

F64 = torch.float64
OUTPUTS = {
    "q": "f64",
    "qd": "f64",
    "qdd": "f64",
    "label": "i64",
    "plan_t": "f64",
    "tracker_s": "f64",
    "tracker_cpu_s": "f64",
    "planner_s": "f64",
}


def _write(path: Path, t: torch.Tensor) -> None:
    """``t`` as raw float64 at ``path``, atomically (a temporary name, then renamed)."""
    tmp = path.with_name(path.name + ".tmp")
    t.detach().to(F64).contiguous().numpy().tofile(tmp)
    os.replace(tmp, path)


def write_inputs(folder: Path, envs: torch.Tensor, q0: torch.Tensor, qd0: torch.Tensor) -> Path:
    """``envs (T, env_dim)``, ``q0, qd0 (D,)`` as the C++ loop's inputs in ``folder``."""
    if envs.dim() != 2 or q0.dim() != 1 or q0.shape != qd0.shape:
        raise ValueError(
            f"want envs (T, env_dim), q0 and qd0 (D,), got {tuple(envs.shape)}, "
            f"{tuple(q0.shape)}, {tuple(qd0.shape)}"
        )
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name, t in (("env", envs), ("q0", q0), ("qd0", qd0)):
        _write(folder / f"{name}.f64", t)
    return folder


def read_outputs(folder: Path, dof: int) -> dict[str, torch.Tensor]:
    """The C++ loop's ``--out`` folder: ``q, qd, qdd (T, D)``, ``label (T,)`` int64, ``plan_t,
    tracker_s, tracker_cpu_s (T,)``, ``planner_s`` (one per plan)."""
    out = {}
    for name, kind in OUTPUTS.items():
        dtype = np.float64 if kind == "f64" else np.int64
        a = torch.from_numpy(np.fromfile(Path(folder) / f"{name}.{kind}", dtype=dtype))
        out[name] = a.view(-1, dof) if name in ("q", "qd", "qdd") else a
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=("inputs", "outputs"))
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument("--dof", type=int, help="outputs: the arm's joints (programs.json's dof)")
    args = ap.parse_args(argv)
    if args.what == "inputs":
        data = torch.load(args.src, weights_only=True)
        write_inputs(args.dst, data["env"].to(F64), data["q0"].to(F64), data["qd0"].to(F64))
    else:
        if args.dof is None:
            ap.error("outputs needs --dof")
        tmp = args.dst.with_name(args.dst.name + ".tmp")
        torch.save(read_outputs(args.src, args.dof), tmp)
        os.replace(tmp, args.dst)


if __name__ == "__main__":
    main()
