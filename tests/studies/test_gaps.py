"""The studies of gaps in a stream: restart or carry, pose jumps, a rate that drops."""

import json

from studies import gap_restart, pose_jumps, rate_drop

PARTS = {"early_all", "early_changed", "late_all", "late_changed"}


def _f1s(by_method):
    return [f1 for parts in by_method.values() for f1 in parts.values()]


def test_gap_restart_scores_after_the_gap_both_ways(sim_recordings, tmp_path):
    argv = ["-o", str(tmp_path), "--recordings", *map(str, sim_recordings), "--gaps", "3",
            "--places", "1", "--before", "8", "--after", "6", "--warmup", "3"]  # fmt: skip
    results = gap_restart.main(argv)

    assert set(results["overall"]) == {"k3_carry", "k3_restart"}
    carried = results["overall"]["k3_carry"]
    assert {"copy_last", "temporal_average", "constant_velocity", "bundled"} <= set(carried)
    assert set(carried["bundled"]) == PARTS
    assert all(0.0 <= f1 <= 1.0 for f1 in _f1s(carried))
    assert set(results["recordings"]) == {"static", "dynamic"}
    written = json.loads((tmp_path / "gap_restart.json").read_text())
    assert written["config"]["gaps"] == [3] and written["results"] == results

    spliced = gap_restart.main([*argv, "--splice"])
    assert set(spliced["overall"]) == {"splice_carry", "splice_restart"}


def test_pose_jumps_scores_the_frames_after_a_jump(sim_recordings, tmp_path):
    dynamic = sim_recordings[1]
    argv = ["-o", str(tmp_path), str(dynamic), "--places", "1", "--before", "10",
            "--after", "8", "--early", "3"]  # fmt: skip
    results = pose_jumps.main(argv)

    assert {"none", "reset", "relocalise", "dynamic/reset"} <= set(results)
    assert set(results["reset"]["bundled"]) == PARTS
    # the baselines take no poses: a jump in them changes nothing of theirs
    assert results["reset"]["copy_last"] == results["none"]["copy_last"]


def test_rate_drop_scores_a_slower_rate_and_dropped_scans(sim_recordings, tmp_path):
    dynamic = sim_recordings[1]
    argv = ["-o", str(tmp_path), str(dynamic), "--places", "1", "--before", "8",
            "--after", "6", "--every", "2", "--early", "3", "--drops", "0.3"]  # fmt: skip
    results = rate_drop.main(argv)

    assert {"every_2", "drops_0.3", "dynamic/every_2"} <= set(results)
    assert set(results["every_2"]["bundled"]) == PARTS
    dropped = {p.rsplit("_", 1)[0] for p in results["drops_0.3"]["bundled"]}
    assert dropped <= {"after_one", "after_two", "after_none"} and "after_one" in dropped
