"""A 1 kHz control loop with a trained arm run (docs/control_loop.md).

    python examples/control_loop.py RUN_DIR [--plot docs/img/control_loop.png] [--planner
    thread|inline] [--limits auto|off|joint|together]

The same loop runs an iiwa14 run (``robot=iiwa14``): the start and the slide are laid out in the
run's own workspace (:func:`start_and_slide`).

The policy is loaded with ``planner="thread"``: its class decisions run on a thread beside the
loop, which is paced at real time (each step waits for its millisecond) so that the planner sees
the loop as a robot's would; ``--planner inline`` runs every decision inside the call (the
moving test's choice exactly) and the loop as fast as it goes. With the thread the reference
keeps the robot's velocity, acceleration and jerk limits (the policy's default, ``--limits
auto``; ``--limits off``: not). Printed: the ticks whose ``policy.reference`` took over 1 ms,
and the plan's age. The plant is the MuJoCo Panda scene of the
physics test (:func:`protorch.sim.scene.build_scene`),
stepped by MuJoCo at 1 ms; at every step the reference comes from ``policy.reference`` for the
environment seen now and the measured joints, and the torque from the project's computed-torque
controller (:class:`protorch.sim.controller.ComputedTorque`, its own model of the arm), clipped to
the Panda's torque limits. A scripted "person" slides the can to another place while the arm moves.
Needs the physics extra (``pip install "protorch[physics]"``).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

import protorch
from protorch.sim.controller import ComputedTorque
from protorch.sim.mj import load_mujoco
from protorch.sim.scene import build_scene, controller_model


def person(env0: np.ndarray, can_to: np.ndarray, start: float, seconds: float):
    """The environment at time ``t``: the can slides in a straight line from where it stands
    (``env0[:2]``) to ``can_to`` between ``start`` and ``start + seconds``; the target stays."""

    def env_at(t: float) -> np.ndarray:
        s = min(max((t - start) / seconds, 0.0), 1.0)
        env = env0.copy()
        env[:2] = (1 - s) * env0[:2] + s * can_to
        return env

    return env_at


def start_and_slide(task, env: str | None, can_to: str | None) -> tuple[np.ndarray, np.ndarray]:
    """The start environment ``(4,)`` and where the can slides to ``(2,)``: given as ``"a,b,c,d"``
    and ``"x,y"``, or laid out in the run's own workspace (the middle of its can and target
    rectangles along x; the can starts at y = 0.03, left of the straight path, and slides to
    y = -0.09 across it; the target at y = -0.05), so that the slide crosses the path of the
    Panda's run and of an iiwa14 run alike."""
    (cx0, cx1), _ = task.can_box
    (gx0, gx1), _ = task.goal_box
    cx, gx = 0.5 * (cx0 + cx1), 0.5 * (gx0 + gx1)
    env0 = (
        np.array([cx, 0.03, gx, -0.05])
        if env is None
        else np.array([float(v) for v in env.split(",")])
    )
    to = (
        np.array([env0[0], -0.09])
        if can_to is None
        else np.array([float(v) for v in can_to.split(",")])
    )
    if env0.shape != (4,) or to.shape != (2,):
        raise SystemExit(f"--env needs 4 numbers and --can-to 2, got {env!r}, {can_to!r}")
    return env0, to


def control_loop(
    policy,
    env_at,
    *,
    seconds: float,
    timestep: float = 0.001,
    kp: float = 400.0,
    kd: float = 40.0,
    realtime: bool = False,
) -> dict:
    """Run the loop for ``seconds`` (module docstring); ``env_at(t) -> (4,)`` is the environment the
    motion capture reports at ``t``. Returns numpy arrays per step: ``t``, the measured ``q``,
    ``qd``,
    the reference ``q_r``, ``qd_r``, ``qdd_r``, the class ``label``, the applied ``tau``, ``env``,
    the
    seconds ``policy.reference`` took, the plan's age ``plan_age`` (``t - plan_t``, s); the torque
    ``limits (J,)``, and ``can_contacts``, ``table_contacts``: the steps with an arm-can, an
    arm-table
    contact. ``realtime``: each step waits until its ``timestep`` of wall-clock time has come."""
    mujoco = load_mujoco()
    task = policy.task
    scene = build_scene(task, timestep=timestep)  # the plant
    model, data = scene.model, mujoco.MjData(scene.model)
    ctrl = ComputedTorque(
        controller_model(task, timestep=timestep), 1, kp=kp, kd=kd
    )  # the controller's own model
    limits = scene.torque_limits  # (J,)
    data.qpos[:] = task.start_config().numpy()
    mujoco.mj_forward(model, data)
    steps = int(round(seconds / timestep))
    j = task.num_dof
    log = {k: np.zeros((steps, j)) for k in ("q", "qd", "q_r", "qd_r", "qdd_r", "tau")}
    log.update(
        t=np.zeros(steps),
        label=np.zeros(steps, dtype=np.int64),
        env=np.zeros((steps, 4)),
        seconds=np.zeros(steps),
        plan_age=np.zeros(steps),
        can_contacts=0,
        table_contacts=0,
        limits=limits,
    )
    policy.reset(
        torch.from_numpy(env_at(0.0)),
        torch.from_numpy(data.qpos.copy()),
        torch.from_numpy(data.qvel.copy()),
    )
    start = time.perf_counter()
    for i in range(steps):
        t = i * timestep
        if realtime:  # wait for this step's millisecond
            wait = start + t - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
        env = env_at(t)
        data.mocap_pos[scene.can_mocap] = [env[0], env[1], task.can_height / 2]
        data.mocap_pos[scene.target_mocap] = [env[2], env[3], task.ee_height]
        q, qd = data.qpos.copy(), data.qvel.copy()  # (J,) measured
        t0 = time.perf_counter()
        ref = policy.reference(torch.from_numpy(env), t, torch.from_numpy(q), torch.from_numpy(qd))
        log["seconds"][i] = time.perf_counter() - t0
        tau = ctrl.torques(q[None], qd[None], ref.q[None], ref.qd[None], ref.qdd[None])[
            0
        ].numpy()  # (J,)
        data.ctrl[:] = np.clip(tau, -limits, limits)
        mujoco.mj_step(model, data)
        log["can_contacts"] += int(data.sensordata[scene.can_contact] > 0)
        log["table_contacts"] += int(data.sensordata[scene.table_contact] > 0)
        for k, v in (
            ("q", q),
            ("qd", qd),
            ("q_r", ref.q.numpy()),
            ("qd_r", ref.qd.numpy()),
            ("qdd_r", ref.qdd.numpy()),
            ("tau", data.ctrl),
        ):
            log[k][i] = v
        log["t"][i], log["label"][i], log["env"][i], log["plan_age"][i] = (
            t,
            ref.label,
            env,
            t - ref.plan_t,
        )
    return log


