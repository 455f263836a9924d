"""The Panda's link volumes (protorch.robots.panda_volumes): the capsules ride on the chain's
frames, the inertial data are physical, and a bad chain is refused."""

from __future__ import annotations

import pytest
import torch

from protorch.robots import PANDA_LIMITS
from protorch.robots.kinematics import ArmKinematics
from protorch.robots.panda_volumes import (
    PANDA_CAPSULES,
    PANDA_INERTIALS,
    PANDA_TORQUE_LIMITS,
    capsule_index,
    capsule_segments,
)


def test_capsule_endpoints_are_the_link_frames_applied_to_the_local_points(gen):
    kin = ArmKinematics()
    lo, hi = torch.tensor(PANDA_LIMITS, dtype=torch.float64).T
    q = lo + (hi - lo) * torch.rand(4, 7, generator=gen, dtype=torch.float64)
    frames = kin.frames(q)  # (4, F, 4, 4)
    a, b, r = capsule_segments(frames, kin.frame_names)
    assert a.shape == (4, len(PANDA_CAPSULES), 3) and r.shape == (len(PANDA_CAPSULES),)
    for i, c in enumerate(PANDA_CAPSULES):
        f = frames[:, kin.frame_names.index(c.link)]  # (4, 4, 4)
        expect = (f @ torch.tensor([*c.b, 1.0], dtype=torch.float64))[:, :3]
        assert torch.allclose(b[:, i], expect, atol=1e-12)
        assert float(r[i]) == c.radius
    # rigid: a capsule's length never changes with the joints
    length = (b - a).norm(dim=-1)
    assert torch.allclose(length, length[:1].expand_as(length), atol=1e-12)


def test_inertials_are_physical_and_the_torque_limits_are_the_urdfs():
    for name, inertial in PANDA_INERTIALS.items():
        xx, yy, zz, xy, xz, yz = inertial.inertia
        mat = torch.tensor([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]], dtype=torch.float64)
        eig = torch.linalg.eigvalsh(mat)
        assert inertial.mass > 0 and bool((eig > 0).all()), name
        # the triangle inequality of principal moments (a rigid body's inertia must satisfy it)
        assert float(eig[0] + eig[1]) >= float(eig[2]) - 1e-12, name
    kin = ArmKinematics()
    import xml.etree.ElementTree as ET

    efforts = [float(j.find("limit").get("effort")) for j in ET.fromstring(kin.urdf_text).iter("joint")
               if j.get("type") == "revolute"]
    assert tuple(efforts) == PANDA_TORQUE_LIMITS


def test_a_chain_without_the_panda_links_is_refused():
    with pytest.raises(ValueError, match="have no link 'panda_hand'"):
        capsule_index(["base", "l1", "l2"])
