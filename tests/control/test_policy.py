"""The policy object (protorch.policy.policy): the reference equals the map's label-aware mean at
a fixed environment, the fast means equal the map's, the reference stays continuous when the
environment jumps, bad input is refused, run folders are read or refused, and the exported program
runs without protorch and equals policy.reference."""

from __future__ import annotations

import gc
import math
import shutil
import subprocess
import sys
import textwrap
import weakref
from pathlib import Path

import pytest
import torch

from protorch import ProMP
from protorch.control.episodes import promp_state_at
from protorch.gp import make_env_map
from protorch.gp.model import label_aware_mean
from protorch.policy.means import MAX_RANK, ClassMeans
from protorch.policy.policy import Policy

F64 = torch.float64


class TwoWays:
    """A user's own task with two classes: 2 DoF, the environment ``(2,)`` a goal; the objectives
    are the end's distance to the goal and the bend of the path halfway (no Python branch on
    values, so torch.export can trace it)."""

    name = "two_ways"
    env_dim = 2
    num_dof = 2

    def costs(self, traj, env):  # (..., T, 2), (..., 2) -> (..., 2)
        end = (traj[..., -1, :] - env).norm(dim=-1)
        bend = traj[..., traj.shape[-2] // 2, 1].abs()
        return torch.stack([end, 0.1 * bend], -1)

    def sample_envs(self, n, generator=None, dtype=F64):
        return torch.rand(n, 2, generator=generator, dtype=dtype)


def toy_policy(nearest_k=None, seed=0, backend="torch", **kw) -> Policy:
    g = torch.Generator().manual_seed(seed)
    promp = ProMP(2, 10, 50)
    m = 40
    E = torch.rand(m, 2, generator=g, dtype=F64)  # (M, 2)
    MU = torch.randn(m, promp.num_weights, generator=g, dtype=F64)  # (M, N)
    VAR = 10 ** (-3 + torch.rand(m, promp.num_weights, generator=g, dtype=F64))  # (M, N)
    labels = torch.arange(m) % 2
    env_map = make_env_map(backend, 3.0, nearest_k=nearest_k).fit(E, MU, VAR, labels)
    return Policy(
        promp, env_map, "two_ways", task=TwoWays(), **{"duration": 2.0, "switch_margin": 0.05, **kw}
    )


@pytest.mark.parametrize(
    "nearest_k, backend",
    [(None, "torch"), (8, "torch"), (8, "gpytorch"), (8, "sparse"), (20, "torch")],
)  # 20: every entry of a class, the same rows in both
def test_class_means_equal_the_maps_prediction(nearest_k, backend):
    pol = toy_policy(nearest_k, backend=backend)
    envs = torch.rand(20, 2, generator=torch.Generator().manual_seed(1), dtype=F64)
    for e in envs:
        fast = pol.means(e)  # (2, N)
        want = pol.env_map.predict_mean(e.expand(2, -1), torch.tensor([0, 1]))  # (2, N)
        torch.testing.assert_close(fast, want, rtol=0, atol=1e-12)
        torch.testing.assert_close(pol.means(e, [1])[0], want[1], rtol=0, atol=1e-12)


def test_class_means_along_a_walk_equal_the_maps_prediction():
    """A slowly moving environment on a map large enough for the candidate search, with neighbour
    sets changing by one environment (swap updates) and by more (new factorisations)."""
    g = torch.Generator().manual_seed(5)
    promp = ProMP(2, 6, 30)
    m = 600
    E = torch.rand(m, 2, generator=g, dtype=F64)  # (M, 2)
    MU = torch.randn(m, promp.num_weights, generator=g, dtype=F64)  # (M, N)
    VAR = 10 ** (-3 + torch.rand(m, promp.num_weights, generator=g, dtype=F64))  # (M, N)
    env_map = make_env_map("torch", 30.0, nearest_k=10).fit(E, MU, VAR, torch.arange(m) % 2)
    means = ClassMeans(env_map)
    steps = torch.linspace(0, 1, 400, dtype=F64)[:, None]
    walk = torch.tensor([0.2, 0.3], dtype=F64) + steps * torch.tensor(
        [0.5, 0.4], dtype=F64
    )  # (400, 2)
    walk = walk + 2e-3 * torch.randn(
        walk.shape, generator=g, dtype=F64
    )  # noisy: sets flip back and forth
    for i, e in enumerate(walk):
        fast = means(e) if i % 3 == 0 else means(e, [i % 2])  # (K', N)
        want = env_map.predict_mean(e.expand(2, -1), torch.tensor([0, 1]))  # (2, N)
        torch.testing.assert_close(
            fast, want if i % 3 == 0 else want[i % 2 : i % 2 + 1], rtol=0, atol=1e-12
        )
    assert means.updates > 20 and means.misses > means.updates  # both kinds of solve ran
    assert means.full_searches < 0.5 * 400  # the candidates served most searches
    # a set's inverses readied ahead of its next swap, or its pending swap terms written into them
    # (ClassMeans.prepare, on a call with time to spare), give the map's means as the swaps doing it
    # themselves (pending terms up to MAX_RANK, then written) do
    ready, lazy, prepared = ClassMeans(env_map), ClassMeans(env_map), 0
    for e in walk:
        want = env_map.predict_mean(e.expand(2, -1), torch.tensor([0, 1]))  # (2, N)
        torch.testing.assert_close(ready(e), want, rtol=0, atol=1e-12)
        torch.testing.assert_close(lazy(e), want, rtol=0, atol=1e-12)
        prepared += ready.prepare(0) + ready.prepare(1)
    assert (
        prepared > ready.misses - ready.updates >= 2 and ready.updates == lazy.updates > 20
    )  # every factorised set, and more
    assert all(
        s.U is None or 2 * s.U.shape[-1] <= MAX_RANK for s in ready.base
    )  # spare calls wrote the larger ones
    # a set taken back from the cache holds no inverse once newer sets pushed it out of the factor
    # cache (one set here): the next change still swaps, from the class's newest set holding one
    small = ClassMeans(env_map, factor_cache=1)
    for e in walk:
        torch.testing.assert_close(
            small(e),
            env_map.predict_mean(e.expand(2, -1), torch.tensor([0, 1])),
            rtol=0,
            atol=1e-12,
        )
    assert (
        small.misses == lazy.misses and small.misses - small.updates <= 4
    )  # (76 of 123 factorised before)


class _Node:
    pass


def test_loading_collects_the_garbage_so_that_a_call_does_not():
    """A reference cycle that became garbage in the collector's oldest generation before the
    policy was built is freed by the build (its warm-up ends with a full collection, ~0.1 s over
    torch's objects), not later by whichever call of the loop the collector's counts pick, and the
    counts start afresh."""
    gc.collect()
    holder = [_Node()]
    holder[0].me = holder[0]  # a cycle: only the cyclic collector frees it
    gone = weakref.ref(holder[0])
    gc.collect()  # the cycle, still reachable, moves to the oldest generation
    holder.clear()  # now garbage there
    assert gone() is not None
    toy_policy(8)
    assert gone() is None
    assert gc.get_count()[1:] == (0, 0)


def test_the_fast_end_effector_equals_the_kinematics():
    from protorch.policy.means import EndEffector
    from protorch.tasks.arm.reach import ArmReachTask

    kin = ArmReachTask().kinematics
    q = kin.lower + (kin.upper - kin.lower) * torch.rand(
        40, 7, generator=torch.Generator().manual_seed(6), dtype=F64
    )
    torch.testing.assert_close(EndEffector(kin)(q), kin.ee_position(q), rtol=0, atol=1e-12)


@pytest.mark.parametrize("nearest_k", [None, 8])
def test_reference_at_a_fixed_environment_is_the_label_aware_mean(nearest_k):
    pol = toy_policy(nearest_k)
    envs = torch.rand(12, 2, generator=torch.Generator().manual_seed(2), dtype=F64)
    labels = set()
    for e in envs:
        best = label_aware_mean(pol.env_map, pol.promp, pol.task, e[None], dtype=F64)
        pol.reset()
        for t in (0.0, 0.013, 0.7, 1.999, 2.0, 3.5):
            r = pol.reference(e, t)
            z = min(t / pol.duration, 1.0)
            pos, dpos = promp_state_at(pol.promp, best.mean[0], z)
            assert r.label == int(best.label[0])
            torch.testing.assert_close(r.q, pos, rtol=0, atol=1e-12)
            torch.testing.assert_close(
                r.qd, dpos / pol.duration if z < 1 else torch.zeros_like(pos), rtol=0, atol=1e-12
            )
            if 0 < z < 1:  # the acceleration: the velocity's derivative
                h = 1e-5
                _, d1 = promp_state_at(pol.promp, best.mean[0], z + h / pol.duration)
                _, d0 = promp_state_at(pol.promp, best.mean[0], z - h / pol.duration)
                torch.testing.assert_close(
                    r.qdd, (d1 - d0) / pol.duration / (2 * h), rtol=1e-5, atol=1e-6
                )
        labels.add(int(best.label[0]))
    assert labels == {0, 1}  # both classes were chosen somewhere
    assert pol.mean_trajectory(envs).shape == (12, 50, 2)  # chooses the class itself


def test_the_reference_stays_continuous_when_the_environment_jumps():
    pol = toy_policy(8)
    raw = toy_policy(8, blend=math.inf)  # the chosen mean itself
    a, b = torch.tensor([0.2, 0.3], dtype=F64), torch.tensor([0.8, 0.9], dtype=F64)
    dq, dq_raw, dqd, speed = 0.0, 0.0, 0.0, 0.0
    prev = prev_raw = None
    for i in range(6000):  # 1 kHz, the goal jumps at 0.8 s; duration 2 s, then held
        t = i * 1e-3
        env = a if t < 0.8 else b
        r, rr = pol.reference(env, t), raw.reference(env, t)
        if prev is not None:
            dq = max(dq, float((r.q - prev.q).abs().max()))
            dqd = max(dqd, float((r.qd - prev.qd).abs().max()))
            dq_raw = max(dq_raw, float((rr.q - prev_raw.q).abs().max()))
        speed = max(speed, float(r.qd.abs().max()))
        prev, prev_raw = r, rr
    assert dq_raw > 0.05  # the mean jumps
    assert dq <= 1.01 * speed * 1e-3 + 1e-12  # the reference moves by its own velocity only
    assert dqd < 0.1 * dq_raw / 1e-3 * 1e-2  # no velocity jump of the size of the mean's
    # long after the jump the offset has decayed: the held end of the new mean
    torch.testing.assert_close(prev.q, prev_raw.q, rtol=0, atol=1e-9)


def test_past_the_end_the_last_point_is_held():
    pol = toy_policy(8)
    e = torch.tensor([0.4, 0.6], dtype=F64)
    end = pol.reference(e, pol.duration)
    late = pol.reference(e, 10 * pol.duration)
    torch.testing.assert_close(late.q, end.q, rtol=0, atol=0)
    assert float(late.qd.abs().max()) == 0 and float(late.qdd.abs().max()) == 0


@pytest.mark.parametrize(
    "env, t, match",
    [
        (torch.zeros(3, dtype=F64), 0.0, r"env must be \(2,\)"),
        (torch.tensor([0.1, float("nan")], dtype=F64), 0.0, "env holds NaN"),
        (torch.tensor([0.1, 0.2], dtype=F64), -0.01, "t must be a finite time >= 0"),
        (torch.tensor([0.1, 0.2], dtype=F64), float("nan"), "t must be a finite time >= 0"),
    ],
)
def test_bad_input_is_refused_with_the_argument_named(env, t, match):
    with pytest.raises(ValueError, match=match):
        toy_policy(8).reference(env, t)


def test_a_map_with_classes_but_no_task_says_what_it_needs():
    pol = toy_policy(8)
    bare = Policy(pol.promp, pol.env_map, "two_ways")
    with pytest.raises(ValueError, match="needs the run's task"):
        bare.reference(torch.tensor([0.1, 0.2], dtype=F64), 0.0)
    with pytest.raises(ValueError, match="several labels"):
        bare.mean_trajectory(torch.rand(2, 2, dtype=F64))


def test_a_run_folder_of_another_experiment_or_format_is_refused(tmp_path):
    import protorch

    other = tmp_path / "fig3"
    other.mkdir()
    (other / "config.yaml").write_text("name: fig3_toy\nseed: 0\n")
    with pytest.raises(
        ValueError, match=r"run=.*fig3.*experiment 'fig3_toy' is not a self-improvement run"
    ):
        protorch.load(other)
    old = tmp_path / "old"
    old.mkdir()
    (old / "config.yaml").write_text("name: arm_reach\nseed: 0\nsettings:\n  no_such_setting: 1\n")
    with pytest.raises(ValueError, match=r"run=.*old.*older format"):
        protorch.load(old)
    with pytest.raises(FileNotFoundError, match="run="):
        protorch.load(tmp_path / "missing")


BLOCKED_RUNNER = textwrap.dedent("""
    import sys
    class Block:  # protorch must not be needed
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] == "protorch":
                raise ImportError("protorch is blocked in this process")
    sys.meta_path.insert(0, Block())
    import torch
    program, inputs, out = sys.argv[1:4]
    run = torch.export.load(program).module()
    data = torch.load(inputs, weights_only=True)
    res = [run(e, t) for e, t in zip(data["env"], data["t"])]
    torch.save({"q": torch.stack([r[0] for r in res]), "qd": torch.stack([r[1] for r in res]),
                "qdd": torch.stack([r[2] for r in res]), "label": torch.stack([r[3] for r in res])}, out)
    assert not any(m.split(".")[0] == "protorch" for m in sys.modules)
""")


def check_export(
    pol: Policy, tmp_path: Path, envs: torch.Tensor, calls: int = 1000, seed: int = 0
) -> None:
    """``pol.export``'s program run in a fresh process where protorch cannot be imported equals
    ``reset(); reference(env, t)`` over ``calls`` random calls to 1e-9."""
    g = torch.Generator().manual_seed(seed)
    program = pol.export(tmp_path / "policy.pt2")
    env = envs[torch.randint(envs.shape[0], (calls,), generator=g)]  # (calls, d)
    t = 1.3 * pol.duration * torch.rand(calls, generator=g, dtype=F64)  # (calls,) the hold included
    torch.save({"env": env, "t": t}, tmp_path / "inputs.pt")
    script = tmp_path / "run_program.py"
    script.write_text(BLOCKED_RUNNER)
    proc = subprocess.run(
        [
            sys.executable,
            str(script),
            str(program),
            str(tmp_path / "inputs.pt"),
            str(tmp_path / "out.pt"),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = torch.load(tmp_path / "out.pt", weights_only=True)
    labels = set()
    for i in range(calls):
        pol.reset()
        r = pol.reference(env[i], float(t[i]))
        for name in ("q", "qd", "qdd"):
            torch.testing.assert_close(out[name][i], getattr(r, name), rtol=0, atol=1e-9)
        assert int(out["label"][i]) == r.label
        labels.add(r.label)
    assert labels == set(pol.labels.tolist())  # every class was chosen somewhere


@pytest.mark.slow
@pytest.mark.parametrize("nearest_k", [None, 8])
def test_the_exported_program_runs_without_protorch_and_equals_reference(tmp_path, nearest_k):
    pol = toy_policy(nearest_k)
    check_export(
        pol,
        tmp_path,
        torch.rand(300, 2, generator=torch.Generator().manual_seed(4), dtype=F64),
        calls=300,
    )


@pytest.mark.slow
@pytest.mark.skipif(
    shutil.which("c++") is None and shutil.which("g++") is None,
    reason="AOTInductor compiles C++: no compiler on this machine",
)
def test_the_aoti_compiled_program_equals_reference(tmp_path):
    """``export(aoti=True)``: the package AOTInductor builds, loaded by torch alone, gives the
    reference and the class of ``reset(); reference(env, t)`` (the hold included)."""
    pol = toy_policy(8)
    program = torch._inductor.aoti_load_package(
        str(pol.export(tmp_path / "policy_aoti.pt2", aoti=True))
    )
    g = torch.Generator().manual_seed(6)
    labels = set()
    for env, t in zip(
        torch.rand(100, 2, generator=g, dtype=F64),
        1.3 * pol.duration * torch.rand(100, generator=g, dtype=F64),
    ):
        q, qd, qdd, label = program(env, t)
        pol.reset()
        r = pol.reference(env, float(t))
        for got, want in ((q, r.q), (qd, r.qd), (qdd, r.qdd)):
            torch.testing.assert_close(got, want, rtol=0, atol=1e-9)
        assert int(label) == r.label
        labels.add(r.label)
    assert labels == {0, 1}
