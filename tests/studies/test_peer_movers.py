import json

import pytest

from studies import peer_movers


def _report(copy_last_tolerant_k1: float) -> dict:
    """A held-out evaluation report as `lidarflow evaluate --horizon 2` writes it (what
    peer_movers reads of it), with copy-last, the tracker and two peer fold models."""
    scores = {
        "copy_last": [0.8, 0.5],
        "tracker": [0.7, 0.4],
        "flownet": [0.6, 0.3],
        "deeptracking": [0.2, 0.1],
    }
    entry = {f"horizon_{key}": {m: list(v) for m, v in scores.items()} for key in peer_movers.KEYS}
    entry["horizon_mover_f1_tolerant"]["copy_last"][0] = copy_last_tolerant_k1
    return {"config": {"models": {}}, "recordings": [entry]}


def _summary_row(value_1: float, value_k: float, spread: float = 0.0) -> dict:
    return {f"{key}_{k}": [v, spread] for key in peer_movers.KEYS
            for k, v in (("1", value_1), ("K", value_k))}  # fmt: skip


def _study(tmp_path, folds: dict[str, tuple[bool, float]]):
    """A peer study's evaluation/ and a movers summary for ``{fold: (moving, copy-last tolerant
    k=1 in the peer report)}``."""
    (tmp_path / "peers" / "evaluation").mkdir(parents=True)
    summary = {"folds": {}}
    for name, (moving, tolerant) in folds.items():
        (tmp_path / "peers" / "evaluation" / f"{name}.json").write_text(
            json.dumps(_report(tolerant))
        )
        copy_last = _summary_row(0.8, 0.5)
        copy_last["mover_f1_tolerant_1"] = [0.8, 0.0]
        summary["folds"][name] = {
            "moving": moving, "K": 2,
            "scores": {"model": _summary_row(0.9 if moving else 0.85, 0.6, 0.01),
                       "copy_last": copy_last, "tracker": _summary_row(0.7, 0.4)},
        }  # fmt: skip
    path = tmp_path / "summary.json"
    path.write_text(json.dumps(summary))
    return tmp_path / "peers", path


def test_the_peers_join_the_movers_rows_and_the_means_group_the_folds(tmp_path):
    peers, summary = _study(tmp_path, {"a": (False, 0.8), "b": (False, 0.8), "c": (True, 0.8)})
    results = peer_movers.main(["-o", str(tmp_path / "out"), "--peers", str(peers),
                                "--movers", str(summary)])  # fmt: skip
    fold = results["folds"]["a"]["rows"]
    assert fold["flow model (v8's recipe + carried movers)"]["f1_1"] == [0.6, 0.0]
    assert fold["DeepTracking"]["mover_f1_tolerant_K"] == [0.1, 0.0]
    assert fold["default recipe (v10's)"]["f1_1"] == [0.85, 0.01]
    mean = results["mean"]
    assert set(mean) == {"static (2)", "moving (1)", "all (3)"}
    assert mean["static (2)"]["default recipe (v10's)"]["f1_1"] == pytest.approx(0.85)
    assert mean["all (3)"]["default recipe (v10's)"]["f1_1"] == pytest.approx((0.85 * 2 + 0.9) / 3)
    table = (tmp_path / "out" / "peer_movers.md").read_text()
    assert "| a (2) | default recipe (v10's) | 0.850 ± 0.010 |" in table
    assert "| **all (3)** | DeepTracking | 0.200 |" in table


def test_a_fold_whose_baselines_differ_between_the_studies_is_refused(tmp_path):
    peers, summary = _study(tmp_path, {"a": (False, 0.8), "b": (False, 0.7)})
    with pytest.raises(SystemExit, match="b: copy-last differs"):
        peer_movers.main(["-o", str(tmp_path / "out"), "--peers", str(peers),
                          "--movers", str(summary)])  # fmt: skip


def test_a_missing_summary_or_peer_study_is_one_line(tmp_path):
    peers, summary = _study(tmp_path, {"a": (False, 0.8)})
    with pytest.raises(SystemExit, match="no such movers summary"):
        peer_movers.main(["-o", str(tmp_path / "out"), "--peers", str(peers),
                          "--movers", str(tmp_path / "nope.json")])  # fmt: skip
    with pytest.raises(SystemExit, match="no evaluation/ folder"):
        peer_movers.main(["-o", str(tmp_path / "out"), "--peers", str(tmp_path),
                          "--movers", str(summary)])  # fmt: skip
