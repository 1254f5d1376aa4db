"""``lidarflow evaluate`` on a development recording reports what main ``a4a22da`` reported for
the baselines and v8 (a flow model, the bundled one then), and what the bundled model (v10)
scored when it was installed (``check_evaluate.py`` compares all seven and the horizon table; here a
static one and the driving one without poses, whose motion is matched from its scans)."""

from __future__ import annotations

import json

import pytest

from tests.conftest import FLOW_MODEL
from tests.regression.check_evaluate import V8, moved
from tests.regression.make_bundled_pins import SHARED
from tests.test_cli import run


@pytest.mark.parametrize("name", ["positive_2.bag", "datmo_overtakes.bag"])
def test_evaluate_reproduces_the_pinned_report(tmp_path, capsys, name) -> None:
    bag = SHARED / name
    if not bag.exists():
        pytest.fail(f"{bag} is missing: the suite runs with ../shared beside the checkout")
    out = tmp_path / "e.json"
    args = ["evaluate", str(bag), "-m", "bundled", "-m", str(FLOW_MODEL), "--json", str(out)]
    code, _, err = run(args, capsys)
    assert code == 0, err
    report = json.loads(out.read_text())
    assert {"bundled", V8} <= set(report["recordings"][0]["methods"])
    assert moved(report) == []
    # The comparison can fail: a number moved by more than the tolerance is named.
    for method in ("bundled", V8):
        report["recordings"][0]["methods"][method]["f1"] += 0.001
        assert len(moved(report)) == 1 and moved(report)[0].startswith(f"{name} {method} f1: ")
        report["recordings"][0]["methods"][method]["f1"] -= 0.001
