"""Write the flow network of a model folder alone (no occupancy head) as a model folder.

The head recipe (`lidarflow train --recipe head`) copies every weight of `--init` whose shape
fits, the head's too; to train a head afresh on a trained flow network, as the leave-one-out
study does, start from the flow alone:

    python experiments/flow_only.py src/lidarflow/assets/model -o runs/flow_v1
    lidarflow train ... --init runs/flow_v1

Writes OUT/model.json and OUT/model.safetensors.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from safetensors.torch import load_file, save_file

from lidarflow.models.flownet import OCCUPANCY_HEAD_PARAMETERS
from lidarflow.models.presets import resolve_model

# Keyword arguments that only mean something with the occupancy head.
HEAD_KWARGS = (
    "occupancy_head",
    "memory_decays",
    "memory_bias_correction",
    "decision_offset",
    "constant_velocity_input",
    "head_hidden_channels",
    "shift_memories",
    "visibility_input",
    "warp_input",
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", type=Path, help="model folder (model.json + weights)")
    parser.add_argument("-o", "--output", type=Path, required=True)
    args = parser.parse_args()
    card = json.loads((args.model / "model.json").read_text())
    weights = load_file(args.model / card.get("weights", "model.safetensors"))
    # An ego-motion model's names start with its wrapper's "inner."; it stays ego-motion.
    flow = {
        n: v
        for n, v in weights.items()
        if not n.removeprefix("inner.").startswith(OCCUPANCY_HEAD_PARAMETERS)
    }
    kwargs = {k: v for k, v in card.get("model_kwargs", {}).items() if k not in HEAD_KWARGS}
    out = {
        "model": card["model"],
        "model_kwargs": kwargs,
        "out_channels": 4,
        "weights": "model.safetensors",
        "flow_of": str(args.model),
    }
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "model.json").write_text(json.dumps(out, indent=2) + "\n")
    save_file(flow, args.output / "model.safetensors")
    resolve_model(args.output)  # fails here if the flow network does not load alone
    print(f"{len(flow)} of {len(weights)} tensors -> {args.output}")


if __name__ == "__main__":
    main()
