"""Multiresolution error from the summary tables equals the same error computed from the voxels
(Wang, Garcia & Shen 2007, Eqns. 1 and 6-10), and a transfer-function change needs no voxel."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import zarr

from clipvol.bricking.pipeline import brick_volume
from clipvol.bricking.summary import open_summary
from clipvol.scene.lod_error import C1, C2, lod_errors
from clipvol.scene.transfer import TransferFunction

# -- an independent CIE L*u*v* (sRGB, D65), written out from the standard ---------------------------
_M = np.array([[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750], [0.0193339, 0.1191920, 0.9503041]])


def _luv(rgb):
    c = np.clip(rgb, 0, 1)
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    X, Y, Z = np.moveaxis(lin @ _M.T, -1, 0)
    Xn, Yn, Zn = _M.sum(axis=1)
    L = np.where(Y / Yn > (6 / 29) ** 3, 116 * np.cbrt(Y / Yn) - 16, (29 / 3) ** 3 * Y / Yn)
    d = X + 15 * Y + 3 * Z
    dn = Xn + 15 * Yn + 3 * Zn
    up = np.where(d > 0, 4 * X / np.where(d > 0, d, 1), 0)
    vp = np.where(d > 0, 9 * Y / np.where(d > 0, d, 1), 0)
    return np.stack([L, 13 * L * (up - 4 * Xn / dn), 13 * L * (vp - 9 * Yn / dn)], -1)


def _colour(tf, v, rng_):
    rgba = tf.lookup(v, rng_)
    return _luv(rgba[..., :3] * rgba[..., 3:4])


def _child_blocks(pyr, lv, L, pidx):
    """Each child brick ``c`` of node ``pidx`` at level ``L`` (those inside the grid), with its
    voxels at level ``L - 1`` and, voxel for voxel, the level-``L`` voxel each one averages into."""
    B = pyr.brick_shape
    for o in np.ndindex(2, 2, 2):
        c = tuple(2 * p + d for p, d in zip(pidx, o))
        if any(ci >= gi for ci, gi in zip(c, pyr.grid(L - 1))):
            continue
        gidx = [np.arange(ci * b, min((ci + 1) * b, s)) for ci, b, s in zip(c, B, lv[L - 1].shape)]
        yield c, lv[L - 1][np.ix_(*gidx)].reshape(-1), lv[L][np.ix_(*(a // 2 for a in gidx))].reshape(-1)


def _direct_eps(path, tf):
    """Eqns. 1 and 6-10 evaluated voxel by voxel on the store's own levels (read with zarr-python)."""
    g = zarr.open_group(str(path), mode="r")
    tabs = open_summary(path)
    pyr = tabs.pyramid
    vr = pyr.value_range
    lv = [np.asarray(g[str(L)][...]).astype(np.float64) for L in range(pyr.num_levels)]
    B = pyr.brick_shape
    stats = {}
    for L in range(pyr.num_levels):
        for idx in np.ndindex(*pyr.grid(L)):
            v = lv[L][tuple(slice(i * b, (i + 1) * b) for i, b in zip(idx, B))].reshape(-1)
            mu = v.mean()
            cmu = _colour(tf, np.array([mu]), vr)[0]
            dev = np.linalg.norm(_colour(tf, v, vr) - cmu, axis=1)
            stats[L, idx] = (cmu[0], (dev**2).sum() / max(len(v) - 1, 1), len(v))
    raw = {(0, idx): 0.0 for idx in np.ndindex(*pyr.grid(0))}
    for L in range(1, pyr.num_levels):
        for pidx in np.ndindex(*pyr.grid(L)):
            total, worst = 0.0, 0.0
            for c, child, parent in _child_blocks(pyr, lv, L, pidx):
                de = np.linalg.norm(_colour(tf, parent, vr) - _colour(tf, child, vr), axis=1)
                mi, vi, _ = stats[L, pidx]
                mj, vj, n = stats[L - 1, c]
                sig = np.sqrt((de**2).sum() / max(n - 1, 1))
                lum = (mi**2 + mj**2 + C1) / (2 * mi * mj + C1)
                con = (vi + vj + C2) / (2 * np.sqrt(vi * vj) + C2)
                total += sig * lum * con
                worst = max(worst, raw[L - 1, c])
            raw[L, pidx] = total + worst
    return raw


