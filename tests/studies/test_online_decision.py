"""The studies of the online decision: per-frame counts and rules replayed, one long stream."""

import numpy as np

from studies import long_stream, online_rules


def test_online_rules_then_long_stream(sim_recordings, tmp_path):
    counts = tmp_path / "rules"
    argv = ["-o", str(counts), "--model", "bundled", "--recordings", *map(str, sim_recordings)]
    rules = online_rules.main(argv)

    assert len(rules) == 3 * 2 * 4  # grid ranges x maps x rules and constants
    for row in rules:
        assert set(row["recordings"]) == {"static", "dynamic"}
        assert 0 <= row["wins"] <= 2
        for scores in row["recordings"].values():
            assert 0.0 <= scores["f1"] <= 1.0 and -1.0 <= scores["margin"] <= 1.0
    cached = np.load(counts / "dynamic.npz")
    frames = len(cached["pairs"])
    assert cached["pairs"].shape == (frames, 31, 13, 2, 3)
    assert cached["baselines"].shape == (frames, 3, 2, 3)
    # true positives never exceed the predicted cells nor the positives
    tp, predicted, positives = np.moveaxis(cached["pairs"], -1, 0)
    assert (tp <= predicted).all() and (tp <= positives).all()

    out = long_stream.main(["-o", str(tmp_path / "long"), "--counts", str(counts),
                            "--histories", "1.0", "0.98"])  # fmt: skip
    assert set(out["histories"]) == {"1.0", "0.98"}
    assert len(out["orders"]) == long_stream.ORDERS
    row = out["histories"]["1.0"]
    assert set(row["alone"]) == {"static", "dynamic"} and len(row["stream"]) == long_stream.ORDERS
    assert "| 0.98 |" in (tmp_path / "long" / "long_stream.md").read_text()
