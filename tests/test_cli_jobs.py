"""``--jobs N`` (issue 46): many inputs at once, one worker process each, the outputs one
process writes, in input order, one line per failed input, nothing half-written when stopped."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lidarflow.cli.jobs import Outcome, resolve_jobs, run_jobs
from lidarflow.data import read_bag, sample_bag_path
from tests.test_cli import run
from tests.without_torch import PRELUDE

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def short(tmp_path_factory) -> list[Path]:
    """Three short recordings of the sample, of unlike lengths (so that they finish out of
    order)."""
    folder = tmp_path_factory.mktemp("jobs")
    sample = read_bag(sample_bag_path())
    spans = ((0, 30), (60, 80), (120, 145))
    return [sample.slice(a, b).save(folder / f"r{i}.npz") for i, (a, b) in enumerate(spans)]


def _cli(*argv: str, cwd: Path) -> subprocess.CompletedProcess:
    # BLAS on one thread, as in a worker: SSIM's sums change in their 10th digit with its threads
    env = {**os.environ, "PYTHONPATH": f"{ROOT / 'src'}:{ROOT}"}
    env.update({"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"})
    return subprocess.run(
        [sys.executable, "-m", "lidarflow", *argv], cwd=cwd, env=env, capture_output=True,
        text=True, timeout=600,
    )  # fmt: skip


@pytest.mark.slow
def test_evaluate_jobs_writes_what_one_process_writes(short, tmp_path):
    common = [*map(str, short), "--warmup", "5", "--horizon", "2", "--combine", "--learn"]
    one = _cli("evaluate", *common, "-o", "one.json", "--report", "one", cwd=tmp_path)
    assert one.returncode == 0, one.stderr
    two = _cli("evaluate", *common, "-o", "two.json", "--report", "two", "-j", "2", cwd=tmp_path)
    assert two.returncode == 0, two.stderr
    assert (tmp_path / "one.json").read_bytes() == (tmp_path / "two.json").read_bytes()
    report = json.loads((tmp_path / "two.json").read_text())
    assert [e["path"] for e in report["recordings"]] == [str(p) for p in short]
    assert all("horizon_f1" in e for e in report["recordings"])
    for entry in report["recordings"]:
        assert {"bundled_combined", "bundled_learning"} <= set(entry["horizon_f1"])
    for name in ("report.json", "index.html"):
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes()
    assert sorted(p.name for p in (tmp_path / "one").iterdir()) == sorted(
        p.name for p in (tmp_path / "two").iterdir()
    )
    # the tables, in input order, the same
    assert one.stdout.replace("one.json", "X").replace("one/", "X/") == two.stdout.replace(
        "two.json", "X"
    ).replace("two/", "X/")


@pytest.mark.slow
def test_predict_jobs_writes_each_bag_as_one_process_and_a_failure_stops_no_other(
    short, tmp_path, capsys
):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a recording")
    inputs = [str(short[0]), str(bad), str(short[2])]
    code, _, err = run(["predict", *inputs, "-o", str(tmp_path / "one")], capsys)
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lidarflow: error: ") and "bad.npz" in lines[0]
    code, out2, err2 = run(["predict", *inputs, "-o", str(tmp_path / "two"), "-j", "2"], capsys)
    assert code == 1 and err2.strip().splitlines() == lines
    for name in ("r0.mcap", "r2.mcap"):
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes()
    assert sorted(p.name for p in (tmp_path / "two").iterdir()) == ["r0.mcap", "r2.mcap"]
    written = [line.split(":")[0] for line in out2.splitlines() if line.startswith("wrote")]
    assert written == [f"wrote {tmp_path / 'two' / n}" for n in ("r0.mcap", "r2.mcap")]
    code, _, err = run(["predict", *inputs, "-o", str(tmp_path / "x.mcap")], capsys)
    assert code == 2 and "names a folder" in err


def test_two_inputs_of_one_name_get_two_outputs(short, tmp_path, capsys):
    other = tmp_path / "elsewhere"
    other.mkdir()
    twin = other / short[0].name
    twin.write_bytes(short[1].read_bytes())
    code, _, err = run(["predict", str(short[0]), str(twin), "-o", str(tmp_path / "o")], capsys)
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["r0.mcap", "r0_2.mcap"]


def sleepy(task: tuple[float, str]) -> str:
    """A task for the pool: sleeps, then returns its word, or fails where it is ``fail``."""
    seconds, word = task
    time.sleep(seconds)
    if word == "fail":
        raise ValueError("this input is broken")
    print(f"note on {word}", file=sys.stderr)
    return word


@pytest.mark.slow
def test_outcomes_come_in_input_order_and_an_error_names_its_input():
    tasks = [(1.5, "a"), (0.0, "fail"), (0.0, "c"), (0.0, "d")]
    seen: list[Outcome] = []
    names = ["A.bag", "B.bag", "C.bag", "D.bag"]
    done = run_jobs(sleepy, tasks, names, 2, 1, "test", seen.append)
    assert [o.index for o in seen] == [0, 1, 2, 3] and done == seen
    assert [o.value for o in seen] == ["a", None, "c", "d"]
    assert seen[1].error == "B.bag: internal error: ValueError: this input is broken " + (
        "(rerun it with --jobs 1 and LIDARFLOW_DEBUG=1 for the traceback, and please report it)"
    )
    assert seen[0].notes == "note on a\n"  # a worker's stderr comes back with its result
    stopped = run_jobs(sleepy, tasks, names, 2, 1, "test", lambda o: None, stop_on_error=True)
    assert [o.index for o in stopped] == [0, 1]
    assert resolve_jobs(0, 100) == len(os.sched_getaffinity(0)) and resolve_jobs(8, 3) == 3


def _partials(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if ".partial" in p.name]


@pytest.mark.slow
def test_sigterm_stops_every_worker_and_leaves_nothing_half_written(tmp_path):
    sample = read_bag(sample_bag_path())
    inputs = [str(sample.slice(0, 200).save(tmp_path / f"long{i}.npz")) for i in range(2)]
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": f"{ROOT / 'src'}:{ROOT}"}
    argv = [sys.executable, "-m", "lidarflow", "predict", *inputs, "-o", str(out), "-j", "2"]
    proc = subprocess.Popen(argv, env=env, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while not (out.exists() and _partials(out)):  # the workers are writing
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
            time.sleep(0.2)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130 and err.strip().endswith("stopped by signal SIGTERM"), err
    assert not _partials(out)
    # A job may finish before the signal (compiled kernels make one fast): what is left whole.
    for done in out.glob("*.mcap"):
        assert len(read_bag(done, topic="/right_scan")) == 200, done


def slow_write(task: tuple[str, float]) -> str:
    """A task for the pool: writes ``path`` through lidarflow.atomic for ``seconds``, a piece
    every tenth of a second, and takes half a second to close it (as a bag writer writes its
    index, on an interrupt too)."""
    from lidarflow.atomic import atomic_path
    from lidarflow.cli.jobs import job_bar

    path, seconds = task
    steps = int(seconds * 10)
    with job_bar(steps, "writing") as bar, atomic_path(path) as tmp, tmp.open("wb") as f:
        try:
            for _ in range(steps):
                f.write(b"piece")
                f.flush()
                time.sleep(0.1)
                bar.update()
        finally:
            time.sleep(0.5)
    return path


#: ``python -c STOPPABLE FOLDER``: two slow_write tasks of a minute in FOLDER, two workers, in a
#: process that stops on SIGTERM and Ctrl-C as the CLI does.
STOPPABLE = """
import sys
from pathlib import Path
from lidarflow.cli import stop_on_sigterm
from lidarflow.cli.jobs import run_jobs
from tests.test_cli_jobs import slow_write
stop_on_sigterm()
folder = Path(sys.argv[1])
tasks = [(str(folder / "a.bin"), 60.0), (str(folder / "b.bin"), 60.0)]
try:
    run_jobs(slow_write, tasks, ["a", "b"], 2, 1, "writing", lambda o: None)
