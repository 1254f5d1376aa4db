"""The compiled kernels against their NumPy references, to the bit (integers: exactly)."""

from __future__ import annotations

import json
import multiprocessing
import os
import subprocess
import sys

import numpy as np
import pytest

from lidarflow import compiled, geometry
from lidarflow.predict import offsets

pytestmark = [
    pytest.mark.skipif(not compiled.available(), reason="numba is not installed"),
    pytest.mark.usefixtures("compile_now"),
]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("motion", [(0.3, -0.2, 0.05), (40.0, 0.0, 1.0), (0.0, 0.0, 0.0)])
def test_gather_is_the_numpy_reference_to_the_bit(dtype, motion):
    rng = np.random.default_rng(3)
    sampler = geometry.Sampler(*geometry.rigid_positions(np.array(motion), 37, 23))
    maps = rng.random((3, 37, 23)).astype(dtype)
    weight = sampler._weight.astype(dtype)
    reference = geometry._gathered_numpy(maps.reshape(3, -1), sampler._index, weight)
    got = sampler(maps)
    assert got.dtype == dtype
    np.testing.assert_array_equal(got, reference.reshape(maps.shape))


def test_corners_are_the_numpy_reference_to_the_bit(monkeypatch):
    rng = np.random.default_rng(4)
    # inside, on the edges and whole cells, beyond them, and far beyond
    x = np.concatenate([rng.uniform(-3, 26, 400), np.arange(-2.0, 25.0), [-0.0, 22.0, 1e9]])
    y = np.concatenate([rng.uniform(-3, 40, 400), np.arange(-2.0, 25.0), [-1e9, 36.0, -0.0]])
    got = geometry._corners(x, y, 37, 23)
    monkeypatch.setattr(compiled, "numba", None)
    expected = geometry._corners(x, y, 37, 23)
    for g, e in zip(got, expected, strict=True):
        assert g.dtype == e.dtype
        np.testing.assert_array_equal(g, e)


def test_gather_reads_a_strided_map_as_numpy_does():
    maps = np.arange(2 * 6 * 8, dtype=np.float64).reshape(2, 6, 8)[:, :, ::2]  # not contiguous
    sampler = geometry.Sampler(*geometry.rigid_positions(np.array([0.5, 0.25, 0.1]), 6, 4))
    reference = geometry._gathered_numpy(
        np.ascontiguousarray(maps).reshape(2, -1), sampler._index, sampler._weight
    )
    np.testing.assert_array_equal(sampler(maps), reference.reshape(maps.shape))


