"""An arm run killed in its method's loop, then again in its ``labels_off_loop`` baseline's loop,
and resumed each time ends with the uninterrupted run's metrics and checkpoints, bit for bit (the
refill loops' work in flight is saved with each checkpoint, :mod:`protorch.loop.inflight`)."""

from __future__ import annotations

import hashlib
import json
import math

import pytest
from safetensors.torch import load_file

from protorch.experiments import loop_run, run_experiment
from protorch.experiments.common import flatten_metrics
from protorch.loop import state as state_mod

from ..loop.test_resume_inflight import inflight_file
from .test_arm_reach import NO_PHYSICS, cfg

# small, but with problems that stop at different iterations (a low tol over a short window), so
# that each checkpoint leaves environments half optimised in the refill loop's optimiser
SMALL = [
    "task.collision=skeleton",
    NO_PHYSICS,
    "settings.loop.num_envs=24",
    "settings.loop.batch_size=6",
    "settings.loop.add_only=all",
    "optimizer.max_iter=8",
    "optimizer.window=2",
    "optimizer.tol=0.05",
]


class Kill(Exception):
    """The process dying right after a checkpoint (nothing after it reaches the disk)."""


def numbers(out_dir) -> dict:
    """metrics.json flattened, timings and provenance left out (``resumed_from`` too: the one key
    a resumed run must differ in), plus a digest of each checkpoint's tensors."""
    m = json.loads((out_dir / "metrics.json").read_text())
    flat = {
        k: "nan" if isinstance(v, float) and math.isnan(v) else v
        for k, v in flatten_metrics(m).items()
        if "seconds" not in k
        and not k.endswith("resumed_from")
        and k != "settings.threads"
        and k != "summary.run_dir"
        and not k.startswith("run.")
    }
    for path in sorted(out_dir.rglob("dataset.safetensors")):
        t = load_file(path)
        flat[f"checkpoint:{path.parent.parent.relative_to(out_dir)}"] = hashlib.sha256(
            b"".join(t[k].numpy().tobytes() for k in sorted(t))
        ).hexdigest()
    return flat


@pytest.mark.slow
def test_a_run_killed_in_both_loops_resumes_to_the_uninterrupted_runs_numbers(
    tmp_path, monkeypatch
):
    monkeypatch.setattr(loop_run, "core_budget", lambda: 1)  # the baseline's loop runs here
    whole = tmp_path / "whole"
    run_experiment(cfg(*SMALL), whole)
    killed = tmp_path / "killed"
    checkpoint = state_mod.RunState.checkpoint

    def kill_after(folder, n):
        """``RunState.checkpoint`` that kills the run after the ``n``-th checkpoint in
        ``folder``."""
        count = {"n": 0}

        def patched(self, dataset, env_map):
            checkpoint(self, dataset, env_map)
            if self.run_dir == folder:
                count["n"] += 1
                if count["n"] == n:
                    raise Kill

        return patched

    base = killed / "baselines" / "labels_off_loop"
    for folder, again in ((killed, []), (base, ["resume=true"])):
        monkeypatch.setattr(state_mod.RunState, "checkpoint", kill_after(folder, 2))
        with pytest.raises(Kill):
            run_experiment(cfg(*SMALL, *again), killed)
        # the kill left that loop unfinished, with environments half optimised in flight
        tensors, saved = inflight_file(folder)
        busy = (tensors["slots.pick"] >= 0).repeat(saved["labels"])  # (K B,) label-major rows
        assert bool(busy.any()) and int(tensors["opt.tensor.age"][busy].max()) > 0
    monkeypatch.setattr(state_mod.RunState, "checkpoint", checkpoint)
    run_experiment(cfg(*SMALL, "resume=true"), killed)
    m = json.loads((killed / "metrics.json").read_text())
    assert m["loop"]["resumed_from"] == m["loop"]["steps"]  # finished by the second process
    assert m["baselines"]["labels_off_loop"]["loop"]["resumed_from"] == 2
    got, want = numbers(killed), numbers(whole)
    assert {k for k in want if k.startswith("checkpoint:")} == {
        "checkpoint:.",
        "checkpoint:baselines/labels_off_loop",
    }
    assert got == want
