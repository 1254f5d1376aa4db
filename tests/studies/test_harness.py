"""The studies' shared parts, and the house rules every study keeps."""

import importlib
import json
import pkgutil
import re
from pathlib import Path

import pytest

import studies
from studies import harness

ROOT = Path(__file__).resolve().parents[2]
# parts studies share
SHARED = {"harness", "scoring", "folds", "people", "sensor_views", "combination_capture"}
STUDIES = sorted(m.name for m in pkgutil.iter_modules(studies.__path__) if m.name not in SHARED)


@pytest.mark.parametrize("name", STUDIES)
def test_every_study_is_cited_by_a_research_page_and_smoke_tested(name):
    # a study nobody can find from the docs, or that no test runs, is lab clutter
    cited = re.compile(rf"studies\.{name}\b")
    pages = [p for p in (ROOT / "docs").rglob("*.md") if cited.search(p.read_text())]
    imported = re.compile(rf"studies\.{name}\b|from studies import [\w, ]*\b{name}\b")
    tests = [p for p in (ROOT / "tests").rglob("test_*.py") if imported.search(p.read_text())]
    assert pages, f"no page under docs/ cites studies.{name}"
    assert tests, f"no test runs studies.{name}"


@pytest.mark.parametrize("name", STUDIES)
def test_each_study_has_help_and_writes_under_runs(name, capsys):
    module = importlib.import_module(f"studies.{name}")
    with pytest.raises(SystemExit) as stopped:
        module.main(["--help"])
    assert stopped.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith(f"usage: python -m studies.{name}")
    assert f"runs/studies/{name}" in text  # the default output folder, not docs/
    # the command that reruns it and what it writes, for the research page that cites it
    assert f"python -m studies.{name}" in module.__doc__ and "Writes" in module.__doc__


@pytest.mark.parametrize("name", sorted(SHARED) + STUDIES)
def test_no_study_imports_the_cli(name):
    source = (ROOT / "studies" / f"{name}.py").read_text()
    assert not re.search(r"lidarflow\.cli|subprocess", source)
    assert len(source.splitlines()) <= 400


def test_nothing_under_src_imports_studies():
    for path in (ROOT / "src").rglob("*.py"):
        assert not re.search(r"^\s*(from|import) studies\b", path.read_text(), re.M), path


def test_write_summary_is_atomic_and_keeps_the_command(tmp_path, capsys):
    p = harness.parser("example", "An example.")
    p.add_argument("--k", type=int, default=3)
    args = harness.parse(p, ["-o", str(tmp_path), "--k", "5"])
    path = harness.write_summary(args, "example", {"a": (1, Path("x"))}, "| a |\n")

    written = json.loads(path.read_text())
    assert written == {
        "config": {"k": 5, "command": f"python -m studies.example -o {tmp_path} --k 5"},
        "results": {"a": [1, "x"]},
    }
    assert (tmp_path / "example.md").read_text() == "| a |\n"
    assert sorted(f.name for f in tmp_path.iterdir()) == ["example.json", "example.md"]
    assert capsys.readouterr().out == "| a |\n"


def test_write_atomic_leaves_the_old_file_when_killed(tmp_path, monkeypatch):
    target = harness.write_atomic(tmp_path / "x.json", "old")

    def killed(*_args):
        raise KeyboardInterrupt

    monkeypatch.setattr(harness.os, "replace", killed)
    with pytest.raises(KeyboardInterrupt):
        harness.write_atomic(target, "new")
    assert target.read_text() == "old"
    assert list(tmp_path.iterdir()) == [target]  # no temporary left beside it


def test_write_arrays_reads_back_and_a_killed_write_leaves_nothing(tmp_path, monkeypatch):
    import numpy as np

    target = harness.write_arrays(tmp_path / "a.npz", {"x": np.arange(3)})
    assert np.load(target)["x"].tolist() == [0, 1, 2]

    def killed(*_args, **_kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez_compressed", killed)
    with pytest.raises(KeyboardInterrupt):
        harness.write_arrays(tmp_path / "b.npz", {"x": np.arange(3)})
    assert list(tmp_path.iterdir()) == [target]  # neither b.npz nor its temporary


def test_verdict_and_judged_follow_the_rule():
    base = {b: {"f1": 0.5, "changed_f1": 0.2, "ap": 0.5} for b in harness.BASELINES}
    methods = {**base, "m": {"f1": 0.6, "changed_f1": 0.1, "ap": 0.6}}
    scores = harness.judged(methods)
    assert scores["verdict"] == "F1 only"
    assert scores["margins"] == {"f1": 0.1, "changed_f1": -0.1}
    methods["m_fixed"] = {"f1": 0.7, "changed_f1": 0.3, "ap": 0.7}  # the other rule: not judged
    assert harness.judged(methods)["verdict"] == "F1 only"


def test_variant_parses_name_recipe_and_keys():
    from studies.folds import Variant

    v = Variant.parse("tiny=blurred optim.epochs=1 data.grid=32")
    assert v == Variant("tiny", "blurred", ("optim.epochs=1", "data.grid=32"))
    with pytest.raises(Exception, match="NAME=RECIPE"):
        Variant.parse("tiny=optim.epochs=1")


def test_a_model_that_loses_on_movers_does_not_win():
    base = {b: {"f1": 0.5, "changed_f1": 0.2, "ap": 0.5} for b in harness.BASELINES}
    base["copy_last"]["mover_f1_tolerant"] = 0.4
    methods = {**base, "m": {"f1": 0.6, "changed_f1": 0.3, "ap": 0.6, "mover_f1_tolerant": 0.3}}
    scores = harness.judged(methods)
    assert scores["verdict"] == "loses movers"
    assert scores["margins"]["mover_f1_tolerant"] == -0.1
    methods["m"]["mover_f1_tolerant"] = 0.45
    assert harness.judged(methods)["verdict"] == "wins"
    del methods["m"]["mover_f1_tolerant"]  # a report without the mover metric: as before
    assert harness.judged(methods)["verdict"] == "wins"
