"""protorch.load: a run folder read without Hydra or OmegaConf (a fresh process that cannot import
either loads a real run and makes a call), the config read as OmegaConf wrote it; one policy, one
answer: mean_trajectory takes one environment, and its class is the one reference starts with."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from protorch.policy.load import read_config
from tests.control.test_policy import toy_policy

F64 = torch.float64
ROOT = Path(__file__).resolve().parents[2]

NO_HYDRA = textwrap.dedent("""
    import sys, time
    class Block:  # neither may be imported
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in ("hydra", "omegaconf"):
                raise ImportError(name + " is blocked in this process")
    sys.meta_path.insert(0, Block())
    t0 = time.perf_counter()
    import protorch
    policy = protorch.load(sys.argv[1], planner=sys.argv[2])
    env = policy.task.sample_envs(1)[0]
    policy.reset(env)
    r = policy.reference(env, 0.1)
    assert r.q.shape == (policy.promp.num_dof,) and r.plan_t in (0.0, 0.1)
    policy.close()
    assert not any(m.split(".")[0] in ("hydra", "omegaconf") for m in sys.modules)
    print("ok", round(time.perf_counter() - t0, 2))
""")


@pytest.mark.slow  # a small point_particle run, then a fresh process (torch's import)
def test_load_imports_neither_hydra_nor_omegaconf(tmp_path):
    from protorch.experiments import run_experiment

    cfg = {
        "name": "point_particle",
        "seed": 0,
        "plot": False,
        "optimizer": {
            "name": "pro",
            "beta": 20.0,
            "max_iter": 3,
            "num_samples": 10,
            "relevance_samples": 10,
        },
        "gp": {"backend": "torch", "alpha": 1e-3, "var_floor": 1e-4},
        "task": {"_target_": "protorch.tasks.PointParticleTask", "demo_envs": 4},
        "settings": {
            "loop": {"num_envs": 6, "batch_size": 6},
            "test": {"num_envs": 3},
            "dynamic": {"episodes": 1},
            "dynamic_paper": {"episodes": 1},
            "baselines": [],
            "progress": False,
        },
    }
    run_experiment(cfg, tmp_path)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", NO_HYDRA, str(tmp_path), "thread"],
        capture_output=True,
        text=True,
        check=False,
        env=env,
        cwd=ROOT,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("ok")


def test_the_config_is_read_as_omegaconf_wrote_it(tmp_path):
    """Floats without a dot (``1e-3``) are floats, as OmegaConf reads them, not strings."""
    p = tmp_path / "config.yaml"
    p.write_text(
        "name: arm_reach\ngp:\n  var_floor: 1e-3\n  alpha: 30.0\n  nearest_k: 30\nflag: "
        "true\nnone: null\n"
    )
    assert read_config(p) == {
        "name": "arm_reach",
        "gp": {"var_floor": 1e-3, "alpha": 30.0, "nearest_k": 30},
        "flag": True,
        "none": None,
    }
    p.write_text("- a list\n")
    with pytest.raises(ValueError, match="not a mapping"):
        read_config(p)


@pytest.mark.parametrize("planner", ["inline", "thread"])
def test_mean_trajectory_takes_one_environment_and_answers_as_reference(planner):
    """``mean_trajectory(env (d,))`` is ``(T, D)``, the batch's row for it, and at a fixed
    environment right after ``reset()`` the reference tracks that class and is that trajectory."""
    pol = toy_policy(nearest_k=8, planner=planner, plan_period=1e6)
    envs = torch.rand(12, 2, generator=torch.Generator().manual_seed(4), dtype=F64)
    batch = pol.mean_trajectory(envs)  # (12, T, D)
    labels = set()
    for i, e in enumerate(envs):
        one = pol.mean_trajectory(e)
        assert one.shape == batch.shape[1:]
        torch.testing.assert_close(one, batch[i], rtol=0, atol=1e-12)
        pol.reset()
        T = one.shape[0]
        for k in (0, T // 2, T - 1):
            r = pol.reference(e, k / (T - 1) * pol.duration)
            torch.testing.assert_close(r.q, one[k], rtol=0, atol=1e-9)
        assert r.label == int(pol.labels[pol.first_class(e)])
        labels.add(r.label)
    assert labels == {0, 1}
    pol.close()
