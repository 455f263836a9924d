"""Latency of ``policy.reference`` in a 1 kHz control loop, and the continuity of the reference
(issue 35).

Latency: ``protorch.load(run, backend=b)`` for each map backend (torch, gpytorch, sparse), then
10,000 calls of ``policy.reference(env, t, q)`` on one thread at ``t = 0, 1, 2, ... ms`` (a new
motion, ``reset()``, every ``duration + 1`` s), ``q`` the last reference (the arm tracking it),
the environment changing at every call. Two motions of the environment:

* ``moving``: a person carries the can and the target (each a smooth random walk at up to 0.2 m/s,
  kept on the task's sampler region) seen by motion capture with 0.5 mm of noise per call;
* ``jumping``: a new random environment at every call (the worst case: the map's nearest
  neighbours change at every call, so each call solves their GP anew).

Printed: median, p99 and max (ms), the first call included (it is the first call after ``load``),
of the wall-clock time and of the calling thread's CPU time (``time.thread_time``: on a shared
machine the wall clock also counts the time the thread waited for a core), the share of calls
that solved a new neighbour set (and of those by a swap update of the last set's inverses), and
the load average. Load and warm-up time is printed apart. Also the collections of Python's garbage
collector that ran within the timed calls, per generation (a full one, generation 2, walks every
object torch's import left and takes ~0.1 s: ``Policy`` collects once after its warm-up).

Continuity (``--continuity N``): the run's moving test re-simulated (its own environments and moves,
:func:`protorch.control.arm.run_arm_episodes`); the policy's class at every instant of every
episode (given the episode's environment, joints and velocities of that instant) compared with the
test's;
then the first ``N`` episodes with a class switch replayed at 1 kHz through ``policy.reference``
(the environment and joints of the test's instant): the largest change of ``q_r`` and ``qd_r``
between consecutive calls, against the same with the offset off (``blend=inf``: the chosen mean).

    python benchmarks/control_loop.py RUN_DIR [--calls 10000] [--backends torch,gpytorch,sparse]
    [--check on,off]
        [--continuity 10] [--soak 200000]

``--pieces``: the walk once more with the decisions' pieces (every class's mean, the scores, the
plan check and its plan, capsule placement and bounds) each timed. ``--check on,off`` times the
class choice with and without its plan check (the run's
``dynamic.check``, on by default: :func:`protorch.control.arm_choice.rest_blocked`) side by side.

``--soak CALLS``: a long loop on the first backend's policy (moving environments, a new walk every
20,000 calls): the process's resident memory and the number of objects the garbage collector
tracks every 20,000 calls, which stay flat when every cache the policy keeps is bounded, and each
walk's p99.

``--planner thread,process,inline``: ``thread`` and ``process`` (the planner in a child process)
paced at 1 kHz, the plan's age printed; ``--competitors N`` runs N CPU-bound processes while the
calls are timed; ``--switch-interval S`` sets ``sys.setswitchinterval``; ``--limits
off|joint|together|both`` picks the limiter (``both``: off, then joint); ``--gc-freeze`` calls
``gc.freeze()`` after each load; ``--spinner`` runs a thread spinning in Python beside the
loop (an application's other thread: wherever a call lets the GIL go, the spinner may take it
for up to a switch interval); ``--realtime PRIO`` puts the calling thread (not the planner)
at ``SCHED_FIFO`` priority ``PRIO`` after each load (Linux, ``CAP_SYS_NICE``). Paced calls also
print how late they started after their tick was due (the sleep's overshoot, the wait for a core
and, with a planner thread, for the GIL). ``--exported export|aoti|aoti-tracker|cpp``: also both
halves written by ``policy.export(folder)`` and driven by ``examples/exported_loop.py`` in a
process without protorch (the tracker's wall and CPU time); ``cpp``: both compiled by AOTInductor
and also driven by the C++ loop of ``examples/cpp`` (built here with cmake and torch's libtorch),
the two timings side by side.

``--aoti``: also the program ``policy.export(path, aoti=True)`` writes (AOTInductor, compiled on
this machine; the compile time is printed), loaded with ``torch._inductor.aoti_load_package`` and
called on the same environments and times: every call chooses the class afresh (no hysteresis, no
neighbour set kept), so its cost hardly depends on the call. Its largest difference from
``reset(); reference(env, t)`` over 200 calls is printed first.
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import torch

import protorch


def _percentile(ts: list[float], q: float) -> float:
    s = sorted(ts)
    return s[min(len(s) - 1, int(math.ceil(q * len(s))) - 1)]


def environments(policy, calls: int, kind: str, seed: int = 0) -> torch.Tensor:
    """``(calls, d)`` environments, one per call (module docstring)."""
    g = torch.Generator().manual_seed(seed)
    task = policy.task
    if kind == "jumping":
        return task.sample_envs(calls, g)
    lo, hi = task.sample_envs(4096, g).aminmax(dim=0)  # the sampler's box
    env = task.sample_envs(1, g)[0]
    vel = torch.zeros_like(env)
    out = torch.empty(calls, env.numel(), dtype=torch.float64)
    dt = 1e-3
    for i in range(calls):
        vel = (
            vel + 0.5 * torch.randn(env.shape, generator=g, dtype=torch.float64) * dt**0.5 * 4
        ).clamp(-0.2, 0.2)
        env = env + vel * dt
        bounce = (env < lo) | (env > hi)
        vel = torch.where(bounce, -vel, vel)
        env = torch.minimum(torch.maximum(env, lo), hi)
        out[i] = env + 5e-4 * torch.randn(env.shape, generator=g, dtype=torch.float64)
    return out


class Collections:
    """The garbage collector's collections while :attr:`on`: ``(generation, seconds)`` each (once
    :meth:`start` has put it among the collector's callbacks; :func:`main` does)."""

    def __init__(self) -> None:
        self.on, self.seen, self._t0 = False, [], 0.0

    def start(self) -> None:
        if self not in gc.callbacks:
            gc.callbacks.append(self)

    def stop(self) -> None:
        if self in gc.callbacks:
            gc.callbacks.remove(self)

    def __call__(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
        elif self.on:
            self.seen.append((info["generation"], time.perf_counter() - self._t0))

    def summary(self) -> str:
        parts = []
        for g in range(3):
            ds = [d * 1e3 for gen, d in self.seen if gen == g]
            parts.append(
                f"generation {g}: {len(ds)}" + (f" (longest {max(ds):.2f} ms)" if ds else "")
            )
        return "; ".join(parts)


COLLECTIONS = Collections()


def print_times(kind: str, ts: list[float], cpu: list[float]) -> None:
    """Median, p99, max and first of the calls' wall-clock and CPU seconds, in ms."""
    for what, xs in (("wall", ts), ("cpu", cpu)):
        ms = [x * 1e3 for x in xs]
        print(
            f"  {kind:8s} {what:4s} {len(ms)} calls: median {_percentile(ms, 0.5):.3f} ms, "
            f"p99 {_percentile(ms, 0.99):.3f} ms, max {max(ms):.3f} ms, first {ms[0]:.3f} ms"
        )


def time_calls(
    policy, envs: torch.Tensor, kinds: list[str] | None = None
) -> tuple[list[float], list[float], int]:
    """Wall-clock and CPU seconds (this thread's: what a call costs when its core is free) of each
    call; ``kinds`` receives each call's kind (:func:`print_kinds`)."""
    period = int(round((policy.duration + 1.0) * 1000))
    ts, cpu, q = [], [], None
    misses0 = policy.means.misses
    for i in range(envs.shape[0]):
        if i % period == 0:
            policy.reset()
            q = None
        slot, misses = policy._m.slot, policy.means.misses
        COLLECTIONS.on = True
        c0, t0 = time.thread_time(), time.perf_counter()
        r = policy.reference(envs[i], (i % period) * 1e-3, q)
        ts.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)
        COLLECTIONS.on = False
        if kinds is not None:
            solved = "solve" if policy.means.misses > misses else ""
            kinds.append(
                ("decision" + (" + " + solved if solved else ""))
                if policy._m.slot != slot
                else solved or "light"
            )
        q = r.q
    return ts, cpu, policy.means.misses - misses0


