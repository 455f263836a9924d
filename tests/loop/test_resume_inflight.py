"""A killed refill loop resumes bit for bit: the environments in flight at its checkpoint (the
optimiser's rows, its random generator, the slots) are saved beside the data set and put back,
so the resumed run's data set, map and metrics rows are the uninterrupted run's exactly."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest
import torch

from protorch import RWR
from protorch.data.checkpoint import checkpoint_path
from protorch.data.dataset import TrajectoryDataset
from protorch.data.files import CheckpointError, read_safetensors
from protorch.loop import state as state_mod
from protorch.loop.inflight import (
    INFLIGHT_FORMAT,
    INFLIGHT_SCHEMA,
    load_optimizer_state,
    optimizer_state,
)

from .test_loop import KW, ROOT, Crash, crash_at_2, loop, setup

RUN = dict(num_envs=12, batch_size=3, refill=True)
FIELDS = ("env", "mean", "var", "label", "origin", "converged", "cost")


def same_run(res, whole) -> None:
    """``res`` (resumed) is ``whole`` (uninterrupted) bit for bit: data set, order of the
    environments, metrics rows (timings aside) and the map's predictions."""
    assert res.tried == whole.tried
    for f in FIELDS:
        a, b = getattr(res.dataset, f), getattr(whole.dataset, f)
        assert a.dtype == b.dtype and a.numpy().tobytes() == b.numpy().tobytes(), f  # NaN too
    strip = [{k: v for k, v in r.items() if k != "seconds"} for r in res.metrics]
    assert strip == [{k: v for k, v in r.items() if k != "seconds"} for r in whole.metrics]
    q = setup()[0].sample_envs(5, torch.Generator().manual_seed(9))  # (5, 2)
    assert torch.equal(res.env_map.predict_mean(q), whole.env_map.predict_mean(q))


def inflight_file(run):
    """The in-flight file the run's checkpoint names, read back: ``(tensors, state)``."""
    record = TrajectoryDataset.load(checkpoint_path(run)).metadata["loop"]["inflight"]
    path = checkpoint_path(run).parent / record["file"]
    tensors, body = read_safetensors(
        path, fmt=INFLIGHT_FORMAT, schema_version=INFLIGHT_SCHEMA, keys=record["keys"]
    )
    return tensors, body["state"]


@pytest.mark.parametrize("optimizer", ["pro", "rwr"])
def test_a_refill_loop_killed_after_a_checkpoint_resumes_bit_for_bit(tmp_path, optimizer):
    extra = (
        {}
        if optimizer == "pro"
        else {
            "optimizer": RWR,
            "optimizer_kwargs": {k: KW[k] for k in ("beta", "num_samples", "max_iter", "tol")}
            | {"window": 2},
        }
    )
    task, promp, ds = setup()
    whole = loop(task, promp, ds, **RUN, **extra)
    run = tmp_path / "run"
    with pytest.raises(Crash):
        loop(task, promp, setup()[2], **RUN, **extra, run_dir=run, on_step=crash_at_2)
    tensors, saved = inflight_file(run)
    # the kill left environments half optimised, at different ages: what a resume must keep
    busy = tensors["slots.pick"] >= 0  # (B,)
    assert saved["pending"] and 0 < int(busy.sum()) < 3
    assert int(tensors["opt.tensor.age"][busy].min()) > 0
    tried = TrajectoryDataset.load(checkpoint_path(run)).metadata["loop"]["tried"]
    assert set(saved["started"]) > set(tried)  # started: the finished and those in flight
    res = loop(task, promp, setup()[2], **RUN, **extra, run_dir=run, resume=True)
    assert res.resumed_from == 2
    same_run(res, whole)
    # the finished run's checkpoint holds nothing in flight, and no in-flight file is left
    assert "inflight" not in TrajectoryDataset.load(checkpoint_path(run)).metadata["loop"]
    assert not list(checkpoint_path(run).parent.glob("inflight-*"))


def test_a_kill_between_the_inflight_file_and_the_data_set_resumes_from_the_previous_one(
    tmp_path, monkeypatch
):
    task, promp, ds = setup()
    whole = loop(task, promp, ds, **RUN)
    run = tmp_path / "run"
    calls = {"n": 0}
    checkpoint = state_mod.RunState.checkpoint

    def dying(self, dataset, env_map):
        calls["n"] += 1
        if calls["n"] == 3:  # the in-flight file of step 3 is written, then the process dies
            save = self.save

            def die(*a, **k):
                raise Crash

            self.save = die
            try:
                checkpoint(self, dataset, env_map)
            finally:
                self.save = save
        checkpoint(self, dataset, env_map)

    monkeypatch.setattr(state_mod.RunState, "checkpoint", dying)
    with pytest.raises(Crash):
        loop(task, promp, setup()[2], **RUN, run_dir=run)
    monkeypatch.undo()
    folder = checkpoint_path(run).parent
    assert sorted(p.name for p in folder.glob("inflight-*")) == [
        "inflight-2.safetensors",
        "inflight-3.safetensors",
    ]
    assert TrajectoryDataset.load(checkpoint_path(run)).metadata["loop"]["step"] == 2
    res = loop(task, promp, setup()[2], **RUN, run_dir=run, resume=True)
    assert res.resumed_from == 2
    same_run(res, whole)


