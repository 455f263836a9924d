"""Helpers every figure module shares: tensors to numpy, a pyplot-free figure, atomic saving."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["to_numpy", "new_figure", "atomic_save", "frame_indices", "legend_below"]


def to_numpy(x):
    """A tensor or array-like as a numpy array (``None`` stays ``None``)."""
    if x is None:
        return None
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


def new_figure(figsize):
    """A figure on its own Agg canvas: no pyplot state, so the caller's backend and open figures
    are left alone and nothing needs closing."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig


def atomic_save(path, suffix: str, save) -> Path:
    """Call ``save(tmp)`` on a temporary file beside ``path`` (mode 0644), then rename it over
    ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=suffix)
    os.close(fd)
    try:
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; an image is meant to be read
        save(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def frame_indices(n: int, frames, num_frames: int) -> list[int]:
    """``num_frames`` evenly spaced instants of ``n`` (or the given ``frames``, checked)."""
    if frames is None:
        if num_frames < 1:
            raise ValueError(f"num_frames must be >= 1, got {num_frames}")
        return sorted({int(round(i)) for i in np.linspace(0, n - 1, min(num_frames, n))})
    idx = [int(f) for f in frames]
    bad = [f for f in idx if not 0 <= f < n]
    if bad or not idx:
        raise ValueError(f"frames must be instants in [0, {n - 1}], got {list(frames)}")
    return idx


def legend_below(fig, axes, *, ncol: int = 6, fontsize: int = 7):
    """One legend for the whole figure, centred below its panels (so it covers no data), with
    each label of ``axes`` once; call after ``tight_layout``. Returns the legend (or ``None``)."""
    handles, labels = [], []
    for ax in np.ravel(axes):
        for h, label in zip(*ax.get_legend_handles_labels()):
            if label not in labels and not label.startswith("_"):
                handles.append(h)
                labels.append(label)
    if not handles:
        return None
    return fig.legend(
        handles,
        labels,
        loc="upper center",
        bbox_to_anchor=(0.5, 0.0),
        ncol=min(ncol, len(labels)),
        fontsize=fontsize,
        frameon=False,
    )
