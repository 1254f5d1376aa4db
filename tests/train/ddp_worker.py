"""Run by ``torchrun`` in test_distributed: a few DDP steps, then every rank saves its weights.

Usage: ``torchrun --standalone --nproc_per_node 2 tests/train/ddp_worker.py DATA RUN_DIR OUT``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from safetensors.torch import save_file

from lidarflow.train import build_config, train


def main() -> None:
    data, run_dir, out = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
    cfg = build_config(
        "blurred",
        None,
        {
            "data.sources": [data],
            "data.grid": 32,
            "data.seq_len": 8,
            "data.warmup": 3,
            "data.val_fraction": 0.25,
            "optim.batch_size": 2,
            "optim.epochs": 2,
            "optim.lr": 0.01,
            "runtime.device": "cpu",
            "runtime.threads": 1,
            "runtime.tensorboard": False,
        },
    )
    result = train(cfg, run_dir)
    rank = int(os.environ["RANK"])
    state = {k: v.contiguous() for k, v in result.model.state_dict().items()}
    save_file(state, str(out / f"rank{rank}.safetensors"))
    (out / f"rank{rank}.rows").write_text(repr([r.get("train_loss") for r in result.rows]))


if __name__ == "__main__":
    main()
