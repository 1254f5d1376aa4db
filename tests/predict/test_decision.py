"""The decision offsets chosen online: counts exact, choice causal, the model unchanged before."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.baselines import ConstantVelocity, CopyLast, TemporalAverage
from lidarflow.evaluate.metrics import THRESHOLD, confusion
from lidarflow.predict.decision import OnlineDecision, OnlineDecisionConfig
from lidarflow.predict.offsets import (
    counts,
    counts_all_and_changed,
    pair_counts,
    pair_counts_within,
)

LOGIT = float(np.log(THRESHOLD / (1 - THRESHOLD)))
GRID = np.array([-0.6, 0.0, 0.3, 1.2, 2.7])


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return (1.0 / (1.0 + np.exp(-x))).astype(np.float32)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 60))
def test_pair_counts_equal_counting_each_pair(seed, cells):
    rng = np.random.default_rng(seed)
    need = rng.normal(0.5, 1.5, cells)
    need[: cells // 4] = 0.3  # exactly on an offset of the grid
    moved = rng.choice([0.0, 1.0, 0.25, 0.7], cells)
    target = rng.random(cells) < 0.4
    tp, predicted, positives = pair_counts(need, moved, target, GRID, GRID[::-1])
    assert positives == target.sum()
    for i, a in enumerate(GRID):
        for j, b in enumerate(GRID[::-1]):
            hit = moved * a + (1 - moved) * b >= need
            assert tp[i, j] == np.count_nonzero(hit & target)
            assert predicted[i, j] == np.count_nonzero(hit)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 60))
def test_pair_counts_within_masks_are_pair_counts_on_each(seed, cells):
    rng = np.random.default_rng(seed)
    need = rng.normal(0.5, 1.5, cells)
    need[: cells // 4] = 0.3
    moved = rng.choice([0.0, 1.0, 0.25, 0.7], cells)
    target = rng.random(cells) < 0.4
    mask = rng.random(cells) < 0.5
    got = pair_counts_within(need, moved, target, [None, mask], GRID, GRID[::-1])
    for (tp, predicted, positives), m in zip(got, [np.ones(cells, bool), mask], strict=True):
        want = pair_counts(need[m], moved[m], target[m], GRID, GRID[::-1])
        assert np.array_equal(tp, want[0]) and np.array_equal(predicted, want[1])
        assert positives == want[2]


def test_pair_counts_within_many_fractional_cells() -> None:
    """Enough cells that the pairs' hits are summed in several slices (one thread)."""
    rng = np.random.default_rng(5)
    need = rng.normal(0.5, 1.5, 5000)
    moved = rng.random(5000)
    target, mask = rng.random(5000) < 0.4, rng.random(5000) < 0.3
    got = pair_counts_within(need, moved, target, [None, mask], GRID, GRID[::-1])
    for (tp, predicted, positives), m in zip(got, [np.ones(5000, bool), mask], strict=True):
        want = pair_counts(need[m], moved[m], target[m], GRID, GRID[::-1])
        assert np.array_equal(tp, want[0]) and np.array_equal(predicted, want[1])
        assert positives == want[2]


def test_counts_all_and_changed_are_counts() -> None:
    rng = np.random.default_rng(7)
    target, changed = rng.random((30, 20)) < 0.3, rng.random((30, 20)) < 0.2
    predictions = [rng.random((30, 20)) < q for q in (0.1, 0.5, 0.9)]
    table = counts_all_and_changed(predictions, target, changed)
    for k, mask in enumerate((np.ones_like(target), changed)):
        for j, p in enumerate(predictions):
            assert table[k, j].tolist() == list(counts(p, target, mask))