def plot(log: dict, path: str, title: str = "") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    j = log["q"].shape[1]
    fig, axes = plt.subplots(j + 2, 1, figsize=(8, 1.3 * (j + 2) + 0.6), sharex=True)
    t = log["t"]
    for k in range(j):
        ax = axes[k]
        ax.plot(t, log["q_r"][:, k], color="C0", lw=1.6, label="reference q_r")
        ax.plot(t, log["q"][:, k], color="C3", lw=0.9, ls="--", label="executed q (MuJoCo)")
        ax.set_ylabel(f"q{k + 1} (rad)", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=7, loc="upper right", ncol=2)
    ax = axes[-2]
    ax.plot(t, log["plan_age"] * 1e3, color="C4", lw=0.9, label="plan age t - plan_t (ms)")
    ax.set_ylabel("ms", fontsize=8)
    ax.legend(fontsize=7, loc="upper right")
    ax.tick_params(labelsize=7)
    ax = axes[-1]
    ax.plot(t, log["env"][:, 1], color="C2", lw=1.2, label="can y (m)")
    ax.step(
        t,
        0.05 * log["label"],
        color="k",
        lw=1.0,
        where="post",
        label="class x 0.05 (0 left, 1 right)",
    )
    ax.set_xlabel("time (s)")
    ax.legend(fontsize=7, loc="upper right")
    ax.tick_params(labelsize=7)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(
        description="a 1 kHz loop: MuJoCo arm, policy.reference, computed torque"
    )
    ap.add_argument("run")
    ap.add_argument(
        "--env",
        default=None,
        help="can_x,can_y,goal_x,goal_y at the start (default: the middle of the run's can and "
        "target rectangles along x, the can at y=0.03 and the target at y=-0.05: on the Panda's "
        "run 0.56,0.03,0.70,-0.05)",
    )
    ap.add_argument(
        "--can-to", default=None, help="where the person slides the can (default: can_x,-0.09)"
    )
    ap.add_argument(
        "--move-at", type=float, default=0.8, help="s: when the person starts moving the can"
    )
    ap.add_argument("--move-for", type=float, default=0.4, help="s: how long the slide takes")
    ap.add_argument("--plot", default=None)
    ap.add_argument("--planner", default="thread", choices=["thread", "inline"])
    ap.add_argument(
        "--limits",
        default="auto",
        choices=["auto", "off", "joint", "together"],
        help="the reference held to the robot's velocity, acceleration and jerk limits (thread): "
        "auto (the policy's default: joint by joint with planner thread, none inline), off, joint "
        "(each joint handed over on its own), together (all joints synchronised)",
    )
    args = ap.parse_args()
    torch.set_num_threads(1)
    limits = False if args.limits == "off" else args.limits
    policy = protorch.load(args.run, planner=args.planner, limits=limits)
    env0, can_to = start_and_slide(policy.task, args.env, args.can_to)
    log = control_loop(
        policy,
        person(env0, can_to, args.move_at, args.move_for),
        seconds=policy.duration + 1.0,
        realtime=args.planner == "thread",
    )
    err = np.abs(log["q_r"] - log["q"])
    goal = policy.task.kinematics.ee_position(torch.from_numpy(log["q"][-1])).numpy()
    ms = np.sort(log["seconds"]) * 1e3
    print(
        f"{len(log['t'])} steps of 1 ms; classes {sorted(set(log['label'].tolist()))}, switches "
        f"{int((np.diff(log['label']) != 0).sum())}; tracking |q_r - q| max {err.max():.2e} rad; "
        f"steps with an arm-can contact {log['can_contacts']}, arm-table {log['table_contacts']}; "
        f"end effector {np.linalg.norm(goal[:2] - env0[2:]) * 1e3:.1f} mm from "
        f"the target; |tau| / limit max {np.max(np.abs(log['tau']) / log['limits']):.2f}; "
        f"policy.reference median {ms[len(ms) // 2]:.3f} ms, max {ms[-1]:.3f} ms, over 1 ms at "
        f"{int((ms > 1.0).sum())} ticks; plan age median {np.median(log['plan_age']) * 1e3:.1f} "
        "ms, "
        f"max {log['plan_age'].max() * 1e3:.1f} ms"
    )
    policy.close()
    if args.plot:
        plot(log, args.plot, f"{args.run}: the can slides at {args.move_at:g} s")


if __name__ == "__main__":
    main()