def _head(rng):
    from clipvol.bricking.generators import ct_head

    return ct_head((40, 36, 44), seed=3)


TF_A = TransferFunction.preset("bone")
TF_B = TransferFunction.from_points([(0.0, (0, 0, 0, 0)), (0.5, (0.2, 0.6, 1.0, 0.1)), (1.0, (1, 0.3, 0.1, 0.9))])


@pytest.mark.parametrize("tf", [TF_A, pytest.param(TF_B, marks=pytest.mark.slow)], ids=["bone", "blue-red"])
def test_table_error_equals_voxel_error(tmp_path, rng, tf):
    path = tmp_path / "h.zarr"
    brick_volume(_head(rng), path, brick=8, progress=False)
    got = lod_errors(open_summary(path), tf)
    ref = _direct_eps(path, tf)
    for (L, idx), want in ref.items():
        assert got.raw_eps[L][idx] == pytest.approx(want, rel=1e-6, abs=1e-6), (L, idx)
    assert max(float(e.max()) for e in got.eps) == pytest.approx(1.0)


def test_float_store_error_within_quantisation(tmp_path, rng):
    vol = _head(rng).astype(np.float32) / 7.0  # uniform 256-level quantisation of a float store
    path = tmp_path / "f.zarr"
    brick_volume(vol, path, brick=8, progress=False)
    got = lod_errors(open_summary(path), TF_B)
    ref = _direct_eps(path, TF_B)
    L = max(k[0] for k in ref)
    for (lv, idx), want in ref.items():
        if lv >= 1:
            assert got.raw_eps[lv][idx] == pytest.approx(want, rel=0.1, abs=0.02 * ref[L, (0, 0, 0)]), (lv, idx)


def test_transfer_function_change_needs_only_the_tables(tmp_path, rng):
    path = tmp_path / "h.zarr"
    brick_volume(_head(rng), path, brick=8, progress=False)
    want = _direct_eps(path, TF_B)
    tabs = open_summary(path)
    a = lod_errors(tabs, TF_A)
    for L in range(tabs.pyramid.num_levels):  # the voxels are gone: only the tables are left
        shutil.rmtree(path / str(L))
    b = lod_errors(tabs, TF_B)
    assert any(not np.allclose(x, y) for x, y in zip(a.raw_eps, b.raw_eps))
    for (L, idx), w in want.items():
        assert b.raw_eps[L][idx] == pytest.approx(w, rel=1e-6, abs=1e-6)


def _direct_bias(path, tf):
    """The classification bias voxel by voxel on the store's own levels (read with zarr-python): per
    child brick, the RMS over its voxels of |colour(parent value) - mean colour of the child voxels
    under parents of that value|; per node, the mean over its children plus the worst child's own."""
    g = zarr.open_group(str(path), mode="r")
    pyr = open_summary(path).pyramid
    vr = pyr.value_range
    lv = [np.asarray(g[str(L)][...]).astype(np.float64) for L in range(pyr.num_levels)]
    out = {(0, idx): 0.0 for idx in np.ndindex(*pyr.grid(0))}
    for L in range(1, pyr.num_levels):
        for pidx in np.ndindex(*pyr.grid(L)):
            per_child, worst = [], 0.0
            for c, child, parent in _child_blocks(pyr, lv, L, pidx):
                fc = _colour(tf, child, vr)
                s = 0.0
                for k in np.unique(parent):
                    sel = parent == k
                    s += sel.sum() * float(np.sum((_colour(tf, np.array([k]), vr)[0] - fc[sel].mean(axis=0)) ** 2))
                per_child.append(np.sqrt(s / len(child)))
                worst = max(worst, out[L - 1, c])
            out[L, pidx] = float(np.mean(per_child)) + worst
    return out


@pytest.mark.parametrize("tf", [TF_A, pytest.param(TF_B, marks=pytest.mark.slow)], ids=["bone", "blue-red"])
def test_classification_bias_equals_the_voxels(tmp_path, rng, tf):
    """The bias the visible-error estimate uses (``LodErrors.bias``), from the tables, equals the
    same quantity computed from the voxels."""
    path = tmp_path / "h.zarr"
    brick_volume(_head(rng), path, brick=8, progress=False)
    got = lod_errors(open_summary(path), tf)
    ref = _direct_bias(path, tf)
    for (L, idx), want in ref.items():
        assert got.bias[L][idx] == pytest.approx(want, rel=1e-6, abs=1e-6), (L, idx)
    assert max(float(b.max()) for b in got.bias) > 0


