"""The online context-table expert: its codes, its causality, that it learns a simple motion,
and its table on a small fake capture."""

from __future__ import annotations

import numpy as np

from lidarflow.evaluate.metrics import confusion
from lidarflow.scan import GridSpec
from studies import context_expert as study
from studies.online_combination import BASELINES


def _moving_blob(frames: int, size: int = 20) -> np.ndarray:
    """A 2x2 blob moving one cell right per frame along a row, wrapping round."""
    occ = np.zeros((frames, size, size), bool)
    for t in range(frames):
        x = t % (size - 1)
        occ[t, 8:10, x : x + 2] = True
    return occ


def test_codes_pack_the_window_row_major_lag_by_lag():
    diagonal = np.eye(3, dtype=bool)[None]  # one frame, the main diagonal occupied
    code = study.context_codes(diagonal, 1, (0,), 1)
    assert code[0, 1, 1] == 1 + (1 << 4) + (1 << 8)  # top-left, centre, bottom-right
    assert code[0, 0, 0] == (1 << 4) + (1 << 8)  # outside the grid reads free
    assert code[0, 0, 2] == 1 << 6  # only (1, 1), down-left of it
    two = np.stack([diagonal[0], np.zeros((3, 3), bool)])  # the diagonal, then nothing
    lagged = study.context_codes(two, 1, (0, 1), 1)
    assert lagged[1, 1, 1] == (1 + (1 << 4) + (1 << 8)) << 9  # the previous frame: bits 9-17
    assert lagged[0, 1, 1] == 1 + (1 << 4) + (1 << 8)  # before the first frame: free
    assert study.context_codes(two, 0, (0,), 1)[0].tolist() == np.eye(3, dtype=int).tolist()
    block = np.zeros((1, 4, 4), bool)
    block[0, 0, 1] = True  # the 2x2 block (0, 0) is occupied once pooled
    pooled = study.context_codes(block, 1, (0,), 2)
    assert pooled[0, 0, 0] == 1 << 4 and pooled[0, 1, 1] == 1 << 4
    assert pooled[0, 2, 2] == 1  # the block up-left of block (1, 1)
    assert pooled[0, 3, 0] == 1 << 1  # the block above block (1, 0)


def test_the_probability_at_t_reads_no_frame_after_t():
    rng = np.random.default_rng(0)
    occ = rng.random((30, 16, 16)) < 0.2
    k, t = 3, 14
    p = study.online_probability(occ, k, study.levels_for(occ, k), 2.0)
    changed = occ.copy()
    changed[t + 1 :] = rng.random((30 - t - 1, 16, 16)) < 0.6
    q = study.online_probability(changed, k, study.levels_for(changed, k), 2.0)
    np.testing.assert_array_equal(p[: t + 1], q[: t + 1])  # bit-identical, NaN included
    assert not np.array_equal(p[t + 1 :], q[t + 1 :], equal_nan=True)
    d = study.online_decided(p, occ, k)
    np.testing.assert_array_equal(d[: t + 1], study.online_decided(q, changed, k)[: t + 1])
    assert np.isnan(p[:k]).all() and not np.isnan(p[k:]).any()  # nothing labelled before k
    np.testing.assert_array_equal(d[:k], occ[:k])  # the warm-up copies the last map


def test_it_learns_a_moving_blob_that_copy_last_only_half_gets():
    occ = _moving_blob(80)
    # two steps ahead the blob's far cell is out of the 3x3 window's reach: half of it is learnt
    for k, least in ((1, 0.9), (2, 0.55)):
        p = study.online_probability(occ, k, study.levels_for(occ, k), 2.0)
        d = study.online_decided(p, occ, k)
        later = slice(40, len(occ) - k)  # after warm-up
        truth = occ[k:][later]
        expert = confusion(d[later], truth).f1
        copy_last = confusion(occ[later], truth).f1
        assert copy_last < 0.5 and expert > least, (k, expert, copy_last)


def _fake_capture(path, frames: int = 40, horizon: int = 3) -> None:
    """A capture as studies.combination_capture writes it, on the study's grid: a blob moving
    right; every method copies the last map, the region is the blob's row."""
    width = GridSpec().width
    occ = np.zeros((frames, width, width), bool)
    for t in range(frames):
        occ[t, 40:42, 10 + t : 12 + t] = True
    scored = np.arange(5, frames - horizon)
    region = np.zeros_like(occ)
    region[:, 38:44, :] = True

    def packed(a: np.ndarray) -> np.ndarray:
        return np.packbits(a, axis=-1)

    copy = np.stack([occ[scored], occ[scored]], axis=1)
    methods = {f"method/{m}": packed(copy) for m in (*BASELINES, "model_combined")}
    np.savez(
        path,
        horizon=horizon,
        scored=scored,
        occupied=packed(occ),
        region=packed(region),
        candidates=packed(np.zeros((frames, 2, 1, width, width), bool)),
        rare=packed(np.zeros((frames, 2, width, width), bool)),
        causal_region=packed(region),
        **methods,
    )


def test_the_table_scores_each_fold_against_copy_last(tmp_path):
    for seed in ("s0", "s1"):
        (tmp_path / seed).mkdir()
        _fake_capture(tmp_path / seed / "blob.npz")
    out = tmp_path / "out"
    rows = study.main(["table", str(tmp_path / "s0"), str(tmp_path / "s1"), "-o", str(out)])
    assert set(rows) == {"blob@0", "blob@1"} and rows["blob@1"]["K"] == 3
    for row in rows.values():
        assert row["copy_last"]["margins"][2] == 0.0  # the mover margin is over copy-last
        assert len(row["region"]["seeds"]) == 2 and len(row["thresholds"]) == 2
    # one step ahead the blob's motion is learnt in the region: copy-last gets half of its
    # cells (and all of them within the mover metric's tolerance of two cells)
    assert rows["blob@0"]["region"]["margins"][0] > 0.3
    assert rows["blob@0"]["region"]["margins"][2] > -1e-9
    assert (out / "summary.json").exists()
    assert "| blob | 3 |" in (out / "summary.md").read_text()
