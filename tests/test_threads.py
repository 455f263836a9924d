"""``torch_threads``: the number inside the block, the old one restored after it (also on error);
a run's metrics do not depend on the number."""

from __future__ import annotations

import pytest
import torch

from protorch.threads import torch_threads
from tests.small_runs import SMALL, small_run


def test_sets_and_restores_threads_even_when_the_block_raises():
    before = torch.get_num_threads()
    with torch_threads(1) as n:
        assert n == 1 and torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    with pytest.raises(RuntimeError):
        with torch_threads(1):
            raise RuntimeError("boom")
    assert torch.get_num_threads() == before


def test_none_leaves_torch_alone_and_bad_values_are_refused():
    before = torch.get_num_threads()
    with torch_threads(None) as n:
        assert n == before == torch.get_num_threads()
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="threads"):
            with torch_threads(bad):
                pass
    assert torch.get_num_threads() == before


def test_the_free_cores_rule():
    from protorch.threads import threads_for

    assert (
        threads_for(0.0, 2) == 2 and threads_for(0.2, 2) == 2
    )  # idle (a little noise): every core
    assert (
        threads_for(0.5, 2) == 1 and threads_for(1.0, 2) == 1
    )  # one competitor on 2 cores: one thread
    assert threads_for(5.0, 2) == 1  # never fewer than one
    assert threads_for(1.0, 8) == 7 and threads_for(0.0, 1) == 1


def test_auto_inside_a_fixed_setting_keeps_the_callers_number():
    from protorch.threads import ThreadGovernor

    before = torch.get_num_threads()
    with torch_threads(1):
        with ThreadGovernor("auto") as inner:  # the loop's default inside the app's threads=1
            assert inner.fixed == 1 and inner.step() == 1 and torch.get_num_threads() == 1
    assert torch.get_num_threads() == before


