"""The one evaluation pass: each recording is streamed once, for the main table and the horizon
tables alike, and the report says which frames each scores."""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Callable

import numpy as np
import pytest

from lidarflow.baselines import ConstantVelocity, CopyLast, Method, TemporalAverage
from lidarflow.data.recording import Recording
from lidarflow.evaluate.runner import evaluate_maps, horizon_scores
from lidarflow.scan import GridSpec
from lidarflow.sim import SimConfig, write_simulation
from tests.test_cli import run


def _walker(n: int = 24) -> np.ndarray:
    maps = np.zeros((n, 12, 16), np.float32)
    maps[:, 0, :] = 1  # a wall
    for t in range(n):
        maps[t, 5 + t % 3, 2 + t % 12] = 1  # something that moves
    return maps


@pytest.mark.slow
@pytest.mark.parametrize("report", [False, True])
def test_evaluate_horizon_streams_each_recording_once(tmp_path, capsys, monkeypatch, report):
    rec = tmp_path / "drive.npz"
    write_simulation(rec, 30, 8, SimConfig(scenario="dynamic"))
    frames: Counter[int] = Counter()  # frame -> times rasterized
    maps = Recording.maps

    def counted(
        self: Recording, grid: GridSpec | None = None, start: int = 0, stop: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        occupancy, visibility = maps(self, grid, start, stop)
        frames.update(range(start, start + len(occupancy)))
        return occupancy, visibility

    resets: Counter[str] = Counter()  # method -> passes begun

    def counting(was: Callable[[Method], None]) -> Callable[[Method], None]:
        def reset(self: Method) -> None:
            resets[self.name] += 1
            was(self)

        return reset

    for method in (CopyLast, TemporalAverage, ConstantVelocity):
        monkeypatch.setattr(method, "reset", counting(method.reset))
    monkeypatch.setattr(Recording, "maps", counted)
    out = tmp_path / "e.json"
    folder = ["--report", str(tmp_path / "report")] if report else []
    args = ["evaluate", str(rec), "--baselines-only", "--warmup", "5", "--horizon", "4"]
    code, text, err = run([*args, *folder, "-o", str(out)], capsys)
    assert code == 0, err
    entry = json.loads(out.read_text())["recordings"][0]
    assert "horizon_f1" in entry and entry["frames_evaluated"] == 30 - 5 - 1
    # One pass: every frame rasterized once, every method reset once, for both tables.
    assert sorted(frames) == list(range(30)) and set(frames.values()) == {1}
    assert resets == {"copy_last": 1, "temporal_average": 1, "constant_velocity": 1}
    # The tables say which frames they score: the horizon's k = 1 is not the main table.
    assert entry["horizon_frames_evaluated"] == 30 - 5 - 4
    assert "horizon tables: 21 frames at every k" in text and "main table scores 24" in text


def test_the_horizon_k1_column_is_the_main_table_on_the_frames_it_scores():
    maps, horizon, warmup = _walker(), 3, 4
    methods = [CopyLast(), TemporalAverage(), ConstantVelocity()]
    ahead = horizon_scores(maps, maps, methods, horizon, warmup)["f1"]
    # the horizon scores t = warmup .. n - 1 - K; the main table of the maps up to t + 1 so too
    cut = maps[: len(maps) - horizon + 1]
    main = evaluate_maps(cut, cut, methods, warmup)
    for name, scorer in main.items():
        assert scorer.frames == len(maps) - horizon - warmup
        assert ahead[name][0] == pytest.approx(scorer.summary()["f1"], abs=1e-12)
    # on the whole recording the main table scores K - 1 more frames, and here differs
    whole = evaluate_maps(maps, maps, methods, warmup)
    assert whole["copy_last"].frames == len(maps) - 1 - warmup
