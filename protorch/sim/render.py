"""Offscreen pictures of physics episodes: ``mujoco.Renderer`` frames of the scene
(:mod:`protorch.sim.scene`) replayed from ``episodes.npz``, written as a GIF and a strip of frames:
the arm's capsules, or its URDF's visual meshes where it has them.

OpenGL's backend is chosen when ``mujoco`` is first imported (``MUJOCO_GL``), so the pictures are
made in a subprocess (``python -m protorch.sim.render``), first with ``MUJOCO_GL=egl`` and, where
that fails, with ``osmesa``: :func:`render_in_subprocess` returns one line saying what was
written, or why nothing was (neither backend works: install ``libegl1`` or ``libosmesa6``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from ..data.files import atomic_write_bytes
from ..tasks.arm.reach import ArmReachTask
from .mj import load_mujoco
from .scene import CAPSULE_GROUP, VISUAL_GROUP, build_scene

__all__ = [
    "render_frames",
    "write_gif",
    "write_strip",
    "render_episode",
    "render_in_subprocess",
    "main",
]

BACKENDS = ("egl", "osmesa")


def render_frames(
    scene,
    q: np.ndarray,
    can: np.ndarray,
    target: np.ndarray,
    *,
    camera: str = "front",
    width: int = 480,
    height: int = 360,
) -> list[np.ndarray]:
    """RGB frames ``(height, width, 3)`` uint8 of the arm at joints ``q (n, J)`` with the can and
    the target at ``can, target (n, 2)``."""
    mujoco = load_mujoco()
    model = scene.model
    data = mujoco.MjData(model)
    renderer = mujoco.Renderer(model, height=height, width=width)
    option = mujoco.MjvOption()
    if getattr(scene, "visuals", False):  # the robot's visual meshes instead of its capsules
        option.geomgroup[VISUAL_GROUP], option.geomgroup[CAPSULE_GROUP] = 1, 0
    try:
        renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        frames = []
        for qi, ci, ti in zip(q, can, target):
            data.qpos[scene.qpos_index] = qi
            data.mocap_pos[scene.can_mocap] = (ci[0], ci[1], scene.task.can_height / 2)
            data.mocap_pos[scene.target_mocap] = (ti[0], ti[1], scene.task.ee_height)
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera=camera, scene_option=option)
            renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
            frames.append(renderer.render().copy())
    finally:
        renderer.close()
    return frames


def write_gif(path: Path, frames: list[np.ndarray], fps: float = 12.5) -> Path:
    """An endlessly looping GIF of ``frames``, written atomically."""
    import io

    from PIL import Image

    images = [Image.fromarray(f) for f in frames]
    buf = io.BytesIO()
    images[0].save(
        buf, format="GIF", save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0
    )
    return atomic_write_bytes(path, buf.getvalue())


def write_strip(path: Path, frames: list[np.ndarray], titles: list[str], heading: str) -> Path:
    """``frames`` side by side with a title each, as a PNG (matplotlib, atomic)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2.6 * len(frames), 2.4))
    axes = fig.subplots(1, len(frames), squeeze=False)[0]
    for ax, img, title in zip(axes, frames, titles):
        ax.imshow(img)
        ax.set_title(title, fontsize=8)
        ax.axis("off")
    fig.suptitle(heading, fontsize=9)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return atomic_write_bytes(path, buf.getvalue())


def _frame_titles(ep: dict, idx: list[int], labels) -> list[str]:
    names = {0: "left", 1: "right"}
    out = []
    for t in idx:
        s = f"t = {t * ep['dt']:.2f} s"
        if labels is not None and int(labels[t]) >= 0:
            s += f", {names.get(int(labels[t]), labels[t])}"
        if ep["contact"][t]:
            s += ", CONTACT"
        out.append(s)
    return out


