"""The sparse backend beyond the contract: Eq. 7 and 8 on each query's nearest environments, its
error against the exact map, memory linear in M, the authors' nearest_k mode equal to the exact
backends', and its options through save / load and protorch.load."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from protorch.gp import load_env_map, make_env_map

from .reference import local_reference, make_data, smooth_data

ALPHA = 1.3
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def _maxerr(a, b) -> float:
    return float((a - b).abs().max())


@pytest.mark.parametrize("index", ["kdtree", "brute"])
def test_beyond_the_neighbours_it_is_eq78_on_the_nearest_with_the_label_prior(index):
    E, MU, VAR = make_data(300, 5, seed=3)
    labels = (E[:, 1] > 1).long()
    Q = make_data(12, 1, seed=4)[0]
    ql = torch.arange(12) % 2
    gp = make_env_map("sparse", ALPHA, neighbours=16, index=index).fit(
        E[:100], MU[:100], VAR[:100], labels[:100]
    )
    gp.add(E[100:], MU[100:], VAR[100:], labels[100:])
    mu, var = gp.predict(Q, ql)
    for g in (0, 1):
        s, sq = labels == g, ql == g
        rmu, rvar = local_reference(E[s], MU[s], VAR[s], Q[sq], ALPHA, 16)
        assert (
            _maxerr(mu[sq], torch.as_tensor(rmu)) < 1e-9
            and _maxerr(var[sq], torch.as_tensor(rvar)) < 1e-9
        )


def test_both_index_kinds_give_the_same_map():
    E, MU, VAR = make_data(400, 3, seed=5)
    Q = make_data(50, 1, seed=6)[0]
    a = make_env_map("sparse", ALPHA, neighbours=20).fit(E, MU, VAR).predict(Q)
    b = make_env_map("sparse", ALPHA, neighbours=20, index="brute").fit(E, MU, VAR).predict(Q)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])


def test_nearest_k_is_the_exact_backends_nearest_k_bit_for_bit():
    """The authors' local GPs (the arm's gp.nearest_k = 30): the same neighbours, the same solve."""
    E, MU, VAR = smooth_data(700, 7, seed=1)
    labels = torch.arange(700) % 2
    Q = smooth_data(40, 1, seed=2)[0]
    ql = torch.arange(40) % 2
    sparse = make_env_map("sparse", 30.0, nearest_k=30).fit(
        E[:300], MU[:300], VAR[:300], labels[:300]
    )
    for s in range(300, 700, 100):
        sparse.add(E[s : s + 100], MU[s : s + 100], VAR[s : s + 100], labels[s : s + 100])
    exact = make_env_map("torch", 30.0, nearest_k=30).fit(E, MU, VAR, labels)
    for a, b in zip(sparse.predict(Q, ql), exact.predict(Q, ql)):
        assert torch.equal(a, b)


def test_error_against_the_exact_map_shrinks_with_the_neighbours():
    """On smooth arm-like data (alpha = 30, 300 environments on a 0.6 m table): exact once the
    neighbourhood holds every environment, and within the error stated in docs/benchmarks.md
    (benchmarks/gp_sparse.py) before."""
    E, MU, VAR = smooth_data(300, 6)
    Q = smooth_data(24, 1, seed=9)[0]
    exact_mu, exact_var = make_env_map("torch", 30.0).fit(E, MU, VAR).predict(Q)
    spread = MU.std(0)  # (N,)
    errs = []
    for k in (8, 32, 128, 300):
        mu, var = make_env_map("sparse", 30.0, neighbours=k).fit(E, MU, VAR).predict(Q)
        errs.append((float(((mu - exact_mu).abs() / spread).median()), _maxerr(var, exact_var)))
    assert errs[0][0] > errs[1][0] > errs[2][0] > 1e-6 > errs[3][0] and errs[3][1] < 1e-9
    assert errs[0][1] > errs[1][1] > errs[2][1]
    # a subset of the data with the label's own prior variance: never more certain than all of it
    assert bool(
        (make_env_map("sparse", 30.0).fit(E, MU, VAR).predict(Q)[1] >= exact_var - 1e-12).all()
    )
    assert errs[1][0] < 0.05  # the default's 32 neighbours: median error under 5 % of the spread


def test_memory_is_linear_in_the_data():
    """No M x M (nor N M^2) state: every buffer together stays within a few rows per environment."""
    m, n, d = 3000, 20, 4
    E, MU, VAR = smooth_data(m, n, d)
    gp = make_env_map("sparse", 30.0).fit(E[:1000], MU[:1000], VAR[:1000], torch.arange(1000) % 2)
    gp.add(E[1000:], MU[1000:], VAR[1000:], torch.arange(1000, m) % 2)
    gp.predict(E[:5], torch.zeros(5, dtype=torch.long))
    stored = sum(b.numel() for b in gp.buffers())
    assert stored <= 2 * m * (d + 2 * n + 2) + 4 * n, stored  # capacity doubling at most


def test_options_survive_save_and_load(tmp_path):
    E, MU, VAR = make_data(80, 3)
    gp = make_env_map("sparse", ALPHA, neighbours=12, index="brute").fit(E, MU, VAR)
    back = load_env_map(gp.save(tmp_path / "map.safetensors"))
    assert back.backend == "sparse" and back.neighbours == 12 and back.index == "brute"
    Q = make_data(5, 1, seed=1)[0]
    assert torch.equal(back.predict(Q)[0], gp.predict(Q)[0])


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"neighbours": 0}, "neighbours"),
        ({"neighbours": 2.5}, "neighbours"),
        ({"index": "faiss"}, "index"),
    ],
)
def test_bad_options(kw, match):
    with pytest.raises(ValueError, match=match):
        make_env_map("sparse", ALPHA, **kw)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("index", ["kdtree", "brute"])
def test_on_device(device, index):
    E, MU, VAR = make_data(200, 4, seed=7)
    Q = make_data(6, 1, seed=8)[0]
    gp = make_env_map("sparse", ALPHA, neighbours=16, index=index, device=device).fit(E, MU, VAR)
    mu, var = gp.predict(Q)
    assert mu.device.type == device
    ref = local_reference(E, MU, VAR, Q, ALPHA, 16)
    assert (
        np.abs(mu.cpu().numpy() - ref[0]).max() < 1e-9
        and np.abs(var.cpu().numpy() - ref[1]).max() < 1e-9
    )


@pytest.mark.parametrize("nearest_k", [None, 30])
def test_adds_across_storage_blocks_and_trees_equal_one_bulk_fit(nearest_k, tmp_path):
    """2,600 environments added in batches of 1 to 700 (storage blocks of 1,024, 1,024, 2,048 rows;
    a k-d tree and a brute-force tail per label) predict what one fit of them predicts: the same
    neighbours and solves
    (bit for bit with nearest_k; the label prior's running sums round differently without), and
    so does the map saved and loaded."""
    m = 2600
    E, MU, VAR = smooth_data(m, 3, seed=11)
    labels = (E[:, 0] > 0.4).long()
    Q = smooth_data(60, 1, seed=12)[0]
    ql = torch.arange(60) % 2
    grown = make_env_map("sparse", 30.0, nearest_k=nearest_k).fit(
        E[:30], MU[:30], VAR[:30], labels[:30]
    )
    s = 30
    for b in [1] * 1100 + [700, 3, 500] + [1] * 267:
        grown.add(E[s : s + b], MU[s : s + b], VAR[s : s + b], labels[s : s + b])
        s += b
    assert s == m and len(grown._data.blocks) == 3
    index = grown.groups["0"].index
    assert (
        index.trees and index.n > index.n_tree and len(index.points.blocks) == 2
    )  # trees, a tail, 2 blocks
    bulk = make_env_map("sparse", 30.0, nearest_k=nearest_k).fit(E, MU, VAR, labels)
    back = load_env_map(grown.save(tmp_path / "map.safetensors"))
    assert torch.equal(back.E, E) and torch.equal(back.labels, labels)
    for other in (bulk, back):
        for a, b in zip(grown.predict(Q, ql), other.predict(Q, ql)):
            assert torch.equal(a, b) if nearest_k else _maxerr(a, b) < 1e-12
