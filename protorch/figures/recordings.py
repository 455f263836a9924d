"""The cleaning of a recordings folder drawn (:mod:`protorch.data.recordings`): raw, trimmed,
aligned."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .common import atomic_save, new_figure

__all__ = ["recordings_figure"]

_NOTES = 8  # summary lines written under the panels


def recordings_figure(
    path: str | Path, folder, joint_names: Sequence[str], *, groups: int = 2
) -> Path:
    """One row per environment (the first ``groups``), three panels: the recordings as recorded
    over their own time (the kept part between the marks), trimmed and resampled over the phase,
    and aligned over the phase; one colour per recording, the joint that moves most; under the
    panels the report's summary lines (recordings excluded and why, findings). ``folder``:
    a :class:`~protorch.data.demos.DemoFolder` read by
    :func:`~protorch.data.recordings.read_recordings` (its ``stages`` and ``report``)."""
    recs = folder.report["recordings"]
    group_ids = sorted({r["group"] for r in recs})[:groups]
    notes = folder.report.get("summary", [])
    shown = notes[:_NOTES] + (
        [f"... and {len(notes) - _NOTES} more (metrics.json: demos.recordings)"]
        if len(notes) > _NOTES
        else []
    )
    below = 0.14 * len(shown) + (0.2 if shown else 0.0)  # inches of text under the panels
    fig = new_figure((12, 3.2 * len(group_ids) + below))
    axes = fig.subplots(len(group_ids), 3, squeeze=False)
    for row, g in enumerate(group_ids):
        members = [i for i, r in enumerate(recs) if r["group"] == g]
        span = np.ptp(np.concatenate([folder.stages[i]["trimmed"] for i in members]), axis=0)
        j = int(span.argmax())
        for c, i in enumerate(members):
            st, r, colour = folder.stages[i], recs[i], f"C{c}"
            t = st["time"] - st["time"][0]
            axes[row, 0].plot(
                t,
                st["raw"][:, j],
                color=colour,
                lw=0.8,
                label=f"{r['file']} ({r['rate_hz']:.0f} Hz)",
            )
            for at in (st["start"], st["end"]):
                axes[row, 0].axvline(at - st["time"][0], color=colour, ls=":", lw=0.8)
            z = np.linspace(0, 1, st["trimmed"].shape[0])
            axes[row, 1].plot(
                z,
                st["trimmed"][:, j],
                color=colour,
                lw=0.8,
                label=f"trimmed {r['trimmed_start_s']:.2f} + {r['trimmed_end_s']:.2f} s",
            )
            axes[row, 2].plot(
                z,
                st["aligned"][:, j],
                color=colour,
                lw=0.8,
                label=f"warp max {r.get('warp_max', 0.0):.3f}",
            )
        axes[row, 0].set_ylabel(f"env {g}: {joint_names[j]} (rad)")
        for ax, title in zip(
            axes[row], ("raw (dotted: kept)", "trimmed, resampled by time", "aligned (DTW)")
        ):
            ax.set_title(title, fontsize=9)
            ax.legend(fontsize=6)
        axes[row, 0].set_xlabel("time (s)")
        axes[row, 1].set_xlabel("phase")
        axes[row, 2].set_xlabel("phase")
    if shown:  # the excluded recordings and the findings (protorch.data.quality), under the panels
        fig.text(0.01, 0.005, "\n".join(shown), fontsize=7, va="bottom", family="monospace")
    fig.tight_layout(rect=(0, below / (3.2 * len(group_ids) + below), 1, 1))
    return atomic_save(path, ".png", lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
