"""The combination's ceiling study on a short simulated recording: what it keeps scores as
evaluate's horizon tables do, and every fixed pair is tabled beside the combination as it ran."""

from __future__ import annotations

import numpy as np

from lidarflow.online.combination import CANDIDATES
from lidarflow.sim import SimConfig, write_simulation
from studies import combination_ceiling as study
from studies import still_candidate
from studies.combination_capture import capture
from studies.online_combination import KEYS


def test_the_kept_maps_score_as_evaluate_and_the_pairs_are_tabled(tmp_path):
    recording = tmp_path / "static.npz"  # 15 Hz: K = 15 needs 10 + 15 + 1 frames at least
    write_simulation(recording, 40, 7, SimConfig(scenario="static"))
    out = tmp_path / "s0"
    tables = capture(recording, None, out / "static.npz")
    fold = study.Capture(out / "static.npz")
    for at in (0, 1):
        for method in ("model", "model_combined", "copy_last", "tracker"):
            got = fold.metrics(fold.methods[method][:, at], at)
            expected = [tables[f"horizon_{key}"][method][-at] for key in KEYS]
            np.testing.assert_allclose(got, expected, atol=1e-12, err_msg=method)
        pairs = fold.pairs(at)
        assert set(pairs) == set(study.SPLITS)
        assert pairs["rare"].shape == (len(CANDIDATES), len(CANDIDATES), 3)
        # a pair of one candidate is that candidate whatever the split
        same = CANDIDATES.index("copy_last")
        np.testing.assert_allclose(pairs["rare"][same, same], pairs["region"][same, same])
    table = study.table([out])
    assert "| static | k=1 |" in table and "| hindsight_region | ~1 s |" in table
    for at in (0, 1):  # the leader replayed on the rare split is the combination, nearly
        replayed = fold.margins(fold.replay(at, "rare"), at)
        ran = fold.margins(fold.methods["model_combined"][:, at], at)
        assert fold.replay(at, "region").shape == fold.methods["model"][:, at].shape
        np.testing.assert_allclose(replayed, ran, atol=0.01)
    first, second = fold.half(0), fold.half(1)
    np.testing.assert_array_equal(np.concatenate([first.scored, second.scored]), fold.scored)
    assert len(second.methods["model"]) == len(second.scored)
    assert "| warm_region | k=1 |" in study.table([out], halves=True)


def test_the_pair_left_out_is_the_best_on_the_other_recordings():
    """On ``a`` the pair (3, 3) is best, on the two others (1, 2): left out, ``a`` gets (1, 2)
    and its own margins there; in hindsight, (3, 3)."""
    n = len(CANDIDATES)

    def grid(best):
        g = np.full((n, n, 3), -0.1)
        g[best] = 0.05
        return g.tolist()

    def fold(best):
        entry = {"model": [0.0, 0.0, 0.0], "model_combined": [0.0, 0.0, 0.0], "K": 8}
        return {at: {**entry, "rare": grid(best), "region": grid(best)} for at in ("0", "1")}

    seeds = [{"a": fold((3, 3)), "b": fold((1, 2)), "c": fold((1, 2))}]
    rows = study.chosen(seeds)
    a = rows["a@0"]
    assert a["hindsight_rare"]["pair"] == [CANDIDATES[3], CANDIDATES[3]]
    assert a["left_out_rare"]["pair"] == [CANDIDATES[1], CANDIDATES[2]]
    assert a["left_out_rare"]["margins"] == [-0.1, -0.1, -0.1]
    assert rows["b@1"]["left_out_region"]["pair"] == [CANDIDATES[1], CANDIDATES[2]]


def test_a_ninth_candidate_is_replayed_and_tabled(tmp_path):
    recording = tmp_path / "static.npz"
    write_simulation(recording, 40, 7, SimConfig(scenario="static"))
    capture(recording, None, tmp_path / "s0" / "static.npz")
    fold = study.Capture(tmp_path / "s0" / "static.npz")
    z = np.load(fold.path)
    kept = study._unpacked(z["candidates"])
    for at in (0, 1):
        # a copy of a candidate already there changes no choice: ties go to the first
        copy = kept[:, at, CANDIDATES.index("tracker")][:, None]
        for split in study.SPLITS:
            np.testing.assert_array_equal(
                fold.replay(at, split, copy), fold.replay(at, split), err_msg=split
            )
    seeds = still_candidate.main([str(tmp_path / "s0"), "-o", str(tmp_path / "out")])
    row = seeds[0]["static@1"]
    assert set(row["hindsight"]) == set(study.SPLITS)
    assert {"replay_still_rare", "replay_region", "model_combined"} <= set(row)
    assert "| static | ~1 s |" in (tmp_path / "out" / "summary.md").read_text()