def test_a_missing_or_foreign_inflight_file_is_refused_naming_it(tmp_path):
    task, promp, _ = setup()
    run = tmp_path / "run"
    with pytest.raises(Crash):
        loop(task, promp, setup()[2], **RUN, run_dir=run, on_step=crash_at_2)
    folder = checkpoint_path(run).parent
    (path,) = folder.glob("inflight-*.safetensors")
    data = path.read_bytes()
    other = tmp_path / "other"
    with pytest.raises(Crash):  # another run's file of the same step, put in its place
        loop(task, promp, setup(5)[2], **RUN, run_dir=other, on_step=crash_at_2)
    path.write_bytes((checkpoint_path(other).parent / path.name).read_bytes())
    with pytest.raises(CheckpointError, match="not the in-flight state"):
        loop(task, promp, setup()[2], **RUN, run_dir=run, resume=True)
    path.unlink()
    with pytest.raises(CheckpointError, match=f"{path.name} is missing"):
        loop(task, promp, setup()[2], **RUN, run_dir=run, resume=True)
    path.write_bytes(data)
    assert loop(task, promp, setup()[2], **RUN, run_dir=run, resume=True).resumed_from == 2


def test_an_optimiser_state_round_trip_goes_on_with_the_same_numbers():
    from protorch import PRO

    def cost(w):  # (B, S, N) -> (B, S, 2)
        return torch.stack([(w - 1).pow(2).sum(-1), w.abs().sum(-1)], -1)

    def run(opt, n):
        for _ in range(n):
            it = opt.iteration
            while opt.iteration == it:
                opt.tell(cost(opt.ask()))

    kw = dict(beta=10.0, relevance_samples=20, num_samples=20, max_iter=100, tol=0.0)
    a = PRO(torch.zeros(4, 3, dtype=torch.float64), torch.ones(4, 3), seed=1, **kw)
    a.history_limit = 3
    run(a, 4)
    a.restart(torch.tensor([1]), torch.full((1, 3), 0.5), torch.ones(1, 3))
    tensors, meta = optimizer_state(a)
    b = PRO(torch.zeros(4, 3, dtype=torch.float64), torch.ones(4, 3), seed=7, **kw)
    b.history_limit = 3
    load_optimizer_state(b, {k: t.clone() for k, t in tensors.items()}, meta)
    run(a, 3)
    run(b, 3)
    assert a.iteration == b.iteration == 7
    for x, y in ((a.mean, b.mean), (a.var, b.var), (a.age, b.age), (a.rollouts, b.rollouts)):
        assert torch.equal(x, y)
    assert torch.equal(a.converged, b.converged)
    a.ask()
    with pytest.raises(RuntimeError, match="between two iterations"):
        optimizer_state(a)


SCRIPT = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {root!r})
    from tests.loop.test_loop import loop, setup
    from tests.loop.test_resume_inflight import RUN
    task, promp, ds = setup()
    loop(task, promp, ds, **{{**RUN, "num_envs": 24}}, threads=1, run_dir={run!r}, resume=True,
         on_step=lambda row: time.sleep(0.2))
    print("finished")
""")


@pytest.mark.slow
def test_a_refill_loop_sigkilled_at_any_instant_resumes_bit_for_bit(tmp_path):
    task, promp, ds = setup()
    whole = loop(task, promp, ds, **{**RUN, "num_envs": 24}, threads=1)
    run = tmp_path / "run"
    script = tmp_path / "job.py"
    script.write_text(SCRIPT.format(root=str(ROOT), run=str(run)))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, str(script)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    ckpt = checkpoint_path(run)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        if ckpt.is_file() and TrajectoryDataset.load(ckpt).metadata["loop"]["step"] >= 2:
            time.sleep(0.1)  # somewhere in the next steps' work (or inside a checkpoint)
            break
        time.sleep(0.02)
    assert proc.poll() is None, f"the loop ended before it was killed: {proc.stderr.read()!r}"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    state = TrajectoryDataset.load(ckpt).metadata["loop"]
    assert 2 <= state["step"] and len(state["tried"]) < 24 and "inflight" in state
    out = subprocess.run(
        [sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0 and "finished" in out.stdout, out.stderr
    final = TrajectoryDataset.load(ckpt)
    assert final.metadata["loop"]["tried"] == whole.tried
    for f in FIELDS:
        a, b = getattr(final, f), getattr(whole.dataset, f)
        assert a.numpy().tobytes() == b.numpy().tobytes(), f
    rows = final.metadata["loop"]["rows"]
    assert [{k: v for k, v in r.items() if k != "seconds"} for r in rows] == [
        {k: v for k, v in r.items() if k != "seconds"} for r in whole.metrics
    ]
