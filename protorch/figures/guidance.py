"""The guidance comparison of the beam experiment (protorch.experiments.beam_guidance): assisted
success and free-phase force per optimiser, side by side."""

from __future__ import annotations

from pathlib import Path

from .common import atomic_save, new_figure

__all__ = ["guidance_figure"]


def guidance_figure(path, results: dict) -> Path:
    """Two bar panels from ``{optimiser: {"assisted_success_rate", "free_force", ...}}``."""
    names = list(results)
    fig = new_figure((8.0, 3.2))
    ax1, ax2 = fig.subplots(1, 2)
    x = range(len(names))
    ax1.bar(x, [results[n]["assisted_success_rate"] for n in names], color="tab:green")
    ax1.set_ylim(0, 1.05)
    ax1.set_ylabel("assisted success rate")
    ax2.bar(x, [results[n]["free_force"] for n in names], color="tab:blue")
    ax2.set_ylabel("mean |F| away from the via points (N)")
    for ax in (ax1, ax2):
        ax.set_xticks(list(x), names)
    fig.suptitle("guidance built from each optimiser's distribution (same 100 operators)")
    fig.tight_layout()
    return atomic_save(path, ".png", lambda tmp: fig.savefig(tmp, format="png", dpi=110))