def time_paced(
    policy, envs: torch.Tensor
) -> tuple[list[float], list[float], list[float], list[float]]:
    """:func:`time_calls` for ``planner="thread"``: the calls paced at 1 kHz (the loop sleeps to
    the next millisecond, as a control loop waits for its next tick; the planner thread runs in
    between), each motion's first plan made by ``reset(env)`` before its first tick. Wall-clock
    and CPU seconds of each call, the age of the plan it tracked (``t - plan_t``, seconds) and
    how late the call started (seconds after its tick was due: the sleep's overshoot, the wait
    for a core and, with a planner thread, for the GIL)."""
    period = int(round((policy.duration + 1.0) * 1000))
    ts, cpu, ages, late, q = [], [], [], [], None
    due = time.perf_counter()
    for i in range(envs.shape[0]):
        if i % period == 0:
            policy.reset(envs[i])
            q = None
            due = time.perf_counter()
        now = time.perf_counter()
        if now < due:
            time.sleep(due - now)
        was_due, due = due, max(due + 1e-3, time.perf_counter())
        t = (i % period) * 1e-3
        COLLECTIONS.on = True
        c0, t0 = time.thread_time(), time.perf_counter()
        r = policy.reference(envs[i], t, q)
        ts.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)
        COLLECTIONS.on = False
        late.append(max(t0 - was_due, 0.0))
        ages.append(t - r.plan_t)
        q = r.q
    return ts, cpu, ages, late