def test_the_probe_counts_the_machine_busy_time_minus_its_own(monkeypatch):
    import os
    from types import SimpleNamespace

    import protorch.threads as th

    hz, ncpu = os.sysconf("SC_CLK_TCK"), os.cpu_count() or 1
    machine = iter([(0, 0), (3 * hz // 2, ncpu * hz)])  # 1 s of wall time: 1.5 cores busy in all
    ours = iter([0.0, 0.5])  # of which this process used 0.5 core-seconds
    monkeypatch.setattr(th, "_machine_jiffies", lambda: next(machine))
    monkeypatch.setattr(th.os, "times", lambda: SimpleNamespace(user=next(ours), system=0.0))
    assert th.LoadProbe().other_cores() == pytest.approx(1.0)


@pytest.mark.slow
@pytest.mark.skipif(
    not __import__("os").path.exists("/proc/stat"), reason="the load probe reads /proc/stat"
)
def test_the_probe_sees_another_busy_process():
    import subprocess
    import sys
    import time

    from protorch.threads import LoadProbe

    spin = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        t0 = time.perf_counter()
        while (
            time.perf_counter() - t0 < 0.2
        ):  # the competitor starts; this process's work is its own
            pass
        probe = LoadProbe()
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < 0.5:
            pass
        other = probe.other_cores()
    finally:
        spin.kill()
        spin.wait()
    assert other > 0.6, other  # the spinner's core (any further load only adds to it)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SMALL))
def test_a_runs_metrics_are_the_same_at_one_and_two_threads(name):
    # the arm's physics episodes at one and two threads: test_the_physics_episodes_are_the_same_...
    one, two = small_run(name, 1, physics=False), small_run(name, 2, physics=False)
    assert any(k.startswith("checkpoint:") for k in one)
    assert one == two  # every metric, and the loops' data sets bit for bit


def test_the_core_budget_and_the_threads_beside_workers():
    from protorch.threads import available_cores, beside_workers, core_budget

    with torch_threads(1):
        assert (
            core_budget() == 1 and beside_workers(1) == 1
        )  # one core: never fewer than one thread
    with torch_threads(3):
        assert core_budget() == 3 and beside_workers(1) == 2
    with torch_threads("auto"):
        assert (
            core_budget() == available_cores() and beside_workers(1) == "auto"
        )  # auto measures the workers
    assert core_budget() == available_cores()  # no setting: the available cores


_PHYSICS_RUN = """
import hashlib, json, sys
from protorch.app.main import pin_mkl_code_path
pin_mkl_code_path()  # the app's MKL code path, before MKL's first call
import torch
from protorch.control.episodes import check_timing
from protorch.primitives.promp import ProMP
from protorch.robots import load_robot
PANDA_MAX_ACCELERATION = load_robot("panda").max_acceleration
from protorch.control.physics import FixedMeans, run_physics_episodes
from protorch.sim.scene import build_scene, controller_model
from protorch.tasks import ArmReachTask

task, promp = ArmReachTask(collision="volume"), ProMP(7, num_basis=10, num_steps=100, dtype=torch.float64)
env = torch.tensor([[0.55, 0.30, 0.70, -0.10]], dtype=torch.float64)
q, _ = task.ik_path(task.straight_paths(env, 100))
E = 120
w = promp.weights(q) + 1e-3 * torch.randn(E, 70, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
timing = check_timing(0.02, 0.2, 0.0)
out = {}
for threads in (1, 2):
    torch.set_num_threads(threads)  # as the app's threads= does
    res = run_physics_episodes(build_scene(task), controller_model(task), FixedMeans(w), promp, timing,
                               env.expand(E, timing.total + 1, -1), kp=400.0, kd=40.0, ref_kp=10.0,
                               max_acceleration=PANDA_MAX_ACCELERATION, threads=threads, feasible=0.9)
    out[threads] = {k: hashlib.sha256(getattr(res, k).tobytes()).hexdigest()[:16]
                    for k in ("q", "q_ref", "max_torque_ratio", "tracking_rms", "deepest", "final_goal_distance")}
print(json.dumps(out))
"""


@pytest.mark.slow
def test_the_physics_episodes_are_the_same_at_one_and_two_threads(same_bits_runs):
    """120 MuJoCo episodes (enough for MKL to split the markers' product differently on two threads
    under the app's code path) at threads=1 and threads=2 in one process: every array bit for
    bit."""
    pytest.importorskip("mujoco", minversion="4.0", reason="the physics extra is not installed")
    runs = same_bits_runs["physics"]
    assert runs["1"] == runs["2"]


def test_one_thread_runs_the_block_on_one_thread_and_restores_the_number():
    from protorch.threads import one_thread

    with torch_threads(2):
        with one_thread():
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2
        with pytest.raises(RuntimeError):
            with one_thread():
                raise RuntimeError("boom")
        assert torch.get_num_threads() == 2
    with torch_threads(1), one_thread():
        assert torch.get_num_threads() == 1


_TRAJECTORY_RUN = """
import hashlib, json
from protorch.app.main import pin_mkl_code_path
pin_mkl_code_path()  # the app's MKL code path, before MKL's first call
import torch
from protorch.primitives.promp import ProMP

def digest(x):
    return hashlib.sha256(x.numpy().tobytes()).hexdigest()[:16]

promp = ProMP(7, num_basis=10, num_steps=100, dtype=torch.float32)
fit = ProMP(7, num_basis=10, num_steps=100, dtype=torch.float64)
g = torch.Generator().manual_seed(0)
shapes = [(4, 100, 70), (200, 70), (20, 100, 70)]  # a cost chunk of the loop's samples, a batch of means, more
ws = [torch.randn(*s, generator=g) for s in shapes]
demos = [torch.randn(n, 100, 7, generator=g, dtype=torch.float64).cumsum(1) / 10 for n in (60, 2004)]  # demos, priors
out = {}
for threads in (1, 2):
    torch.set_num_threads(threads)
    out[threads] = [digest(promp.trajectory(w)) for w in ws] + [digest(fit.weights(y)) for y in demos]
print(json.dumps(out))
"""


@pytest.mark.slow
def test_the_promp_trajectories_and_weights_are_the_same_at_one_and_two_threads(same_bits_runs):
    """The ProMP's basis product (trajectories at the loop's sizes) and its ridge regression (the
    weights of 60 demonstrations and of 2,004 priors) under the app's MKL code path, at threads=1
    and threads=2 in one process, bit for bit: MKL on two threads gave other last bits for each
    (the ``(4, 100, 70)`` cost chunk of the reduced arm run among them), which the loop carried
    into its data set."""
    runs = same_bits_runs["trajectory"]
    assert runs["1"] == runs["2"]


_ARM_COSTS_RUN = """
import hashlib, json
from protorch.app.main import pin_mkl_code_path
pin_mkl_code_path()  # the app's MKL code path, before MKL's first call
import torch
from protorch.tasks import ArmReachTask

def digest(x):
    return hashlib.sha256(x.numpy().tobytes()).hexdigest()[:16]

task = ArmReachTask(collision="volume")  # its can objective: the end link's capsules
g = torch.Generator().manual_seed(0)
lo, hi = task.kinematics.lower.float(), task.kinematics.upper.float()
q = lo + (hi - lo) * torch.rand(18, 100, 25, 7, generator=g)  # (c, S, T', D) a cost chunk of the reduced arm run
env = task.sample_envs(18, g, dtype=torch.float32)[:, None]  # (c, 1, 4)
out = {}
for threads in (1, 2):
    torch.set_num_threads(threads)
    out[threads] = [digest(task.costs(q, env)), digest(task.success(q, env)), digest(task.side(q, env))]
print(json.dumps(out))
"""


@pytest.mark.slow
def test_the_arm_costs_are_the_same_at_one_and_two_threads(same_bits_runs):
    """The arm's objectives (float32, volume can objective), success and class on a cost chunk of
    the reduced arm run's size (18 problems x 100 samples x 25 steps) under the app's MKL code
    path, at threads=1 and threads=2 in one process, bit for bit: the can objective places the end
    link's capsule ends with one ``(2C, 4) @ (4, P)`` product per coordinate, whose columns MKL
    split between two threads with other last bits. In the reduced arm run that changed one can
    objective value of its 133rd cost evaluation (48,600 values) at threads=2, and with it one
    learned entry of its data set."""
    runs = same_bits_runs["arm_costs"]
    assert runs["1"] == runs["2"]


_ONE_PROCESS = """
import json, sys
from protorch.app.main import pin_mkl_code_path
pin_mkl_code_path()  # the app's MKL code path, before MKL's first call
out = {}
for name, code in json.loads(sys.argv[1]).items():
    try:
        ns = {"__name__": "__" + name + "__"}
        exec(code, ns)  # each script prints its own line; its result is ns["out"]
        out[name] = ns["out"]
    except ImportError as exc:  # the physics extra not installed: that test skips
        out[name] = repr(exc)
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def same_bits_runs():
    """The three same-bits scripts above in one fresh process (each sets its own thread counts;
    one interpreter start instead of three): ``{script: {"1": digests, "2": digests}}``."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    scripts = {"physics": _PHYSICS_RUN, "trajectory": _TRAJECTORY_RUN, "arm_costs": _ARM_COSTS_RUN}
    proc = subprocess.run(
        [sys.executable, "-c", _ONE_PROCESS, json.dumps(scripts)],
        cwd=Path(__file__).resolve().parents[1],
        capture_output=True,
        text=True,
        check=True,
    )
    runs = json.loads(proc.stdout.strip().splitlines()[-1])
    return {
        k: {str(t): d for t, d in v.items()} if isinstance(v, dict) else v for k, v in runs.items()
    }