def test_classify_mode_is_checked(tmp_path, rng):
    from clipvol.errors import ParameterError

    path = tmp_path / "h.zarr"
    brick_volume(_head(rng), path, brick=8, progress=False)
    tabs = open_summary(path)
    with pytest.raises(ParameterError, match="classify"):
        lod_errors(tabs, TF_A, classify="median")


def _expected_prem(tf, value, spread, vr, n=4001):
    """E[a c] over N(value, spread), integrated directly on a grid of 8 standard deviations (the
    table's ends extended, as the lookup clamps), independent of the pre-integrated tables."""
    if spread <= 0:
        rgba = tf.lookup(np.array([value]), vr)[0]
        return rgba[:3] * rgba[3]
    x = value + spread * np.linspace(-4.0, 4.0, n)
    w = np.exp(-0.5 * ((x - value) / spread) ** 2)
    rgba = tf.lookup(x, vr)
    return (w[:, None] * rgba[:, :3] * rgba[:, 3:4]).sum(axis=0) / w.sum()


def _direct_distribution_bias(path, tf):
    """The distribution-mode bias voxel by voxel (levels read with zarr-python): per child brick and
    parent value k, the fine values' variance plus the child brick's mean spread^2 (0 at level 0;
    above, the same quantity over its own pairs) gives s; |Luv(E[a c] over N(k, s)) - Luv(mean of
    the fine voxels' premultiplied colour)| (fine colour: level 0's, or at level >= 2 the child
    value's E[a c] at its brick's mean spread), RMS over the child's voxels; per node the mean over
    its children plus the worst child's own."""
    g = zarr.open_group(str(path), mode="r")
    pyr = open_summary(path).pyramid
    vr = pyr.value_range
    lv = [np.asarray(g[str(L)][...]).astype(np.float64) for L in range(pyr.num_levels)]
    out = {(0, idx): 0.0 for idx in np.ndindex(*pyr.grid(0))}
    s2 = {(0, idx): 0.0 for idx in np.ndindex(*pyr.grid(0))}
    for L in range(1, pyr.num_levels):
        for pidx in np.ndindex(*pyr.grid(L)):
            per_child, worst, num, den = [], 0.0, 0.0, 0.0
            for c, child, parent in _child_blocks(pyr, lv, L, pidx):
                cs = np.sqrt(s2[L - 1, c])
                vals, back = np.unique(child, return_inverse=True)
                fine = np.array([_expected_prem(tf, v, cs, vr) for v in vals])[back.reshape(-1)]
                tot = 0.0
                for k in np.unique(parent):
                    sel = parent == k
                    var = float(np.var(child[sel])) + s2[L - 1, c]
                    coarse = _expected_prem(tf, k, np.sqrt(var), vr)
                    tot += sel.sum() * float(np.sum((_luv(coarse) - _luv(fine[sel].mean(axis=0))) ** 2))
                    num += sel.sum() * var
                den += len(child)
                per_child.append(np.sqrt(tot / len(child)))
                worst = max(worst, out[L - 1, c])
            out[L, pidx] = float(np.mean(per_child)) + worst
            s2[L, pidx] = num / den
    return out


