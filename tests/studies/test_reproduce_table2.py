import json

from studies import reproduce_table2


def test_table2_trains_the_three_rows_and_scores_them_beside_the_baselines(tiny_training, tmp_path):
    argv = ["-o", str(tmp_path), "--platforms", "dynamic", "--train-frames", "24",
            "--val-frames", "16", "--epochs", "1", "--batch-size", "2", "--no-report",
            "--set", *[k for k in tiny_training if not k.startswith("optim.")]]  # fmt: skip
    table = reproduce_table2.main(argv)

    overall = table["sim dynamic"]
    baselines = ("copy_last", "temporal_average", "constant_velocity", "tracker")
    for row in (*reproduce_table2.ROWS, *baselines):
        assert 0.0 <= overall[row]["f1"] <= 1.0
    # simulated validation data has ground-truth flow: the flow models get an end-point error
    assert overall["lidar_flownet"]["epe"] is not None
    run = json.loads(
        (tmp_path / "dynamic" / "lidar_flownet_no_gaussian" / "config.json").read_text()
    )
    assert run["schedule"]["gaussian"] is False
    lines = (tmp_path / "table2.md").read_text().splitlines()
    assert sum(line.startswith("| sim dynamic |") for line in lines) == 3 + len(baselines)
