#!/bin/bash
# One fold of the real-data flow screen: flow fine-tuned on the fold's six real recordings,
# then the head (shift recipe), then the offset chosen on the six, reported on the held-out one.
set -e
HELD=$1; D=../shared/data
ALL="$D/positive_1.bag $D/positive_2.bag $D/positive_3.bag $D/positive_4.bag $D/demo_stationary_simple_environment.bag $D/datmo_overtakes.bag $D/general_tracking_moving_1.bag.zip"
TRAIN=$(for r in $ALL; do [[ "$r" == *"$HELD"* ]] || echo -n "$r "; done; true)
HELDP=$(for r in $ALL; do [[ "$r" == *"$HELD"* ]] && echo -n "$r"; done; true)
OUT=runs/realflow/$HELD
export OMP_NUM_THREADS=1
L=.venv/bin/lidarflow
[ -f $OUT/flow/model.safetensors ] || $L train $TRAIN -m flownet --recipe blurred --init docs/results/accuracy/loo/sim_flow_2 \
  --epochs 3 --batch-size 8 --lr 0.001 --set data.stride=10 --set data.epoch_windows=300 \
  --set schedule.gaussian_start=5 --set schedule.gaussian_step_epochs=1 --set schedule.lr_step_epochs=2 \
  --set runtime.final_weights=best --threads 1 --amp bf16 --channels-last -o $OUT/flow
[ -f $OUT/run/model.safetensors ] || $L train $TRAIN --recipe residual --init $OUT/flow --config docs/results/accuracy/loo/head_cv_h16_shift.json \
  --epochs 3 --batch-size 4 --seq-len 16 --warmup 6 --lr 0.000001 --amp bf16 --channels-last --threads 1 -o $OUT/run
.venv/bin/python experiments/decision_offset.py -m $OUT/run -o $OUT/offset --offsets 0 0.3 0.6 0.9 1.2 1.5 --choose $TRAIN --report $HELDP