@pytest.mark.slow
def test_distribution_residual_equals_the_voxels(tmp_path, rng, monkeypatch):
    """Consistent levels (``classify="distribution"``): the normal model's residual from the tables
    equals the same model evaluated voxel by voxel with a directly integrated normal expectation
    (within the renderer's table resolution: 32 spread rows, bilinear; 1 %), and it is well below
    the mean mode's bias where a sharp table meets thin bright structures; the bias of the mode is
    the larger of the residual and DISTRIBUTION_FLOOR times the mean mode's (the mean mode's at a
    floor of 1)."""
    from clipvol.scene import lod_error
    from clipvol.scene.lod_error import DISTRIBUTION_FLOOR, colour_table, classification_bias, distribution_residual

    path = tmp_path / "h.zarr"
    brick_volume(_head(rng), path, brick=8, progress=False)
    tabs = open_summary(path)
    got = distribution_residual(tabs, TF_A)
    ref = _direct_distribution_bias(path, TF_A)
    for (L, idx), want in ref.items():  # measured: within 0.3 % of the larger of the value and 1 Delta E
        assert got[L][np.ravel_multi_index(idx, tabs.pyramid.grid(L))] == pytest.approx(want, rel=0.01, abs=0.01), (L, idx)
    mean = lod_errors(tabs, TF_A)
    for L in range(1, tabs.pyramid.num_levels):
        assert got[L].sum() < 0.7 * mean.bias[L].sum(), L
    assert max(float(b.max()) for b in got) > 0
    F = colour_table(TF_A, tabs.quantiser.centres(), tabs.pyramid.value_range)
    for floor in (DISTRIBUTION_FLOOR, 0.5, 0.0):
        monkeypatch.setattr(lod_error, "DISTRIBUTION_FLOOR", floor)
        mode = classification_bias(tabs, F, "distribution", TF_A)
        for L in range(tabs.pyramid.num_levels):
            want = mean.bias[L].reshape(-1) if floor >= 1 else np.maximum(got[L], floor * mean.bias[L].reshape(-1))
            assert np.allclose(mode[L], want), (floor, L)


def _tubes(shape):
    """Thin bright tubes (1-2 voxels across) in air: their level-0 voxels show bone, the coarse
    levels' means do not."""
    vol = np.zeros(shape, np.uint8)
    vol[:, 10:12, 13] = 255  # along z
    vol[30, :, 33:35] = 255  # along y
    vol[5:7, 40, :] = 230  # along x
    return vol


def test_emission_counts_what_lies_beneath(tmp_path):
    """A coarse brick's emission and opacity are at least the voxel-weighted mean of its children's
    (bottom-up from level 0, each the mean over its own voxels of ``|Luv(c a)|`` and ``a``), so
    they are positive exactly where the brick or a descendant at any level shows something - here
    on an odd-sized grid where the coarse levels' own voxels show nothing along thin tubes."""
    path = tmp_path / "tubes.zarr"
    brick_volume(_tubes((72, 56, 40)), path, brick=8, progress=False)
    g = zarr.open_group(str(path), mode="r")
    tabs = open_summary(path)
    pyr = tabs.pyramid
    tf = TransferFunction.preset("bone")
    vr = pyr.value_range
    lv = [np.asarray(g[str(L)][...]).astype(np.float64) for L in range(pyr.num_levels)]
    B = np.array(pyr.brick_shape)
    shows = [tf.lookup(a, vr)[..., 3] > 0 for a in lv]
    top = pyr.num_levels - 1
    assert shows[0].any() and not shows[top].any()  # the case: the root's own voxels show nothing
    err = lod_errors(tabs, tf)
    want_em, want_op, count = {}, {}, {}
    for L in range(pyr.num_levels):
        for idx in np.ndindex(*pyr.grid(L)):
            v = lv[L][tuple(slice(i * b, (i + 1) * b) for i, b in zip(idx, B))].reshape(-1)
            em, op = np.linalg.norm(_colour(tf, v, vr), axis=1).mean(), tf.lookup(v, vr)[:, 3].mean()
            count[L, idx] = len(v)
            if L:
                kids = [c for c in (tuple(2 * p + d for p, d in zip(idx, o)) for o in np.ndindex(2, 2, 2))
                        if all(ci < gi for ci, gi in zip(c, pyr.grid(L - 1)))]
                n = sum(count[L - 1, c] for c in kids)
                em = max(em, sum(count[L - 1, c] * want_em[L - 1, c] for c in kids) / n)
                op = max(op, sum(count[L - 1, c] * want_op[L - 1, c] for c in kids) / n)
            want_em[L, idx], want_op[L, idx] = em, op
            assert err.emission[L][idx] == pytest.approx(em, rel=1e-9, abs=1e-9), (L, idx)
            assert err.opacity[L][idx] == pytest.approx(op, rel=1e-9, abs=1e-12), (L, idx)
            # conservative: positive exactly where a voxel of this brick's region shows at some level
            below = any(shows[k][tuple(slice(i * b * 2 ** (L - k), (i + 1) * b * 2 ** (L - k)) for i, b in zip(idx, B))].any()
                        for k in range(L + 1))
            assert (err.emission[L][idx] > 0) == below, (L, idx)
