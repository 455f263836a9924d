"""Fig. 5 (c): via quaternions are drawn with the sign of the mean's curve (q and -q
are one pose)."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from protorch.figures.beam import plot_quaternion_components  # noqa: E402
from protorch.primitives.pose import quaternion_slerp  # noqa: E402


def test_via_markers_follow_the_curves_sign():
    q0 = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    q1 = torch.tensor([0.5, 0.5, 0.5, 0.5], dtype=torch.float64)
    phase = torch.linspace(0, 1, 51, dtype=torch.float64)
    curve = quaternion_slerp(q0, q1, phase)  # (51, 4)
    via_phases = phase[[0, 20, 50]]
    via = curve[[0, 20, 50]] * torch.tensor(
        [[1.0], [-1.0], [-1.0]], dtype=torch.float64
    )  # two given as -q
    fig, ax = plt.subplots()
    plot_quaternion_components(ax, phase, curve, via_phases=via_phases, via=via)
    markers = [line for line in ax.get_lines() if line.get_marker() == "o"]
    assert len(markers) == 3  # one per drawn component
    for k, line in enumerate(markers):
        np.testing.assert_allclose(line.get_ydata(), curve[[0, 20, 50], k].numpy(), atol=1e-12)
    plt.close(fig)
