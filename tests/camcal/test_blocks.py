"""The residual-block interface of the bundle adjustment (rigcal.camcal.blocks): a toy
residual kind plugged in with its own parameter blocks — 2-D points (the eliminated
family) ranged from anchors (kept; one held) — checked against finite differences, the
whole-Jacobian reference, and a known answer."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.camcal.blocks import JacobianChunk, NormalEquations, ParameterBlock, register, sparse_jacobian, sum_normal_equations


class Ranges:
    """r_i = |p[e_i] - a[k_i]| - d_i (D = 1): point e_i (eliminated, 2 columns) from
    anchor k_i (kept, 2 columns, per row). `shared`: chunks of one anchor each, so the
    kept columns are shared by the chunk (the dense-product path); else one chunk with
    per-row columns (the scattered path)."""

    dim = 1

    def __init__(self, params, p0, a0, e, k, d, shared=False, chunk=5):
        self.params, self.p0, self.a0 = params, p0, a0
        self.e, self.k, self.d = e, k, d
        self.n_rows, self.shared, self.chunk = len(e), shared, chunk

    def _points(self, x):
        s_p, s_a = self.params.starts["point"], self.params.starts["anchor"]
        p = self.p0 + np.where(s_p[:, None] >= 0, x[np.maximum(s_p, 0)[:, None] + np.arange(2)], 0.0)
        a = self.a0 + np.where(s_a[:, None] >= 0, x[np.maximum(s_a, 0)[:, None] + np.arange(2)], 0.0)
        return p, a

    def residuals(self, x):
        p, a = self._points(x)
        return (np.linalg.norm(p[self.e] - a[self.k], axis=1) - self.d)[:, None]

    def jacobian_chunks(self, x):
        p, a = self._points(x)
        diff = p[self.e] - a[self.k]
        u = (diff / np.linalg.norm(diff, axis=1)[:, None])[:, None, :]  # (m, 1, 2)
        cols = self.params.starts["anchor"][self.k][:, None] + np.arange(2)
        cols = np.where(self.params.starts["anchor"][self.k][:, None] >= 0, cols, -1)
        if self.shared:
            for kk in np.unique(self.k):
                rows = np.flatnonzero(self.k == kk)
                rows = rows[np.argsort(self.e[rows], kind="stable")]
                yield JacobianChunk(rows, -u[rows], cols[rows[0]], u[rows], self.e[rows])
        else:
            for lo in range(0, self.n_rows, self.chunk):
                rows = np.arange(lo, min(lo + self.chunk, self.n_rows))
                yield JacobianChunk(rows, -u[rows], cols[rows], u[rows], self.e[rows])


def _scene(rng, n_points=7, n_anchors=4):
    """Anchors and points in the plane, every point ranged from every anchor."""
    a = rng.uniform(-5, 5, (n_anchors, 2))
    p = rng.uniform(-3, 3, (n_points, 2))
    e, k = (g.ravel() for g in np.meshgrid(np.arange(n_points), np.arange(n_anchors), indexing="ij"))
    perm = rng.permutation(len(e))  # rows not grouped by point: some chunks hold a point twice, apart
    return a, p, e[perm], k[perm]


def _registry(n_points, n_anchors, held_anchors=(0,)):
    blocks = [ParameterBlock("point", i, 2) for i in range(n_points)]
    blocks += [ParameterBlock("anchor", j, 2, j in held_anchors) for j in range(n_anchors)]
    return register(blocks, eliminated="point")


def test_register_orders_columns_and_holds():
    reg = register([ParameterBlock("frame", 0, 6), ParameterBlock("cam", 0, 4, held=True), ParameterBlock("cam", 1, 4),
                    ParameterBlock("frame", 1, 6), ParameterBlock("board", 0, 6)], eliminated="frame")
    assert reg.size == 4 + 6 + 12 and reg.split == 10 and reg.elim_size == 6
    assert list(reg.starts["cam"]) == [-1, 0] and list(reg.starts["board"]) == [4]
    assert list(reg.starts["frame"]) == [10, 16]
    assert reg.slices("cam") == (None, slice(0, 4)) and reg.slices("frame") == (slice(10, 16), slice(16, 22))
    with pytest.raises(ValueError):
        register([ParameterBlock("frame", 0, 6), ParameterBlock("frame", 1, 3)], eliminated="frame")


@pytest.mark.parametrize("shared", [False, True])
def test_toy_block_jacobian_matches_central_differences(shared):
    rng = np.random.default_rng(1)
    a, p, e, k = _scene(rng)
    reg = _registry(len(p), len(a))
    blk = Ranges(reg, p, a, e, k, rng.uniform(1, 2, len(e)), shared=shared)
    x = rng.normal(0, 0.1, reg.size)
    J = sparse_jacobian([blk], reg, x).toarray()
    h = 1e-6
    Jn = np.column_stack([(blk.residuals(x + h * np.eye(reg.size)[j]) - blk.residuals(x - h * np.eye(reg.size)[j])).ravel()
                          / (2 * h) for j in range(reg.size)])
    assert np.abs(Jn).max() > 0.5
    assert np.max(np.abs(J - Jn)) < 1e-8


@pytest.mark.parametrize("shared", [False, True])
def test_chunked_sums_equal_the_whole_jacobian(shared):
    """sum_normal_equations over two toy blocks (scattered and shared paths, rows weighted)
    equals the plain construction from the whole Jacobian."""
    rng = np.random.default_rng(2)
    a, p, e, k = _scene(rng)
    reg = _registry(len(p), len(a))
    blocks = [Ranges(reg, p, a, e, k, rng.uniform(1, 2, len(e)), shared=shared),
              Ranges(reg, p, a, e[::-1].copy(), k[::-1].copy(), rng.uniform(1, 2, len(e)), shared=not shared, chunk=3)]
    x = rng.normal(0, 0.1, reg.size)
    r = np.concatenate([b.residuals(x).ravel() for b in blocks])
    w = rng.uniform(0.3, 3.0, len(r))
    got = sum_normal_equations(blocks, reg, x, r, w)
    ref = NormalEquations.from_jacobian(sparse_jacobian(blocks, reg, x), r, w, reg.split, reg.elim_size)
    for name in ("g_a", "g_d", "H_aa", "H_ad", "H_dd"):
        A, B = getattr(got, name), getattr(ref, name)
        assert np.abs(B).max() > 0, name
        assert np.max(np.abs(A - B)) <= 1e-12 * np.abs(B).max(), name


def test_gauss_newton_on_the_toy_block_finds_the_points():
    """Known answer: exact ranges from the true points and anchors (anchors 0 and 1 held at
    their truth: the gauge), a start 0.2 off: Gauss-Newton steps of NormalEquations.solve
    (the Schur step over the points) recover every point and the free anchors to 1e-9."""
    rng = np.random.default_rng(3)
    a, p, e, k = _scene(rng, n_points=9, n_anchors=4)
    d = np.linalg.norm(p[e] - a[k], axis=1)
    reg = _registry(len(p), len(a), held_anchors=(0, 1))
    p_start = p + rng.normal(0, 0.2, p.shape)
    a_start = a + rng.normal(0, 0.2, a.shape)
    a_start[:2] = a[:2]
    blk = Ranges(reg, p_start, a_start, e, k, d, shared=True)
    x = np.zeros(reg.size)
    for _ in range(20):
        r = blk.residuals(x).ravel()
        dx, _ = sum_normal_equations([blk], reg, x, r, np.ones_like(r)).solve(0.0)
        x = x + dx
        if np.abs(dx).max() < 1e-13:
            break
    p_hat, a_hat = blk._points(x)
    assert np.abs(blk.residuals(x)).max() < 1e-10
    assert np.max(np.abs(p_hat - p)) < 1e-9 and np.max(np.abs(a_hat - a)) < 1e-9
    assert np.max(np.abs(p_start - p)) > 0.1  # it did move