def print_ages(policy, ts: list[float], ages: list[float], late: list[float]) -> None:
    """The plan's age (median, p99, max, in decision intervals), the calls over 1 ms and how late
    the calls started (:func:`time_paced`; p99 and max, ms)."""
    a = [x / policy.decision_dt for x in ages]
    print(
        f"  plan age in decision intervals ({policy.decision_dt * 1e3:g} ms): median "
        f"{_percentile(a, 0.5):.2f}, "
        f"p99 {_percentile(a, 0.99):.2f}, max {max(a):.2f}; plans made {policy._planner.plans}; "
        f"calls over 1 ms: {sum(x > 1e-3 for x in ts)}; hand-overs by Ruckig: "
        f"{policy._limiter.following if policy._limiter is not None else 0}"
    )
    ms = [x * 1e3 for x in late]
    print(
        f"  calls started late (after the tick was due): p99 {_percentile(ms, 0.99):.3f} ms, max "
        f"{max(ms):.3f} ms, {sum(x > 1.0 for x in ms)} over 1 ms"
    )


def print_kinds(ts: list[float], kinds: list[str]) -> None:
    """Wall-clock median / p90 / max and the calls over 1 ms by kind of call: light (no new
    neighbour
    set, no decision), solve (a new neighbour set solved), decision (the class chosen), both; and
    the p99 of the calls that make no decision."""
    for k in ("light", "solve", "decision", "decision + solve"):
        xs = [t for t, c in zip(ts, kinds) if c == k]
        if xs:
            print(
                f"    {k:17s} {len(xs):6d} calls: median {_percentile(xs, 0.5) * 1e3:.3f}, p90 "
                f"{_percentile(xs, 0.9) * 1e3:.3f}, max {max(xs) * 1e3:.3f} ms; "
                f"{sum(x > 1e-3 for x in xs)} over 1 ms"
            )
    rest = [t for t, c in zip(ts, kinds) if not c.startswith("decision")]
    if rest:  # what the decisions leave: the tail of a loop whose class is chosen elsewhere
        print(
            f"    without the decisions ({len(rest)} calls): p99 "
            f"{_percentile(rest, 0.99) * 1e3:.3f} ms, "
            f"{sum(x > 1e-3 for x in rest)} over 1 ms"
        )


