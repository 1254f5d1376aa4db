"""The decision's shortcuts against the plain computation, to the bit: the elementwise chains
evaluated once per common value, and the pair counts of several maps from one set of mask
columns (compiled and NumPy)."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow import compiled
from lidarflow.predict import logits, offsets

pytestmark = pytest.mark.usefixtures("compile_now")


def _maps(seed: int, shape: tuple[int, ...] = (23, 17)) -> np.ndarray:
    """A probability map as a model gives one: one value on most cells, a few others."""
    rng = np.random.default_rng(seed)
    p = np.full(shape, 0.00038806, np.float32)
    some = rng.random(shape) < 0.2
    p[some] = rng.random(np.count_nonzero(some)).astype(np.float32)
    return p


@pytest.mark.parametrize(
    "p",
    [
        _maps(0),
        _maps(1, (5,)),
        np.linspace(0.0, 1.0, 50, dtype=np.float32),  # the first cell unlike any other
        np.full((4, 4), 0.7, np.float32),  # every cell alike
        np.array([np.nan, 0.5, np.nan, 0.2]),  # the first cell NaN (equal to none)
        np.zeros((0, 3), np.float32),
        np.array([[1e-30, 1.0 - 1e-13], [0.0, 1.0]]),  # clipped at both ends
    ],
)
def test_calibrated_logit_and_sigmoid_are_the_plain_chains(p):
    q = np.clip(np.asarray(p, np.float64), 1e-12, 1.0 - 1e-12)
    logit = np.clip(np.log(q) - np.log1p(-q), -logits.LOGIT_LIMIT, logits.LOGIT_LIMIT)
    got = logits.calibrated_logit(p)
    assert got.shape == logit.shape and got.dtype == np.float64
    np.testing.assert_array_equal(got, logit)
    shifted = logit + 0.3 + (1.2 - 0.3) * (np.asarray(p) > 0.5)
    decided = logits.sigmoid32(shifted)
    assert decided.dtype == np.float32
    np.testing.assert_array_equal(decided, (1.0 / (1.0 + np.exp(-shifted))).astype(np.float32))
    chain = (1.0 / (1.0 + np.exp(-(logit - 0.6)))).astype(np.float32)
    np.testing.assert_array_max_ulp(logits.decided_probability(p, -0.6), chain, maxulp=1)


def test_shifted_probability_is_the_chain_within_a_rounding():
    rng = np.random.default_rng(7)
    p = np.concatenate(
        [
            rng.random(4000, np.float32),
            np.float32([0.0, 1.0, 1e-30, 1e-7, 0.5, 1.0 - 6e-8, 0.99999994]),
            rng.random(100, np.float32) * np.float32(1e-6),  # beyond the logit's limits
        ]
    )
    shift = rng.uniform(-20.0, 20.0, p.shape)
    shift[::5] = 0.0
    chain = logits.sigmoid32(logits.calibrated_logit(p) + shift)
    got = logits.shifted_probability(p, shift)
    assert got.dtype == np.float32
    np.testing.assert_array_max_ulp(got, chain, maxulp=1)
    # most cells to the bit: the rounding differs only where float64 sits on a float32 tie
    assert np.count_nonzero(got != chain) <= p.size // 1000
    np.testing.assert_array_max_ulp(
        logits.shifted_probability(p, 1.5), logits.sigmoid32(logits.calibrated_logit(p) + 1.5)
    )
    for far in (-1e4, -800.0, 800.0, 1e4):  # saturated as the chain, no overflow
        with np.errstate(over="raise"):
            got = logits.shifted_probability(p, far)
        with np.errstate(over="ignore"):  # the chain's exp(1e4) overflows, to the right 0
            chain = logits.sigmoid32(logits.calibrated_logit(p) + far)
        np.testing.assert_array_equal(got, chain)


def test_once_per_common_value_evaluates_the_rest_on_their_own():
    x = np.array([2.0, 2.0, 3.0, 2.0, 5.0])
    seen = []

    def square(v: np.ndarray) -> np.ndarray:
        seen.append(v.copy())
        return v * v

    np.testing.assert_array_equal(logits.once_per_common_value(square, x), x * x)
    assert [s.tolist() for s in seen] == [[2.0], [3.0, 5.0]]
    seen.clear()  # most elements unlike the first: all at once
    np.testing.assert_array_equal(logits.once_per_common_value(square, x[2:]), x[2:] ** 2)
    assert [s.tolist() for s in seen] == [x[2:].tolist()]


def _decision_inputs(seed: int, cells: int, maps: int):
    rng = np.random.default_rng(seed)
    needs, moveds = [], []
    a, b = np.linspace(-4.8, 4.2, 31), np.linspace(-0.6, 3.0, 13)
    for m in range(maps):
        moved = rng.choice([0.0, 1.0, 0.25, 0.7], cells) if m else np.clip(
            rng.normal(0.5, 0.6, cells), 0.0, 1.0)  # fmt: skip
        need = rng.normal(0.0, 2.5, cells)
        need[: cells // 4] = (moved * a[4] + (1.0 - moved) * b[7])[: cells // 4]  # on a pair
        need[cells // 4 : cells // 3] = b[-1]
        needs.append(need)
        moveds.append(moved)
    target, changed = rng.random(cells) < 0.3, rng.random(cells) < 0.2
    return needs, moveds, target, changed, a, b


@pytest.mark.parametrize("numba", [True, False])
@pytest.mark.parametrize(("cells", "maps"), [(0, 2), (1, 1), (600, 2), (3000, 3)])
def test_pair_counts_each_are_each_maps_pair_counts(cells, maps, numba, monkeypatch):
    if numba and not compiled.available():
        pytest.skip("numba is not installed")
    if not numba:
        monkeypatch.setattr(compiled, "numba", None)
    needs, moveds, target, changed, a, b = _decision_inputs(cells + maps, cells, maps)
    got = offsets.pair_counts_each(needs, moveds, target, [None, changed], a, b)
    assert len(got) == maps
    for counted, need, moved in zip(got, needs, moveds, strict=True):
        for (tp, predicted, positives), m in zip(
            counted, [np.ones(cells, bool), changed], strict=True
        ):
            want = offsets.pair_counts(need[m], moved[m], target[m], a, b)
            np.testing.assert_array_equal(tp, want[0])
            np.testing.assert_array_equal(predicted, want[1])
            assert positives == want[2]


def test_pair_counts_each_wants_a_moved_map_per_need():
    with pytest.raises(ValueError, match="as many needs as moved maps"):
        offsets.pair_counts_each([np.zeros(3)], [], np.zeros(3, bool), [None], [0.0], [0.0])
