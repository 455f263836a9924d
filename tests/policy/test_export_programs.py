"""The two halves exported (protorch.policy.programs): a process where protorch cannot be
imported drives the planner program every few ticks and the tracker program every tick
(examples/exported_loop.py), each one's state passed in and out, and its references equal the
threaded Python policy's given the same inputs (the same plans made at the same ticks)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from tests.control.test_policy import toy_policy
from tests.policy.test_two_rate import walk

F64 = torch.float64
ROOT = Path(__file__).resolve().parents[2]

BLOCKED = textwrap.dedent("""
    import runpy, sys
    class Block:  # protorch must not be needed
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] == "protorch":
                raise ImportError("protorch is blocked in this process")
    sys.meta_path.insert(0, Block())
    sys.argv = sys.argv[1:]
    runpy.run_path(sys.argv[0], run_name="__main__")
    assert not any(m.split(".")[0] == "protorch" for m in sys.modules)
""")


def python_loop(pol, envs, q0, qd0, every: int) -> dict:
    """The threaded policy on the driver's loop: its planner's step on the tick's inputs at every
    ``every``-th tick, then ``reference``; the arm on its reference."""
    pol.reset()
    q, qd = q0, qd0
    out: dict[str, list] = {k: [] for k in ("q", "qd", "qdd", "label", "plan_t")}
    for i in range(envs.shape[0]):
        t = i * 1e-3
        if i % every == 0:
            with pol._planner.lock:
                pol._planner.plan = pol._plan(
                    pol._motion, envs[i].numpy(), t, q.numpy(), qd.numpy()
                )
        r = pol.reference(envs[i], t, q, qd)
        for k in ("q", "qd", "qdd"):
            out[k].append(getattr(r, k))
        out["label"].append(r.label)
        out["plan_t"].append(r.plan_t)
        q, qd = r.q, r.qd
    return out


def check_programs(pol, tmp_path: Path, envs, q0, every: int, aoti: bool | str = False) -> set:
    """Export ``pol``'s halves, drive them without protorch, compare with :func:`python_loop`
    to 1e-9; the classes tracked."""
    folder = pol.export(tmp_path / "programs", aoti=aoti)
    meta = json.loads((folder / "programs.json").read_text())
    assert (
        meta["aoti"] == {"planner": aoti is True, "tracker": bool(aoti)}
        and meta["dof"] == pol._d
        and meta["labels"] == pol._label_list
        and meta["limits"] is None  # the programs' references are unlimited: compared below
    )
    qd0 = torch.zeros_like(q0)
    torch.save({"env": envs, "q0": q0, "qd0": qd0}, tmp_path / "inputs.pt")
    (tmp_path / "blocked.py").write_text(BLOCKED)
    args = [str(folder), "--inputs", str(tmp_path / "inputs.pt"), "--out", str(tmp_path / "o.pt")]
    proc = subprocess.run(
        [sys.executable, str(tmp_path / "blocked.py"), str(ROOT / "examples" / "exported_loop.py")]
        + args
        + ["--plan-every", str(every)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "protorch imported: False" in proc.stdout
    got = torch.load(tmp_path / "o.pt", weights_only=True)
    want = python_loop(pol, envs, q0, qd0, every)
    for k in ("q", "qd", "qdd"):
        torch.testing.assert_close(got[k], torch.stack(want[k]), rtol=0, atol=1e-9)
    assert got["label"].tolist() == want["label"]
    assert got["plan_t"].tolist() == want["plan_t"]
    return set(want["label"])


def test_the_exported_halves_driven_without_protorch_equal_the_threaded_policy(tmp_path):
    """The toy map (two classes, a switch on the way, environment jumps every 97 ticks): a plan
    every 5 ticks, the class decided every 20 ms; the first tick starts at the measured joints."""
    pol = toy_policy(nearest_k=8, planner="thread", plan_period=1e6)
    labels = check_programs(pol, tmp_path, walk(400), torch.tensor([0.1, -0.2], dtype=F64), 5)
    assert labels == {0, 1}
    pol.close()


def test_programs_json_names_the_limits_of_the_two_halves(tmp_path):
    """``programs.json``'s ``limits``: those the two halves run with in Python, the robot's
    (here given) joint by joint by default, also where the policy itself was loaded inline (its
    exported halves are ``planner="thread"``'s); ``"together"`` synchronised; ``False`` none."""
    lim = {"max_velocity": 1.5, "max_acceleration": 4.0, "max_jerk": 900.0}
    want = {
        "max_velocity": [1.5, 1.5],
        "max_acceleration": [4.0, 4.0],
        "max_jerk": [900.0, 900.0],
    }
    for i, (options, expect) in enumerate(
        [
            ({}, {**want, "synchronised": False}),
            ({"planner": "thread", "plan_period": 1e6}, {**want, "synchronised": False}),
            (
                {"planner": "thread", "plan_period": 1e6, "limits": "together"},
                {**want, "synchronised": True},
            ),
            ({"limits": False}, None),
        ]
    ):
        pol = toy_policy(nearest_k=8, warm_up=False, **lim, **options)
        folder = pol.export(tmp_path / str(i))
        assert json.loads((folder / "programs.json").read_text())["limits"] == expect, options
        pol.close()


def test_a_single_tick_of_each_program_keeps_its_state_explicit():
    """The programs keep nothing between calls: the same inputs and state give the same
    outputs whatever ran before (state passed in and out only)."""
    from protorch.policy.programs import PlannerProgram, TrackerProgram, tracker_state

    pol = toy_policy(nearest_k=8)
    planner, tracker = PlannerProgram(pol), TrackerProgram(pol)
    env, q = torch.tensor([0.4, 0.5], dtype=F64), torch.tensor([0.1, -0.2], dtype=F64)
    t, none = torch.tensor(0.013, dtype=F64), torch.tensor(-1)
    first = planner(env, t, q, torch.zeros_like(q), none, none)
    planner(env + 0.2, t, q, torch.zeros_like(q), none, none)
    again = planner(env, t, q, torch.zeros_like(q), none, none)
    for a, b in zip(first, again):
        assert torch.equal(a, b)
    assert int(first[3]) == 0 and int(first[2]) == pol._label_list.index(int(first[1]))
    # between decisions (the same slot) the tracked class is kept whatever the scores
    other = torch.tensor(1 - int(first[2]))
    kept = planner(env, t, q, torch.zeros_like(q), other, first[3])
    assert int(kept[2]) == int(other) and int(kept[3]) == int(first[3])
    state = tracker_state(pol)
    a = tracker(t, first[0], q, torch.zeros_like(q), *state)
    torch.testing.assert_close(a[0], q, rtol=0, atol=1e-12)  # a motion starts where the arm is
    b = tracker(t, first[0], q, torch.zeros_like(q), *state)
    for x, y in zip(a, b):
        assert torch.equal(x, y)


@pytest.mark.slow
@pytest.mark.skipif(
    shutil.which("c++") is None and shutil.which("g++") is None,
    reason="AOTInductor compiles C++: no compiler on this machine",
)
def test_the_aoti_compiled_halves_equal_the_threaded_policy(tmp_path):
    """``export(folder, aoti=True)``: the AOTInductor packages, loaded by torch alone."""
    pol = toy_policy(nearest_k=8, planner="thread", plan_period=1e6)
    check_programs(pol, tmp_path, walk(200), torch.tensor([0.1, -0.2], dtype=F64), 5, aoti=True)
    pol.close()


@pytest.mark.slow
def test_the_exported_arm_halves_with_the_plan_check_equal_the_threaded_policy(tmp_path):
    """The two-class arm map of tests/control/test_policy_arm.py with the plan check and its
    clearance hysteresis, the can sliding across the arm's path: the decisions from the measured
    joints (the scores, the rollout of the velocity command, the capsules' gap) as the policy's."""
    from tests.control.test_policy_arm import policy as arm_policy
    from tests.control.test_policy_arm import walks

    pol = arm_policy.__wrapped__()
    pol = type(pol)(
        pol._P,
        pol.env_map,
        pol.task_name,
        task=pol.task,
        duration=pol.duration,
        switch_margin=pol.switch_margin,
        decision_dt=pol.decision_dt,
        switch_clearance=pol.switch_clearance,
        check=True,
        planner="thread",
        plan_period=1e6,
        limits=False,  # the exported loop applies no Ruckig (a C++ loop would: programs.json)
    )
    envs = walks(600)[0]  # (601, 4) the can from one side of the path to the other
    q0 = torch.as_tensor(pol.task.start_config(), dtype=F64)
    labels = check_programs(pol, tmp_path, envs, q0, 5)
    assert len(labels) == 2  # a switch on the way
    pol.close()