def time_pieces(policy, envs: torch.Tensor) -> None:
    """The pieces of the class decisions of :func:`time_calls`'s walk: each wrapped in a timer
    (the walk runs once more), their mean wall time per call and how many calls; the plan
    check's pieces only where the carried bounds (``ClearanceMemo``) did not pass the plan."""
    import protorch.control.arm_choice as ac
    import protorch.policy.choice as pc
    import protorch.policy.policy as pm
    from protorch.policy.means import ClassMeans

    spent: dict[str, list[float]] = {}

    def timed(owner, name: str, label: str):
        f = getattr(owner, name)

        def run(*a, **k):
            t0 = time.perf_counter()
            out = f(*a, **k)
            spent.setdefault(label, []).append(time.perf_counter() - t0)
            return out

        return f, run

    pieces = [
        (ClassMeans, "__call__", "every class's mean (new sets solved)"),
        (pm.Policy, "_scores", "the scores"),
        (pc, "checked_choice", "the plan check (all of it)"),
        (ac, "rest_plan", "  the plan (rollout, mean after)"),
        (ac, "capsule_ends", "  the capsules placed"),
        (ac, "capsules_clear", "  the capsules bounded"),
    ]
    saved = []
    for owner, name, label in pieces:
        f, run = timed(owner, name, label)
        saved.append((owner, name, f))
        setattr(owner, name, run)
    try:
        policy.reset()
        time_calls(policy, envs)
    finally:
        for owner, name, f in saved:
            setattr(owner, name, f)
    print("    the decisions' pieces (wall, mean per call):")
    for _, _, label in pieces:
        xs = spent.get(label, [])
        if xs:
            print(f"      {label:38s} {len(xs):5d} calls, {sum(xs) / len(xs) * 1e3:.3f} ms")


def time_aoti(policy, kinds: list[str], calls: int) -> None:
    """The AOTInductor-compiled program of ``policy`` (module docstring, ``--aoti``)."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        path = policy.export(Path(tmp) / "policy_aoti.pt2", aoti=True)
        compile_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        program = torch._inductor.aoti_load_package(str(path))
        load_s = time.perf_counter() - t0
    envs = environments(policy, 200, "jumping", seed=1)
    worst, differ = 0.0, 0
    for i in range(envs.shape[0]):
        t = 0.0075 * i
        out = program(envs[i], torch.tensor(t, dtype=torch.float64))
        policy.reset()
        r = policy.reference(envs[i], t)
        worst = max(
            worst, *(float((a - b).abs().max()) for a, b in zip(out[:3], (r.q, r.qd, r.qdd)))
        )
        differ += int(out[3]) != r.label
    print(
        f"aoti: export + compile {compile_s:.0f} s, load {load_s:.2f} s; against reset(); "
        "reference(): largest "
        f"difference {worst:.2g}, class differs at {differ} of {envs.shape[0]} calls"
    )
    period = int(round((policy.duration + 1.0) * 1000))
    for kind in kinds:
        envs = environments(policy, calls, kind)
        ts, cpu = [], []
        for i in range(envs.shape[0]):
            t = torch.tensor((i % period) * 1e-3, dtype=torch.float64)
            c0, t0 = time.thread_time(), time.perf_counter()
            program(envs[i], t)
            ts.append(time.perf_counter() - t0)
            cpu.append(time.thread_time() - c0)
        print_times(kind, ts, cpu)
        print(f"  {kind:8s} load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


BLOCKED_DRIVER = """
import runpy, sys
class Block:  # protorch must not be needed
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] == "protorch":
            raise ImportError("protorch is blocked in this process")
sys.meta_path.insert(0, Block())
sys.argv = sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


def build_cpp(build: Path) -> Path:
    """examples/cpp configured and built in ``build`` (cmake, torch's cmake files): the
    binary."""
    root = Path(__file__).resolve().parents[1]
    cmake = ["cmake", "-S", str(root / "examples" / "cpp"), "-B", str(build)]
    cmake += ["-DCMAKE_BUILD_TYPE=Release", f"-DCMAKE_PREFIX_PATH={torch.utils.cmake_prefix_path}"]
    for cmd in (cmake, ["cmake", "--build", str(build), "-j", "2"]):
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed: {proc.stderr[-2000:]}")
    return build / "exported_loop"