except KeyboardInterrupt:
    sys.exit(130)
"""


def _running_in_group(group: int) -> list[str]:
    """The processes of process group ``group`` that have not ended (zombies left out)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z" and int(fields[2]) == group:
            found.append(stat.parent.name)
    return found


@pytest.mark.slow
@pytest.mark.parametrize(
    "how", ["ctrl-c to the group", "sigterm to the group", "sigkill to the parent"]
)
def test_stopping_a_jobs_run_ends_every_process_and_leaves_nothing(tmp_path, how):
    env = {**os.environ, "PYTHONPATH": f"{ROOT / 'src'}:{ROOT}", "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-c", STOPPABLE, str(tmp_path)], cwd=ROOT, env=env,
        stderr=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while len(_partials(tmp_path)) < 2:  # both workers are writing
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
            time.sleep(0.1)
        time.sleep(0.3)
        if how == "sigkill to the parent":
            proc.kill()
        else:
            os.killpg(proc.pid, signal.SIGINT if how.startswith("ctrl-c") else signal.SIGTERM)
        code = proc.wait(timeout=60)
        at_exit = _partials(tmp_path)  # the parent waits for the workers' clean-up
        deadline = time.monotonic() + 20  # the workers' clean-up: half a second each
        while _running_in_group(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _running_in_group(proc.pid), f"still running after {how}"
        err = proc.stderr.read()
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.stderr.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == [], how
    if how != "sigkill to the parent":
        assert code == 130 and err == "" and at_exit == [], (err, at_exit)


def torch_in_worker(recording: str) -> tuple[bool, bool]:
    """In a worker: predict on ``recording``, then say whether PyTorch is imported, and
    whether it could be."""
    from lidarflow.cli.per_input import PredictSettings, PredictTask, predict_input
    from lidarflow.extras import torch_available

    settings = PredictSettings(
        None, None, None, None, 1, 1, 0.4, None, frozenset({"predicted"}), False
    )
    output = Path(recording).with_name(f"{os.getpid()}.mcap")
    predict_input(PredictTask(Path(recording), output, settings))
    return sys.modules.get("torch") is not None, torch_available()


@pytest.mark.slow
def test_workers_of_the_core_install_run_without_pytorch(short):
    body = (
        "from lidarflow.cli.jobs import run_jobs\nfrom tests.test_cli_jobs import torch_in_worker\n"
        f"done = run_jobs(torch_in_worker, [{str(short[0])!r}, {str(short[1])!r}], ['a', 'b'], "
        "2, 1, 'x', lambda o: None)\nprint([(o.value, o.error) for o in done])\n"
    )
    env = {"OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin", "PYTHONPATH": f"{ROOT / 'src'}:{ROOT}"}
    done = subprocess.run(
        [sys.executable, "-c", PRELUDE + body], cwd=ROOT, env=env, capture_output=True,
        text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[((False, False), None), ((False, False), None)]", done.stdout
