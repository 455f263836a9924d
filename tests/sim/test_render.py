"""Offscreen pictures of physics episodes (protorch.sim.render), made in a subprocess with EGL or
OSMesa; where neither works the test is skipped with the line the run would print."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from protorch.control.episodes import check_timing
from protorch.experiments.arm_physics import save_episodes
from protorch.robots import load_robot

PANDA_MAX_ACCELERATION = load_robot("panda").max_acceleration
from protorch.control.physics import FixedMeans, run_physics_episodes
from protorch.sim.render import render_in_subprocess
from protorch.sim.scene import build_scene, controller_model


def test_a_reach_is_rendered_as_a_gif_and_frames(task, reach, tmp_path):
    promp, w = reach
    timing = check_timing(0.02, 0.6, 0.1)
    envs = torch.tensor([[0.55, 0.30, 0.70, -0.10]], dtype=torch.float64)[:, None].expand(
        -1, timing.total + 1, -1
    )
    res = run_physics_episodes(
        build_scene(task),
        controller_model(task),
        FixedMeans(w),
        promp,
        timing,
        envs,
        kp=400.0,
        kd=40.0,
        ref_kp=10.0,
        max_acceleration=PANDA_MAX_ACCELERATION,
    )
    path = save_episodes(tmp_path / "episodes.npz", res, None, res.success, None, task)
    kwargs = {"collision": "volume"}
    line = render_in_subprocess(path, tmp_path, kwargs, {"reach": 0})
    if line.startswith("no physics renders"):
        pytest.skip(line)
    assert "physics_reach.gif" in line
    gif = Image.open(tmp_path / "physics_reach.gif")
    assert gif.n_frames == res.q.shape[1]  # every control instant (fewer than 50)
    frame = np.asarray(gif.convert("RGB"))
    assert frame.shape == (360, 480, 3) and frame.std() > 10  # a scene, not a blank image
    red = (
        (frame[..., 0] > 80)
        & (frame[..., 0] > 2 * frame[..., 1].astype(int))
        & (frame[..., 0] > 2 * frame[..., 2].astype(int))
    )
    assert red.sum() > 50  # the can is in the picture
    strip = np.asarray(Image.open(tmp_path / "physics_reach_frames.png").convert("RGB"))
    assert strip.shape[1] > 3 * strip.shape[0]