def time_exported(policy, calls: int, aoti: bool | str) -> None:
    """``--exported``: both halves written by ``policy.export(folder)`` and driven by
    ``examples/exported_loop.py`` in a process where protorch cannot be imported (the planner
    every decision interval, the tracker every tick, back to back), on the moving walk (at most
    2,000 ticks where the planner is not compiled: its ``torch.export`` module is slow): the
    tracker program's wall and CPU time per call. ``aoti="cpp"``: both compiled, and the same
    packages on the same inputs also driven by the C++ loop of ``examples/cpp`` (built here),
    the two timed side by side, their largest difference printed."""
    import tempfile

    cpp = aoti == "cpp"
    root = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        folder = policy.export(Path(tmp) / "programs", aoti=True if cpp else aoti)
        export_s = time.perf_counter() - t0
        compiled = cpp or aoti is True
        envs = environments(policy, calls if compiled else min(calls, 2000), "moving")
        q0 = torch.as_tensor(policy.task.start_config(), dtype=torch.float64)
        qd0 = torch.zeros_like(q0)
        torch.save({"env": envs, "q0": q0, "qd0": qd0}, f"{tmp}/inputs.pt")
        Path(tmp, "blocked.py").write_text(BLOCKED_DRIVER)
        cmd = [sys.executable, f"{tmp}/blocked.py", str(root / "examples" / "exported_loop.py")]
        cmd += [str(folder), "--inputs", f"{tmp}/inputs.pt", "--out", f"{tmp}/out.pt"]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(proc.stderr[-2000:])
        load_py = os.getloadavg()[0]
        out = torch.load(f"{tmp}/out.pt", weights_only=True)
        print(
            f"exported halves (AOTInductor: {aoti}; export "
            f"{export_s:.0f} s), driven without protorch: {proc.stdout.strip()}"
        )
        if not cpp:
            print_times("tracker", out["tracker_s"].tolist(), out["tracker_cpu_s"].tolist())
            print(f"  load average {load_py:.1f} on {os.cpu_count()} cores")
            return
        sys.path.insert(0, str(root / "examples" / "cpp"))
        from raw import read_outputs, write_inputs  # examples/cpp/raw.py

        t0 = time.perf_counter()
        binary = build_cpp(Path(tmp) / "build")
        build_s = time.perf_counter() - t0
        write_inputs(Path(tmp) / "raw_in", envs, q0, qd0)
        cmd = [str(binary), str(folder), f"{tmp}/raw_in", "--out", f"{tmp}/raw_out"]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(proc.stderr[-2000:])
        load_cpp = os.getloadavg()[0]
        got = read_outputs(Path(tmp) / "raw_out", q0.shape[0])
    print(f"examples/cpp (built in {build_s:.0f} s), the same packages: {proc.stdout.strip()}")
    worst = max(float((got[k] - out[k]).abs().max()) for k in ("q", "qd", "qdd"))
    same = torch.equal(got["label"], out["label"].to(torch.long)) and torch.equal(
        got["plan_t"], out["plan_t"]
    )
    print(
        f"  C++ against Python on {envs.shape[0]} ticks: q, qd, qdd differ by {worst:.2g} at "
        f"most; labels and plan times {'the same' if same else 'DIFFER'} at every tick"
    )
    for name, res, load in (("python", out, load_py), ("c++", got, load_cpp)):
        print_times(name, res["tracker_s"].tolist(), res["tracker_cpu_s"].tolist())
        over = int((res["tracker_s"] > 1e-4).sum())
        print(
            f"  {name:8s} tracker calls over 0.1 ms: {over} of {res['tracker_s'].numel()}; load "
            f"average {load:.1f} on {os.cpu_count()} cores"
        )


def reversed_switches(labels: torch.Tensor, within: int = 3) -> tuple[int, int]:
    """Class switches undone within ``within`` decisions (a flicker) in ``labels (E, S)`` (the class
    at every control step of every episode): their count and the episodes they are in."""
    count, episodes = 0, 0
    for row in labels.tolist():
        at = [s for s in range(1, len(row)) if row[s] != row[s - 1]]
        n = sum(b - a <= within for a, b in zip(at, at[1:]))
        count, episodes = count + n, episodes + (n > 0)
    return count, episodes