@pytest.mark.parametrize("cells", [0, 1, 500, 4000])
def test_pair_counts_are_the_numpy_references(cells, monkeypatch):
    rng = np.random.default_rng(cells)
    moved = np.clip(rng.normal(0.5, 0.6, cells), 0.0, 1.0)
    need = rng.normal(0.0, 2.0, cells)
    a, b = np.linspace(-3, 3, 13), np.linspace(-2, 4, 31)
    # cells exactly on a pair's threshold, where another order of operations would flip them
    need[: cells // 3] = (moved * a[4] + (1.0 - moved) * b[7])[: cells // 3]
    need[cells // 3 : cells // 2] = a[5]
    need[cells // 2 : cells // 2 + cells // 10] = a[-1]  # the largest offsets, and beyond
    need[cells // 2 + cells // 10 : cells // 2 + cells // 5] = b[-1]
    need[cells // 2 + cells // 5 : cells // 2 + cells // 4] = np.nextafter(b[-1], np.inf)
    target, changed = rng.random(cells) < 0.3, rng.random(cells) < 0.2
    got = offsets.pair_counts_within(need, moved, target, [None, changed], a, b)
    monkeypatch.setattr(compiled, "numba", None)
    expected = offsets.pair_counts_within(need, moved, target, [None, changed], a, b)
    single = [offsets.pair_counts(need[m], moved[m], target[m], a, b)
              for m in (np.ones(cells, bool), changed)]  # fmt: skip
    for g, e, s in zip(got, expected, single, strict=True):
        for x, y, z in zip(g, e, s, strict=True):
            np.testing.assert_array_equal(x, y)
            np.testing.assert_array_equal(x, z)


@compiled.kernel
def _doubled(x: np.ndarray) -> np.ndarray:
    out = np.empty_like(x)
    for i in range(len(x)):
        out[i] = 2.0 * x[i]
    return out


@compiled.kernel
def _uncompilable(x: np.ndarray) -> object:
    return object()  # a Python object: not in what numba compiles


@compiled.kernel
def _halved(x: np.ndarray) -> np.ndarray:
    return x / 2.0


def _ready_in_a_forked_child() -> tuple[bool, bool]:
    x = np.arange(4.0)
    first = compiled.ready(_halved, x)  # one the parent never asked for
    compiled.wait()
    return first, compiled.ready(_halved, x)


def test_a_kernel_compiles_in_the_background_while_its_caller_takes_the_reference(monkeypatch):
    monkeypatch.setattr(compiled, "background", True)
    monkeypatch.setattr(compiled, "_compiled", set())
    monkeypatch.setattr(compiled, "_asked", set())
    x = np.arange(3.0)
    assert not compiled.ready(_doubled, x)  # asked: compiling starts, the reference serves
    assert not compiled.ready(_uncompilable, x)
    compiled.wait()
    assert compiled.ready(_doubled, x)
    np.testing.assert_array_equal(_doubled(x), 2.0 * x)
    assert not compiled.ready(_uncompilable, x)  # it never will: the reference stays
    assert "_uncompilable" in compiled.failed
    # a fork waits for the compiling under way; the child compiles on a thread of its own
    monkeypatch.setattr(compiled, "_asked", compiled._asked - {_doubled})
    monkeypatch.setattr(compiled, "_compiled", set())
    assert not compiled.ready(_doubled, x)
    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.apply_async(_ready_in_a_forked_child).get(timeout=300) == (False, True)


_FIRST_UPDATES = """
import hashlib, json, os
from lidarflow import compiled
from lidarflow.data import read_bag, sample_bag_path
from lidarflow.predict import Predictor
predictor, digest, pending = Predictor(), hashlib.sha256(), []
for scan in list(read_bag(sample_bag_path()))[:6]:
    p = predictor.update(scan)
    pending.append(compiled._jobs.unfinished_tasks)
    digest.update(p.probability.tobytes() + p.occupied.tobytes())
print(json.dumps({"digest": digest.hexdigest(), "pending": pending}), flush=True)
os._exit(0)  # no waiting at exit for the kernels still compiling
"""


def _first_updates(tmp_path, mode: str) -> dict:
    environment = {**os.environ, "LIDARFLOW_COMPILED": mode, "OMP_NUM_THREADS": "1"}
    environment["NUMBA_CACHE_DIR"] = str(tmp_path / "empty_cache")  # a machine's first run
    done = subprocess.run(
        [sys.executable, "-c", _FIRST_UPDATES], env=environment, capture_output=True,
        text=True, timeout=600, check=True,
    )  # fmt: skip
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_first_run_predicts_while_the_kernels_compile_and_predicts_the_same(tmp_path):
    """The first updates of a machine's first run do not wait for numba: the kernels compile
    behind them, and the maps are those of the NumPy references."""
    background, numpy = _first_updates(tmp_path, "1"), _first_updates(tmp_path, "0")
    assert background["pending"][0] > 0
    assert background["digest"] == numpy["digest"]


_ASK = """
import json, numpy as np
from lidarflow import compiled
from lidarflow.predict.lookahead import _best_candidate_loop as loop
args = (np.zeros((2, 3)), np.ones((2, 4)), np.ones((2, 4)), np.ones(2), 1.0, np.ones((2, 3, 3)),
        20.0, 1e-3)
asked = compiled.ready(loop, *args)
if WAIT:
    compiled.wait()
else:
    compiled.finish()  # what a command that ran to its end does
print(json.dumps({"asked": asked, "hits": sum(loop.stats.cache_hits.values())}), flush=True)
"""


def test_a_command_that_ends_while_kernels_compile_finishes_them_for_the_next(tmp_path):
    environment = {**os.environ, "LIDARFLOW_COMPILED": "1", "NUMBA_CACHE_DIR": str(tmp_path)}
    runs = [
        subprocess.run(
            [sys.executable, "-c", _ASK.replace("WAIT", wait)],
            env=environment,
            capture_output=True,
            text=True,
            timeout=600,
            check=True,
        )
        for wait in ("False", "True")
    ]
    first, second = (json.loads(r.stdout.strip().splitlines()[-1]) for r in runs)
    assert first == {"asked": False, "hits": 0}  # it ends while compiling ...
    assert second == {"asked": False, "hits": 1}  # ... and the next run loads it from the cache
    assert runs[0].stderr == runs[1].stderr == ""  # (said on a terminal only)


def test_a_kernel_of_several_types_compiles_each_in_the_background(monkeypatch):
    monkeypatch.setattr(compiled, "background", True)
    monkeypatch.setattr(compiled, "_compiled", set())
    monkeypatch.setattr(compiled, "_asked", set())
    wide, narrow = np.arange(3.0), np.arange(3.0, dtype=np.float32)
    assert not compiled.ready(_doubled, wide, variant="d")
    compiled.wait()
    assert compiled.ready(_doubled, wide, variant="d")
    assert not compiled.ready(_doubled, narrow, variant="f")  # its own, in the background
    compiled.wait()
    assert compiled.ready(_doubled, narrow, variant="f")
    np.testing.assert_array_equal(_doubled(narrow), 2 * narrow)


def test_kernel_hands_back_the_function_where_numba_is_off(monkeypatch):
    monkeypatch.setattr(compiled, "numba", None)
    assert not compiled.available()

    def loop(x: float) -> float:
        return x + 1.0

    assert compiled.kernel(loop) is loop


def test_align_moves_as_the_numpy_iterations_to_the_last_bits(monkeypatch):
    from lidarflow.data import read_bag, sample_bag_path
    from lidarflow.motion import icp

    points = [icp.scan_points(scan) for scan in list(read_bag(sample_bag_path()))[:30]]
    guesses = [np.zeros(3), np.array([0.05, -0.02, 0.01])]
    pairs = [(points[i], points[i - j]) for i in range(3, 30) for j in (1, 3)]
    got = [icp.align(c, p, g) for c, p in pairs for g in guesses]
    monkeypatch.setattr(compiled, "numba", None)
    expected = [icp.align(c, p, g) for c, p in pairs for g in guesses]
    assert sum(e is not None for e in expected) > len(expected) // 2
    for g, e in zip(got, expected, strict=True):
        assert (g is None) == (e is None)
        if e is not None:
            np.testing.assert_allclose(g.motion, e.motion, rtol=0, atol=1e-12)
            assert g.inliers == e.inliers


@pytest.mark.parametrize("seed", range(6))
def test_the_best_candidate_is_the_numpy_reference_s(seed, monkeypatch):
    from lidarflow.predict.lookahead import best_candidate

    rng = np.random.default_rng(seed)
    shape = (2, 2, 31, 13)
    tp = rng.integers(0, 50, shape).astype(np.float64) * 0.98 ** rng.integers(0, 5)
    predicted = tp + rng.integers(0, 80, shape)
    if seed == 0:  # every candidate equal: the first
        tp, predicted = np.zeros(shape), np.zeros(shape)
    if seed == 1:  # ties on the binding term: the tie break, then the first
        tp[:, :, ::2] = tp[:, :, :1]
        predicted[:, :, ::2] = predicted[:, :, :1]
    positives = rng.integers(0, 90, 2).astype(np.float64)
    made = rng.integers(0, 500, (2, 3)).astype(np.float64)
    baselines = rng.integers(0, 500, (2, 3, 3)).astype(np.float64)
    args = (made, tp, predicted, positives, float(rng.uniform(1, 50)), baselines, 20.0, 1e-3)
    got = best_candidate(*args)
    monkeypatch.setattr(compiled, "numba", None)
    assert got == best_candidate(*args)


def test_a_command_run_to_its_end_finishes_the_compiling_and_an_error_does_not(
    short, monkeypatch, capsys
):
    from lidarflow.cli import main

    finished = []
    monkeypatch.setattr(compiled, "finish", lambda: finished.append(True))
    with pytest.raises(SystemExit) as done:
        main(["info", str(short)])
    assert done.value.code in (0, None) and finished == [True]
    with pytest.raises(SystemExit) as failed:
        main(["info", str(short.parent / "missing.bag")])
    assert failed.value.code != 0 and finished == [True]
