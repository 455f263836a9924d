"""Poses on ``/tf``: a frame's position composed up the transform tree
(:mod:`protorch.data.import_bag`).

``tf2_msgs/TFMessage`` messages on ``/tf`` (and ``/tf_static``) carry ``TransformStamped``
edges ``header.frame_id`` (the parent) -> ``child_frame_id``. A frame's position in its root
(the top of its chain, or the frame named ``root``) is the chain's transforms composed from the
frame up: ``p = t_e + R_e p`` for each edge ``e`` from the frame's own to the root's, every edge
held from each message to the next (the static ones constant). Frame names are read without a
leading ``/`` (ROS 1's ``/world`` is ``world``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .bag_stamps import Stream

__all__ = ["TF_STATIC", "TF_TOPIC", "chain", "compose", "tf_edges"]

TF_TOPIC, TF_STATIC = "/tf", "/tf_static"


def _ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(
        getattr(stamp, "nanosec", getattr(stamp, "nsec", 0))
    )


def tf_edges(messages) -> dict[tuple[str, str], list]:
    """``messages``: ``(log_ns, TFMessage)`` pairs -> ``{(parent, child): [(header_ns, log_ns,
    x, y, z, qx, qy, qz, qw), ...]}`` in the bag's order."""
    edges: dict[tuple[str, str], list] = {}
    for log_ns, msg in messages:
        for tr in msg.transforms:
            t, q = tr.transform.translation, tr.transform.rotation
            key = (tr.header.frame_id.lstrip("/"), tr.child_frame_id.lstrip("/"))
            edges.setdefault(key, []).append(
                (_ns(tr.header.stamp), int(log_ns), t.x, t.y, t.z, q.x, q.y, q.z, q.w)
            )
    return edges


def chain(
    frame: str, dynamic: dict, static: dict, root: str | None, where: str
) -> list[tuple[str, str]]:
    """The edges from ``frame`` up to ``root`` (or the top of its tree), the frame's own first.
    Errors: a frame the bag never names as a child, a frame with two parents, a ``root`` that is
    not above ``frame``."""
    parents: dict[str, set[str]] = {}
    for p, c in [*dynamic, *static]:
        parents.setdefault(c, set()).add(p)
    frame = frame.lstrip("/")
    if frame not in parents:
        names = sorted(set(parents) | {p for ps in parents.values() for p in ps})
        raise ValueError(
            f"{where}: no transform on {TF_TOPIC} or {TF_STATIC} has child_frame_id {frame!r} "
            f"(the frames: {names})"
        )
    out, at, seen = [], frame, {frame}
    while at in parents and at != root:
        if len(parents[at]) > 1:
            raise ValueError(
                f"{where}: frame {at!r} has two parents on {TF_TOPIC}: {sorted(parents[at])}"
            )
        (p,) = parents[at]
        out.append((p, at))
        if p in seen:
            raise ValueError(f"{where}: the transforms above {frame!r} form a loop at {p!r}")
        seen.add(p)
        at = p
    if root is not None and at != root.lstrip("/"):
        raise ValueError(
            f"{where}: --frame {root!r} is not above {frame!r} (its chain: "
            f"{' <- '.join([frame] + [p for p, _ in out])})"
        )
    return out


def edge_stream(key: tuple[str, str], rows: list) -> Stream:
    """One dynamic edge as a :class:`~protorch.data.bag_stamps.Stream` (data: x y z qx qy qz qw)."""
    a = np.asarray(rows, dtype=np.float64)  # (K, 9)
    ns = np.asarray([r[0] for r in rows], dtype=np.int64)
    log = np.asarray([r[1] for r in rows], dtype=np.int64)
    return Stream(f"{TF_TOPIC} {key[0]} -> {key[1]}", ns, log, a[:, 2:])


def compose(
    edges: Sequence[tuple[str, str]], timed: dict, static: dict, start_ns: int
) -> tuple[np.ndarray, np.ndarray]:
    """The frame's position in the chain's root over time: ``(ns (U,), xyz (U, 3))`` at the union
    ``U`` of the dynamic edges' stamps (one sample at ``start_ns`` when every edge is static).
    ``timed[edge] = (ns (K,), data (K, 7))`` sorted; ``static[edge]``: rows, the last is used."""
    from scipy.spatial.transform import Rotation

    stamps = [timed[e][0] for e in edges if e in timed]
    u = (
        np.unique(np.concatenate(stamps)) if stamps else np.array([start_ns], dtype=np.int64)
    )  # (U,)
    p = np.zeros((u.size, 3))  # (U, 3) the frame's origin in its own frame
    for e in edges:
        if e in timed:
            ns, data = timed[e]
            at = np.clip(np.searchsorted(ns, u, side="right") - 1, 0, ns.size - 1)  # the edge held
            d = data[at]  # (U, 7)
        else:
            d = np.broadcast_to(np.asarray(static[e][-1][2:], dtype=np.float64), (u.size, 7))
        p = d[:, :3] + Rotation.from_quat(d[:, 3:]).apply(p)  # into the parent's frame
    return u, p