def soak(policy, calls: int, chunk: int = 20_000) -> None:
    """``calls`` calls of :func:`time_calls`, a new walk every ``chunk`` (each starts a new
    motion); prints the resident memory (``/proc/self/statm``, Linux), the garbage collector's
    tracked objects and the walk's p99 after each."""
    page = os.sysconf("SC_PAGE_SIZE") / 2**20
    rss = lambda: int(Path("/proc/self/statm").read_text().split()[1]) * page  # noqa: E731 (MB)
    print(
        f"soak: {calls} calls; before: {rss():.0f} MB resident, {len(gc.get_objects())} objects "
        "tracked"
    )
    done = 0
    while done < calls:
        envs = environments(policy, min(chunk, calls - done), "moving", seed=1 + done // chunk)
        policy.reset()
        ts = time_calls(policy, envs)[0]
        done += len(ts)
        print(
            f"  after {done} calls: {rss():.0f} MB resident, {len(gc.get_objects())} objects "
            "tracked, "
            f"p99 of the walk {_percentile(ts, 0.99) * 1e3:.3f} ms"
        )


def continuity(run: str, episodes: int) -> None:
    from omegaconf import OmegaConf

    from protorch.control.arm import run_arm_episodes
    from protorch.experiments.policy_run import rebuild_experiment

    policy = protorch.load(run)
    raw = protorch.load(run, blend=math.inf)  # no offset: the chosen mean itself
    cfg = OmegaConf.to_container(OmegaConf.load(f"{run}/config.yaml"), resolve=True)
    exp = rebuild_experiment(cfg)
    env0 = exp.sample(exp.episodes, exp.dyn_seed)
    res = run_arm_episodes(
        policy,
        policy.task,
        env0,
        generator=torch.Generator().manual_seed(exp.dyn_seed),
        **exp.dyn_cfg,
    )
    # the class at every instant of every episode, the episode's measured joints and velocities
    # given
    mismatched = 0
    for e in range(res.q.shape[0]):
        policy.reset()
        for s in range(res.q.shape[1]):
            mismatched += policy.reference(
                res.envs[e, s], s * res.dt, res.q[e, s], res.qd[e, s]
            ).label != int(res.labels[e, s])
    back, where = reversed_switches(res.labels)
    print(
        f"moving test of {run}: {res.q.shape[0]} episodes, {int(res.switches.sum())} class "
        "switches in "
        f"{int((res.switches > 0).sum())} episodes ({back} undone within 3 decisions, in {where} "
        "episodes), "
        f"{int(res.moves.sum())} moves; the policy's class differs from the test's at {mismatched} "
        "of "
        f"{res.labels.numel()} instants"
    )
    # at 1 kHz through the episodes with a switch (the environment and joints of the test's instant)
    chosen = torch.nonzero(res.switches > 0).flatten()[:episodes].tolist()
    per = int(round(res.dt * 1000))
    steps = res.q.shape[1]
    worst = {"blend": [0.0, 0.0], "mean": [0.0, 0.0]}
    for e in chosen:
        for name, pol in (("blend", policy), ("mean", raw)):
            pol.reset()
            prev = None
            for i in range((steps - 1) * per + 1):
                s = i // per
                r = pol.reference(res.envs[e, s], i * 1e-3, res.q[e, s], res.qd[e, s])
                if prev is not None:
                    worst[name][0] = max(worst[name][0], float((r.q - prev.q).abs().max()))
                    worst[name][1] = max(worst[name][1], float((r.qd - prev.qd).abs().max()))
                prev = r
    print(f"  at 1 kHz over the {len(chosen)} first episodes with a switch:")
    for name, (dq, dqd) in worst.items():
        label = "reference (offset, blend 10/s)" if name == "blend" else "chosen mean (no offset)"
        print(f"  {label:32s} largest change per 1 ms call: q_r {dq:.3g} rad, qd_r {dqd:.3g} rad/s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--calls", type=int, default=10_000)
    ap.add_argument("--backends", default="torch,gpytorch,sparse")
    ap.add_argument("--kinds", default="moving,jumping")
    ap.add_argument(
        "--planner",
        default="thread,inline",
        help="thread (paced at 1 kHz, the planner beside the loop), process (paced, the planner in "
        "a child process), inline (back to back), comma separated",
    )
    ap.add_argument(
        "--switch-interval",
        type=float,
        default=None,
        metavar="S",
        help="sys.setswitchinterval(S) first (Python's default 0.005 s)",
    )
    ap.add_argument(
        "--check",
        default="run",
        help="the class choice's plan check: run (the run's dynamic.check), or on,off (both, side "
        "by side)",
    )
    ap.add_argument(
        "--aoti",
        action="store_true",
        help="also the AOTInductor-compiled exported program (the first backend's map)",
    )
    ap.add_argument(
        "--exported",
        default="",
        help="also both halves exported (export(folder)) and driven without protorch: export "
        "(torch.export), aoti (AOTInductor packages, compiled here), aoti-tracker (the tracker "
        "only compiled) or cpp (aoti, also driven by examples/cpp's C++ loop, built here)",
    )
    ap.add_argument(
        "--limits",
        default="run",
        choices=sorted(LIMITS),
        help="the limiter of thread and process: run (the load's default), off, joint, together, "
        "or both (off and joint, one after the other)",
    )
    ap.add_argument(
        "--gc-freeze",
        action="store_true",
        help="gc.freeze() after each load (the objects alive then never walked by a collection)",
    )
    ap.add_argument(
        "--realtime",
        type=int,
        default=0,
        metavar="PRIO",
        help="the calling thread at SCHED_FIFO priority PRIO after each load (Linux, needs "
        "CAP_SYS_NICE; the planner keeps the normal policy)",
    )
    ap.add_argument(
        "--competitors",
        type=int,
        default=0,
        help="CPU-bound processes (a Python busy loop each) running while the calls are timed",
    )
    ap.add_argument(
        "--spinner",
        action="store_true",
        help="a thread of the application spinning in Python beside the loop while the calls are "
        "timed (a GUI's or a middleware's thread: it holds the GIL whenever the loop lets it go)",
    )
    ap.add_argument(
        "--pieces",
        action="store_true",
        help="also the decisions' pieces timed (the walk once more, each piece wrapped in a timer)",
    )
    ap.add_argument(
        "--soak",
        type=int,
        default=0,
        metavar="CALLS",
        help="also a long loop of this many calls: resident memory and tracked objects every "
        "20,000",
    )
    ap.add_argument(
        "--continuity",
        type=int,
        default=0,
        metavar="EPISODES",
        help="also the continuity over this many switching episodes of the moving test",
    )
    args = ap.parse_args()
    torch.set_num_threads(1)
    if args.switch_interval is not None:
        sys.setswitchinterval(args.switch_interval)
    COLLECTIONS.start()
    busy = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"])
        for _ in range(args.competitors)
    ]
    spinning = threading.Event()
    if args.spinner:
        spinning.set()
        threading.Thread(target=spin, args=(spinning,), daemon=True).start()
    try:
        run_all(args)
    finally:
        spinning.clear()
        for p in busy:
            p.kill()
            p.wait()


