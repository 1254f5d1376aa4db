"""Per-epoch metrics: ``metrics.jsonl``, ``metrics.csv`` (rewritten whole each epoch so new
columns can appear) and TensorBoard when installed. A resume drops the rows of epochs after its
checkpoint, so the files always describe the weights on disk.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

from lidarflow.train.checkpoint import atomic_write

__all__ = ["Logbook"]


class Logbook:
    """Appends epoch rows; only rank 0 makes one."""

    def __init__(
        self, run_dir: Path, tensorboard: bool = True, resume_epoch: int | None = None
    ) -> None:
        self.jsonl = run_dir / "metrics.jsonl"
        self.csv = run_dir / "metrics.csv"
        self.rows: list[dict[str, Any]] = []
        if resume_epoch is not None and self.jsonl.exists():
            rows = [json.loads(line) for line in self.jsonl.read_text().splitlines() if line]
            self.rows = [r for r in rows if r.get("epoch", 0) <= resume_epoch]
        self._flush()
        self.writer = None
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter
            except ImportError:  # tensorboard is optional
                pass
            else:
                self.writer = SummaryWriter(str(run_dir / "tensorboard"))

    def log(self, row: dict[str, Any]) -> None:
        self.rows.append(row)
        self._flush()
        if self.writer is not None:
            for key, value in row.items():
                if isinstance(value, int | float) and key != "epoch":
                    self.writer.add_scalar(key, value, row["epoch"])
            self.writer.flush()

    def _flush(self) -> None:
        lines = "".join(json.dumps(r) + "\n" for r in self.rows)
        atomic_write(self.jsonl, lambda tmp: tmp.write_text(lines))
        columns: list[str] = []
        for r in self.rows:
            columns += [k for k in r if k not in columns]
        buf = io.StringIO()
        out = csv.DictWriter(buf, fieldnames=columns)
        out.writeheader()
        out.writerows(self.rows)
        atomic_write(self.csv, lambda tmp: tmp.write_text(buf.getvalue()))

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
