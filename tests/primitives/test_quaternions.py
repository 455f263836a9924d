"""protorch.primitives.quaternions: pytorch_kinematics' conversions, imported only when used."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import torch

from protorch.primitives.quaternions import (
    axis_angle_to_quaternion,
    quaternion_raw_multiply,
    quaternion_to_matrix,
)

ROOT = Path(__file__).resolve().parents[2]


def test_the_conversions_are_pytorch_kinematics_ones():
    import pytorch_kinematics.transforms as pk

    a = torch.randn(5, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    q = axis_angle_to_quaternion(a)
    assert torch.equal(q, pk.axis_angle_to_quaternion(a))
    assert torch.equal(
        quaternion_raw_multiply(q, q.flip(0)), pk.quaternion_raw_multiply(q, q.flip(0))
    )
    assert torch.equal(quaternion_to_matrix(q), pk.quaternion_to_matrix(q))


def test_the_app_starts_without_importing_pytorch_kinematics_or_pyplot():
    code = (
        "import sys, protorch.app.main; "
        "print(sorted({'pytorch_kinematics', 'matplotlib.pyplot'} & set(sys.modules)))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]"