def spin(on: threading.Event) -> None:
    """``--spinner``: Python bytecode while ``on`` is set (the loop's thread takes the GIL back
    from it only at a switch interval, or where it waits itself)."""
    n = 0
    while on.is_set():
        for _ in range(1000):
            n += 1


LIMITS = {"run": "", "off": "off", "joint": "joint", "together": "together", "both": "off,joint"}


def run_all(args) -> None:
    """:func:`main`'s measurements."""
    print(
        f"torch {torch.__version__}, 1 thread, run {args.run}, switch interval "
        f"{sys.getswitchinterval() * 1e3:g} ms, {args.competitors} CPU-bound competitors"
        + (", a thread spinning in Python beside the loop" if args.spinner else "")
    )
    checks = (
        [None]
        if args.check == "run"
        else [{"on": True, "off": False}[c] for c in args.check.split(",")]
    )
    runs = [
        (b, c, p, lim)
        for b in args.backends.split(",")
        for c in checks
        for p in args.planner.split(",")
        for lim in (
            [None] if args.limits == "run" or p == "inline" else LIMITS[args.limits].split(",")
        )
    ]
    for backend, check, planner, limits in runs:
        if args.realtime:  # back to the normal policy, which the planner's thread or child inherit
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        t0 = time.perf_counter()
        policy = protorch.load(
            args.run,
            backend=backend,
            planner=planner,
            **({} if check is None else {"check": check}),
            **({} if limits is None else {"limits": False if limits == "off" else limits}),
        )
        if args.gc_freeze:
            gc.freeze()
        if args.realtime:  # this thread only: the planner thread and child were started at load
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.realtime))
        load_s = time.perf_counter() - t0
        if args.realtime:
            print(f"  the calling thread at SCHED_FIFO priority {args.realtime}")
        print(
            f"backend {backend}, plan check {'on' if policy.check else 'off'}, planner {planner}, "
            f"limits {'off' if policy._limiter is None else type(policy._limiter).__name__}: "
            "map of "
            f"{policy.env_map.num_points} environments, classes {policy.labels.tolist()}, load + "
            f"warm-up {load_s:.2f} s"
            + (f", gc.freeze(): {gc.get_freeze_count()} objects frozen" if args.gc_freeze else "")
        )
        if planner in ("thread", "process"):
            for kind in args.kinds.split(","):
                envs = environments(policy, args.calls, kind)
                COLLECTIONS.seen.clear()
                ts, cpu, ages, late = time_paced(policy, envs)
                print_times(kind, ts, cpu)
                print(
                    f"  {kind:8s} garbage collections within the calls: {COLLECTIONS.summary()}; "
                    "load average "
                    f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
                )
                print_ages(policy, ts, ages, late)
                c0, t0 = time.thread_time(), time.perf_counter()
                gc.collect()  # what one that fell into the loop would hold the GIL for
                print(
                    f"  a full garbage collection after the calls: wall "
                    f"{(time.perf_counter() - t0) * 1e3:.1f} ms, CPU "
                    f"{(time.thread_time() - c0) * 1e3:.1f} ms, {len(gc.get_objects())} objects "
                    "tracked"
                )
            policy.close()
            continue
        for kind in args.kinds.split(","):
            envs = environments(policy, args.calls, kind)
            policy.reset()
            swaps0 = getattr(policy.means, "updates", 0)
            memo = getattr(policy, "_memo", None)
            passed0, checked0 = (memo.passed, memo.checked) if memo is not None else (0, 0)
            kinds: list[str] = []
            COLLECTIONS.seen.clear()
            ts, cpu, misses = time_calls(policy, envs, kinds)
            print_times(kind, ts, cpu)
            print(f"  {kind:8s} garbage collections within the calls: {COLLECTIONS.summary()}")
            swaps = getattr(policy.means, "updates", 0) - swaps0
            print(
                f"  {kind:8s} new neighbour sets solved at {misses / len(ts):.1%} of the calls ("
                f"{swaps / len(ts):.1%} "
                f"by a swap update); load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} "
                "cores"
            )
            if memo is not None:
                passed, checked = memo.passed - passed0, memo.checked - checked0
                print(
                    f"  {kind:8s} plans passed by the bounds carried from earlier checks: {passed} "
                    f"of {passed + checked}"
                )
            print_kinds(ts, kinds)
            if args.pieces:
                time_pieces(policy, envs)
    if args.aoti:
        time_aoti(
            protorch.load(args.run, backend=args.backends.split(",")[0]),
            args.kinds.split(","),
            args.calls,
        )
    if args.exported:
        time_exported(
            protorch.load(args.run, backend=args.backends.split(",")[0], planner="thread"),
            args.calls,
            aoti={"export": False, "aoti": True, "aoti-tracker": "tracker", "cpp": "cpp"}[
                args.exported
            ],
        )
    if args.soak:
        soak(protorch.load(args.run, backend=args.backends.split(",")[0]), args.soak)
    if args.continuity:
        continuity(args.run, args.continuity)


if __name__ == "__main__":
    main()
