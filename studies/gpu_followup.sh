#!/usr/bin/env bash
# The lent GPU's last ~4 minutes after studies/gpu_session.sh (issue 38): SOGMP alone on one fold
# (held-out positive_2) for longer than the shared session gave each fold, and the fold models
# of two folds scored on simulated seeds no model trained on, ~1 s ahead (15 scans of the
# tim561 preset). Needs in the checkout: .devdata/ (the recordings as .npz, and peer_runs/:
# the fold runs of gpu_session.sh for general_tracking_moving_1 and positive_1, flownet_noflow
# made by studies.peer_comparison.zero_flow) and .whl/ (as gpu_session.sh).
set -u
OUT=${OUT:-runs/gpu_followup}
W=$OUT/work
source studies/gpu_env.sh
export OMP_NUM_THREADS=4
R=(.devdata/positive_1.npz .devdata/positive_2.npz .devdata/positive_3.npz .devdata/positive_4.npz
   .devdata/demo_stationary_simple_environment.npz .devdata/datmo_overtakes.npz
   .devdata/general_tracking_moving_1.npz)

python3 -m studies.peer_comparison train -o "$W/c" --model sogmp --recordings "${R[@]}" \
  --held-out .devdata/positive_2.npz \
  --set runtime.amp=auto "runtime.max_minutes=${SOGMP_MINUTES:-1.8}" \
  > "$W/sogmp.log" 2>&1 &
TRAIN=$!
$LF simulate -s dynamic --frames 300 --seed 11 -o "$W/held_dyn11.npz" > /dev/null &
$LF simulate -s static --frames 300 --seed 11 -o "$W/held_sta11.npz" > /dev/null &
wait %2 %3
P=.devdata/peer_runs
for pair in "dyn11 general_tracking_moving_1" "sta11 positive_1"; do
  set -- $pair
  $LF evaluate "$W/held_$1.npz" -m "$P/flownet/$2/run" -m "$P/flownet_noflow/$2/run" \
    -m "$P/sogmp/$2/run" -m "$P/deeptracking/$2/run" --horizon 15 --device cuda --threads 4 \
    -o "$OUT/sim_$1_fold_$2.json" > "$W/sim_$1.log" 2>&1 &
done
wait $TRAIN
t "sogmp trained: $(grep -o 'ends after epoch [0-9]* of [0-9]*' "$W/sogmp.log")"
timeout "${EVAL_SECONDS:-60}" python3 -m studies.peer_comparison evaluate -o "$W/c" \
  --recordings "${R[@]}" --held-out .devdata/positive_2.npz --device cuda --threads 4
cp "$W"/c/evaluation/positive_2.json "$OUT/sogmp_alone_positive_2.json" 2>/dev/null
(cd "$W/c" && tar -czf "$OUT/sogmp_alone.tgz" sogmp/positive_2/run/model.safetensors \
  sogmp/positive_2/run/model.json sogmp/positive_2/run/metrics.jsonl)
wait
t "end: $(ls "$OUT")"
