"""Metrics computed by hand on tiny maps."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from lidarflow.evaluate.metrics import Counts, confusion


def test_hand_computed_counts():
    pred = np.array([[1, 1, 0], [0, 1, 0]], bool)
    true = np.array([[1, 0, 0], [1, 1, 1]], bool)
    c = confusion(pred, true)
    assert (c.tp, c.fp, c.fn) == (2, 1, 2)
    assert c.precision == 2 / 3 and c.recall == 0.5
    assert c.f1 == 2 * 2 / (2 * 2 + 1 + 2)


def test_mask_restricts_counting():
    pred = np.array([1, 1, 0, 0], bool)
    true = np.array([1, 0, 1, 0], bool)
    c = confusion(pred, true, mask=np.array([0, 1, 1, 0], bool))
    assert (c.tp, c.fp, c.fn) == (0, 1, 1)


def test_micro_average_is_sum_of_counts_not_mean_of_f1():
    a = confusion(np.array([1, 0], bool), np.array([1, 0], bool))  # f1 = 1
    b = confusion(np.array([1, 1, 1], bool), np.array([0, 0, 1], bool))  # f1 = 0.5
    total = a + b
    assert total == Counts(2, 2, 0)
    assert b.f1 == 0.5
    assert total.f1 == 4 / 6 and (a.f1 + b.f1) / 2 == 0.75


@given(arrays(bool, (5, 7), elements=st.booleans()))
def test_f1_of_a_map_with_itself_is_one(m):
    assert confusion(m, m).f1 == 1.0


@given(arrays(bool, (5, 7), elements=st.booleans()).filter(lambda m: m.any()))
def test_f1_of_the_complement_is_zero(m):
    assert confusion(~m, m).f1 == 0.0