def render_episode(
    scene,
    episodes: dict,
    i: int,
    out_dir: Path,
    name: str,
    *,
    num_frames: int = 5,
    max_gif_frames: int = 50,
) -> list[Path]:
    """Episode ``i`` of an ``episodes.npz`` (as a dict) as ``<name>.gif`` and
    ``<name>_frames.png``."""
    ep = {k: episodes[k][i] for k in ("q", "can", "target", "contact")} | {
        "dt": float(episodes["dt"])
    }
    labels = episodes["labels"][i] if "labels" in episodes else None
    n = ep["q"].shape[0]
    gif_idx = np.unique(np.linspace(0, n - 1, min(n, max_gif_frames)).round().astype(int))
    frames = render_frames(scene, ep["q"][gif_idx], ep["can"][gif_idx], ep["target"][gif_idx])
    out = [write_gif(out_dir / f"{name}.gif", frames)]
    moved = np.flatnonzero(
        np.any(np.diff(ep["can"], axis=0) != 0, -1) | np.any(np.diff(ep["target"], axis=0) != 0, -1)
    )
    key = sorted({0, n - 1, *(int(m) + 1 for m in moved[:2])})
    idx = sorted(set(key) | set(np.linspace(0, n - 1, num_frames).round().astype(int).tolist()))[
        : max(num_frames, 3) + 2
    ]
    strip = render_frames(scene, ep["q"][idx], ep["can"][idx], ep["target"][idx])
    verdict = "success" if bool(episodes["success"][i]) else "failure"
    out.append(
        write_strip(
            out_dir / f"{name}_frames.png",
            strip,
            _frame_titles(ep, idx, labels),
            f"{name}: episode {i}, MuJoCo, {verdict}",
        )
    )
    return out


def render_in_subprocess(
    episodes_path: Path,
    out_dir: Path,
    task_kwargs: dict,
    picks: dict,
    *,
    timestep: float = 0.002,
    timeout: float = 600.0,
) -> str:
    """Render ``picks`` (``{"reach": i, "switch": j}``: names of the pictures and episode indices)
    of ``episodes_path`` into ``out_dir`` in a subprocess, with EGL, else OSMesa. Returns one line:
    what was written, or why nothing was."""
    if not picks:
        return "nothing to render: no successful held-out reach and no switching episode"
    args = [
        sys.executable,
        "-m",
        "protorch.sim.render",
        "--episodes",
        str(episodes_path),
        "--out",
        str(out_dir),
        "--task",
        json.dumps(task_kwargs),
        "--picks",
        json.dumps(picks),
        "--timestep",
        str(timestep),
    ]
    errors = []
    for backend in BACKENDS:
        env = {**os.environ, "MUJOCO_GL": backend, "PYOPENGL_PLATFORM": backend}
        proc = subprocess.run(args, env=env, capture_output=True, text=True, timeout=timeout)
        if proc.returncode == 0:
            return proc.stdout.strip().splitlines()[-1]
        errors.append(f"{backend}: {(proc.stderr.strip().splitlines() or ['failed'])[-1]}")
    line = "no physics renders: neither EGL nor OSMesa works here (" + "; ".join(errors) + ")"
    print(f"[protorch] {line}", flush=True)
    return line


def main(argv: list[str] | None = None) -> None:
    """``python -m protorch.sim.render --episodes E --out DIR --task JSON --picks JSON``."""
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--episodes", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--task", default="{}")
    p.add_argument("--picks", required=True)
    p.add_argument("--timestep", type=float, default=0.002)
    a = p.parse_args(argv)
    task = ArmReachTask(**json.loads(a.task))
    scene = build_scene(task, timestep=a.timestep)
    with np.load(a.episodes) as f:
        episodes = {k: f[k] for k in f.files}
    written = []
    for name, i in json.loads(a.picks).items():
        written += render_episode(scene, episodes, int(i), Path(a.out), f"physics_{name}")
    print(
        f"rendered with MUJOCO_GL={os.environ.get('MUJOCO_GL', '')}: "
        + ", ".join(p.name for p in written)
    )


if __name__ == "__main__":
    main()
