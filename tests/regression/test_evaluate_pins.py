"""``lidarflow evaluate`` on a development recording reports what main ``a4a22da`` reported
(``check_evaluate.py`` compares all seven and the horizon table; here a static one and the
driving one without poses, whose motion is matched from its scans)."""

from __future__ import annotations

import json

import pytest

from tests.regression.check_evaluate import moved
from tests.regression.make_bundled_pins import SHARED
from tests.test_cli import run


@pytest.mark.parametrize("name", ["positive_2.bag", "datmo_overtakes.bag"])
def test_evaluate_reproduces_the_pinned_report(tmp_path, capsys, name) -> None:
    bag = SHARED / name
    if not bag.exists():
        pytest.fail(f"{bag} is missing: the suite runs with ../shared beside the checkout")
    out = tmp_path / "e.json"
    code, _, err = run(["evaluate", str(bag), "--json", str(out)], capsys)
    assert code == 0, err
    report = json.loads(out.read_text())
    assert moved(report) == []
    # The comparison can fail: a number moved by more than the tolerance is named.
    report["recordings"][0]["methods"]["bundled"]["f1"] += 0.001
    assert len(moved(report)) == 1 and moved(report)[0].startswith(f"{name} bundled f1: ")