def _stream(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random flickering maps, a model logit and a moved map, frame by frame."""
    rng = np.random.default_rng(seed)
    base = rng.random((12, 10)) < 0.3
    maps = np.array([base ^ (rng.random(base.shape) < 0.1) for _ in range(n)])
    logits = rng.normal(-1.0, 2.0, (n, *base.shape))
    moved = np.clip(maps.astype(float) + rng.choice([0.0, 0.5], (n, *base.shape)), 0, 1)
    return maps, logits, moved


@pytest.mark.parametrize(
    ("gain", "window", "history"), [(None, 5, 1.0), (2.5, 2, 1.0), (2.5, 5, 0.9)]
)
def test_margins_look_ahead_from_the_decisions_made_and_the_baselines(gain, window, history):
    maps, logits, moved = _stream(12, seed=3)
    pairs = [(a, b) for a in (0.0, 1.5) for b in (-0.3, 0.9)]
    config = OnlineDecisionConfig(
        occupied_offsets=(0.0, 1.5), free_offsets=(-0.3, 0.9), decay=1, lookahead=7, min_frames=99,
        ta_window=window, ta_threshold=0.5, history_decay=history,
    )  # fmt: skip
    decision = OnlineDecision(0.6, config, gain)  # min_frames: it decides with 0.6
    baselines = [CopyLast(), TemporalAverage(window, 0.5), ConstantVelocity()]
    visibility = np.ones_like(maps[0])
    # The candidates: each pair on the moved map, and (with a gain) on the last map unmoved,
    # where the head's logit g * moved + r becomes g * last + r. Counts: [all, changed cells] x
    # (tp, fp, fn); the pairs' summed (decay 1), the decisions made and the baselines' weighing
    # the past by ``history`` per frame.
    candidates = [(False, p) for p in pairs] + [(True, p) for p in pairs if gain is not None]
    per_pair = {c: np.zeros((2, 3)) for c in candidates}
    made, per_baseline = np.zeros((2, 3)), np.zeros((len(baselines), 2, 3))
    for t in range(len(maps)):
        own = logits[t] + 0.6  # the logit decided with the model's own offset
        decision.update(_sigmoid(logits[t]), maps[t], visibility, moved[t])
        if t > 0:  # frames 1..t scored: the decisions made, plus 7 frames of each pair's mean
            expected = [_margin(made, per_pair[c], 7 / t, per_baseline) for c in candidates]
            assert np.allclose(decision.margins(), np.reshape(expected, (-1, 2, 2)))
        if t + 1 < len(maps):
            target, changed = maps[t + 1], maps[t] != maps[t + 1]
            last = maps[t].astype(float)
            for (unmoved, (a, b)), counts in per_pair.items():
                split = last if unmoved else moved[t]
                logit = logits[t] + (gain * (last - moved[t]) if unmoved else 0.0)
                counts += _counts(logit + b + (a - b) * split >= LOGIT, target, changed)
            made = history * made + _counts(own >= LOGIT, target, changed)
            for j, m in enumerate(baselines):
                p = m.update(maps[t], visibility) >= THRESHOLD
                per_baseline[j] = history * per_baseline[j] + _counts(p, target, changed)


def _counts(predicted: np.ndarray, target: np.ndarray, changed: np.ndarray) -> np.ndarray:
    both = (confusion(predicted, target), confusion(predicted, target, changed))
    return np.array([[c.tp, c.fp, c.fn] for c in both], float)


def _f1(tp: float, fp: float, fn: float) -> float:
    return 2 * tp / (2 * tp + fp + fn) if 2 * tp + fp + fn else 1.0


def _margin(made: np.ndarray, pair: np.ndarray, h: float, baselines: np.ndarray) -> float:
    return min(_f1(*(made[k] + h * pair[k])) - max(_f1(*b[k]) for b in baselines) for k in (0, 1))


def test_the_model_is_unchanged_until_enough_frames_are_scored():
    maps, logits, moved = _stream(8, seed=1)
    decision = OnlineDecision(0.65, OnlineDecisionConfig(min_frames=5))
    for t in range(5):  # frame t scores the prediction made at t - 1
        out = decision.update(_sigmoid(logits[t]), maps[t], np.ones_like(maps[t]), moved[t])
        assert decision.offsets == (0.65, 0.65)
        assert np.allclose(out, _sigmoid(logits[t] + 0.65), atol=1e-6)
    decision.update(_sigmoid(logits[5]), maps[5], np.ones_like(maps[5]), moved[5])
    assert decision.offsets != (0.65, 0.65)  # the grid does not hold the model's own pair


def test_it_moves_to_the_offsets_that_would_have_found_the_cells():
    # A model whose logit on the occupied cells is just below the threshold: at its own offset
    # it predicts nothing; the stream shows an occupied-cell offset of 0.6 would find them all.
    pattern = np.zeros((10, 10), bool)
    pattern[2:5, 3:8] = True
    probability = _sigmoid(np.where(pattern, LOGIT - 0.5, -6.0))
    decision = OnlineDecision(0.0, OnlineDecisionConfig(min_frames=3))
    for t in range(6):
        out = decision.update(probability, pattern, np.ones_like(pattern), pattern.astype(float))
        if t < 3:
            assert not (out >= THRESHOLD).any()
    assert np.array_equal(out >= THRESHOLD, pattern)
    assert decision.offsets[0] >= 0.5


def test_where_the_flow_moves_what_stays_the_unmoved_map_is_chosen():
    # A static pattern that the flow moves one cell right every frame: on the moved map no pair
    # finds the cells (the head's logit is high where the flow put them), on the unmoved map
    # the same head (g * last + r) predicts the pattern exactly. Without the gain the decision
    # cannot tell, and keeps to the moved map.
    pattern = np.zeros((10, 12), bool)
    pattern[2:6, 3:7] = True
    moved = np.roll(pattern, 1, axis=1).astype(float)
    gain, residual = 4.0, -3.0
    probability = _sigmoid(gain * moved + residual)
    visibility = np.ones_like(pattern)
    for given_gain in (gain, None):
        decision = OnlineDecision(0.0, OnlineDecisionConfig(min_frames=3), given_gain)
        for _ in range(6):
            out = decision.update(probability, pattern, visibility, moved)
        assert decision.unmoved == (given_gain is not None)
        assert np.array_equal(out >= THRESHOLD, pattern) == (given_gain is not None)
    unmoved_off = OnlineDecisionConfig(min_frames=3, unmoved=False)
    decision = OnlineDecision(0.0, unmoved_off, gain)
    for _ in range(6):
        decision.update(probability, pattern, visibility, moved)
    assert not decision.unmoved and decision.margins().shape[0] == 1


@pytest.mark.parametrize("gain", [4.0, None])
def test_apply_decides_as_the_update_with_the_same_choice(gain):
    # A roll-out's step re-decides with the choice the last update made: the same map, within
    # a float32 rounding, on fractional maps (a fed-back probability) as on 0/1 ones.
    rng = np.random.default_rng(3)
    decision = OnlineDecision(0.3, OnlineDecisionConfig(min_frames=2), gain)
    for t in range(8):
        probability = rng.random((12, 14), np.float32)
        occupancy = rng.random((12, 14)) < 0.3
        moved = np.roll(occupancy, t % 3, axis=1).astype(np.float32)
        decided = decision.update(probability, occupancy, np.ones_like(occupancy), moved)
        np.testing.assert_array_max_ulp(
            decision.apply(probability, occupancy, moved), decided, maxulp=1
        )
        fed = rng.random((12, 14), np.float32)  # a fed-back probability as the last map
        logits, maps = decision._candidates(probability, fed, moved)
        for unmoved in (False, True) if gain else (False,):  # either choice, made or not
            decision.unmoved = unmoved
            np.testing.assert_array_max_ulp(
                decision.apply(probability, fed, moved), decision._decided(logits, maps), maxulp=1
            )


def test_reset_forgets_the_stream_and_a_new_shape_needs_one():
    maps, logits, moved = _stream(14, seed=2)
    decision = OnlineDecision(0.6, OnlineDecisionConfig(min_frames=2))
    for t in range(14):
        decision.update(_sigmoid(logits[t]), maps[t], np.ones_like(maps[t]), moved[t])
    with pytest.raises(ValueError, match="shape changed"):
        decision.update(
            np.zeros((5, 5), np.float32), np.zeros((5, 5)), np.ones((5, 5)), np.zeros((5, 5))
        )
    decision.reset()
    assert decision.offsets == (0.6, 0.6) and not decision.unmoved
    assert np.isinf(decision.margins()).all()
    decision.update(
        np.zeros((5, 5), np.float32), np.zeros((5, 5)), np.ones((5, 5)), np.zeros((5, 5))
    )


def test_bad_configurations_are_refused():
    with pytest.raises(ValueError, match="decay"):
        OnlineDecisionConfig(decay=0.0)
    with pytest.raises(ValueError, match="offset"):
        OnlineDecisionConfig(free_offsets=())
    with pytest.raises(ValueError, match="lookahead"):
        OnlineDecisionConfig(lookahead=0)
    with pytest.raises(ValueError, match="window"):
        OnlineDecisionConfig(ta_window=0)
    with pytest.raises(ValueError, match="history_decay"):
        OnlineDecisionConfig(history_decay=1.5)


@pytest.mark.slow
def test_a_model_scored_online_equals_its_own_offsets_until_it_chooses(tmp_path, sample_recording):
    from lidarflow.evaluate.model_method import ModelMethod
    from lidarflow.evaluate.runner import evaluate_maps
    from lidarflow.models.presets import resolve_model
    from lidarflow.scan import GridSpec
    from tests.conftest import make_model_dir

    # Untrained, the head is copy-last (logit 2.2 on occupied cells): an occupied-cell offset of
    # -3 predicts nothing, which the stream shows at once.
    kwargs = {"occupancy_head": True, "decision_offset": -3.0}
    net, card = resolve_model(make_model_dir(tmp_path / "m", seed=4, **kwargs))
    own = card["decision"]
    occupancy, visibility = sample_recording.slice(0, 40).maps(GridSpec())
    late = OnlineDecisionConfig(min_frames=100)
    soon = OnlineDecisionConfig(min_frames=1)
    methods = [
        ModelMethod("fixed", net, decision=own),
        ModelMethod("late", net, online=late, decision=own),
        ModelMethod("soon", net, online=soon, decision=own),
    ]
    scores = evaluate_maps(occupancy, visibility, methods)
    assert scores["late"].counts == scores["fixed"].counts
    assert scores["late"].changed == scores["fixed"].changed
    assert scores["fixed"].counts.tp == 0
    assert methods[2].online.offsets[0] > -3.0
    assert scores["soon"].counts.f1 > 0.9


def test_a_model_without_an_occupancy_head_is_refused(random_flownet_dir):
    from lidarflow.errors import EvaluateError
    from lidarflow.evaluate.model_method import ModelMethod
    from lidarflow.models.presets import resolve_model

    net, _ = resolve_model(random_flownet_dir)
    with pytest.raises(EvaluateError, match="occupancy head"):
        ModelMethod("m", net, online=OnlineDecisionConfig())


@pytest.mark.slow
def test_evaluate_online_decision_on_the_command_line(tmp_path, capsys, random_flownet_dir):
    import json

    from lidarflow.data import read_bag, sample_bag_path
    from tests.conftest import make_model_dir
    from tests.test_cli import run

    model = make_model_dir(tmp_path / "head", occupancy_head=True, decision_offset=-3.0)
    out = tmp_path / "e.json"
    part = read_bag(sample_bag_path()).slice(0, 80).save(tmp_path / "part.npz")
    argv = ["evaluate", str(part), "-m", str(model), "--online-decision"]
    code, text, err = run([*argv, "--json", str(out), "--ta-window", "8"], capsys)
    assert code == 0, err
    report = json.loads(out.read_text())
    fixed, online = report["overall"]["head"], report["overall"]["head_online"]
    assert fixed["f1"] == 0.0 and online["f1"] > 0.9 and "head_online" in text
    # It measures itself against the temporal average the report scores.
    decided = report["config"]["online_decision"]
    assert decided["decay"] == 0.98 and decided["ta_window"] == 8
    code, _, err = run(
        ["evaluate", str(part), "-m", str(random_flownet_dir), "--online-decision"], capsys
    )
    assert code == 1 and "occupancy head" in err and len(err.strip().splitlines()) == 1


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_the_numpy_moved_map_equals_the_models_warp(seed):
    import torch

    from lidarflow.ops.warp import warp
    from lidarflow.predict.decision import moved_last_map

    rng = np.random.default_rng(seed)
    occupancy = rng.random((7, 9)) < 0.4
    flow = rng.normal(0, 2.5, (2, 7, 9))
    flow[:, :2] = np.round(flow[:, :2])  # whole cells too, and some beyond the border
    expected = warp(
        torch.from_numpy(occupancy.astype(np.float64))[None, None], torch.from_numpy(flow)[None]
    ).clamp(0, 1)[0, 0]
    assert np.allclose(moved_last_map(occupancy, flow), expected.numpy(), atol=1e-9)
    assert np.array_equal(moved_last_map(occupancy, None), occupancy.astype(float))


def test_predict_chooses_online_unless_told_fixed(tmp_path, capsys):
    from lidarflow.data import read_bag, sample_bag_path
    from tests.conftest import make_model_dir
    from tests.outputs.test_rosout import read_all
    from tests.test_cli import run

    kwargs = {"occupancy_head": True, "decision_offset": -3.0, "online_decision": True}
    model = make_model_dir(tmp_path / "head", **kwargs)
    rec = tmp_path / "short.npz"
    read_bag(sample_bag_path()).slice(0, 25).save(rec)
    peaks = {}
    for flags in ([], ["--fixed-decision"]):
        out = tmp_path / f"out{len(flags)}.mcap"
        code, _, err = run(["predict", str(rec), "-o", str(out), "-m", str(model), *flags], capsys)
        assert code == 0, err
        last = read_all(out)["/lidarflow/decided"][-1]
        peaks[len(flags)] = int(np.max(last.data))  # 100: decided occupied
    # Online, the occupied cells are decided occupied; fixed at -3 none is.
    assert peaks[0] == 100 and peaks[1] == 0
