#!/usr/bin/env bash
# One lent GPU, one command of at most 10 minutes: issue 38's leave-one-recording-out comparison
# (LiDAR-FlowNet's bundled recipe, SOGMP at the peer's recipe, DeepTracking) trained and scored
# there, and issue 36's supervised flow at the paper's data scale (two training seeds).
# Every training has a wall-clock budget (--max-minutes), so the phases end on time whatever the
# chip's speed; what each model got is in its model.json (epochs_done) and metrics.jsonl.
#
# Needs, inside the checkout: .devdata/ (the seven development recordings as `lidarflow convert`
# .npz, and sim_flow_2/, the simulation-only flow network of docs/research/leave_one_out) and
# .whl/ (typer and its needs for the image's Python). Writes everything under OUT (default
# $OUT, else runs/gpu_session) and tars the small files of every run there.
#   studies/gpu_session.sh            # on the device: carry .devdata and .whl
# (docs/research/peer_comparison's run was made at 9e367e6, when the study passed the same
# settings as `lidarflow train` flags after `--` and ran each fold as a `lidarflow` process.)
set -u
OUT=${OUT:-runs/gpu_session}
W=$OUT/work  # runs and data; only the tars below leave the machine
source studies/gpu_env.sh
export OMP_NUM_THREADS=2
nvidia-smi -L
python3 -c "import torch, numpy; print('torch', torch.__version__, 'numpy', numpy.__version__, torch.cuda.get_device_name())"
nvidia-smi --query-gpu=timestamp,memory.used,utilization.gpu --format=csv -l 15 > "$OUT/gpu.csv" &
SMI=$!

# ---- data for the supervised flow: the paper's 36,000 training frames, sensors mixed (seed 11
# is the held-out seed and is never simulated here)
S=$W/sim
mkdir -p "$S"
sim() { $LF simulate --flow-storage sparse --chunk-frames 0 "$@" > /dev/null || echo "simulate $* FAILED"; }
PIDS=()
sim -s dynamic --frames 12000 --seed 21 --sensor tim561 -j 4 -o "$S/dyn21_tim.npz" & PIDS+=($!)
sim -s static --frames 8000 --seed 22 --sensor tim561 -j 3 -o "$S/sta22_tim.npz" & PIDS+=($!)
sim -s dynamic --frames 6000 --seed 23 --sensor hokuyo-urg -j 2 -o "$S/dyn23_urg.npz" & PIDS+=($!)
sim -s dynamic --frames 6000 --seed 24 --sensor rplidar -j 2 -o "$S/dyn24_rp.npz" & PIDS+=($!)
sim -s static --frames 4000 --seed 25 --sensor hokuyo-utm -j 2 -o "$S/sta25_utm.npz" & PIDS+=($!)
sim -s dynamic --frames 150 --seed 30 -o "$S/val_dyn30.npz" & PIDS+=($!)
sim -s static --frames 100 --seed 31 -o "$S/val_sta31.npz" & PIDS+=($!)
wait "${PIDS[@]}"
t "simulated: $(ls "$S")"

# ---- phase A (about 280 s): every training at once, each within its budget
R=(.devdata/positive_1.npz .devdata/positive_2.npz .devdata/positive_3.npz .devdata/positive_4.npz
   .devdata/demo_stationary_simple_environment.npz .devdata/datmo_overtakes.npz
   .devdata/general_tracking_moving_1.npz)
STUDY="python3 -m studies.peer_comparison"
C=$W/compare
PIDS=()
for seed in 0 1; do
  $LF train "$S/dyn*.npz" "$S/sta*.npz" --val "$S/val_dyn30.npz" --val "$S/val_sta31.npz" \
    --recipe supervised_flow --batch-size 32 --epochs 40 --seed $seed --max-minutes 4.4 \
    --set data.epoch_windows=1600 --set schedule.lr_step_epochs=10 \
    --set runtime.tensorboard=false -o "$W/supflow_s$seed" > "$W/supflow_s$seed.log" 2>&1 & PIDS+=($!)
done
$STUDY train -o "$C" --model sogmp --jobs 3 --recordings "${R[@]}" \
  --set runtime.amp=auto runtime.max_minutes=1.35 > "$W/sogmp.log" 2>&1 & PIDS+=($!)
$STUDY train -o "$C" --model deeptracking --jobs 2 --recordings "${R[@]}" \
  --set runtime.amp=auto runtime.max_minutes=0.8 > "$W/deeptracking.log" 2>&1 & PIDS+=($!)
$STUDY train -o "$C" --model flownet --jobs 3 --flow-init .devdata/sim_flow_2 \
  --recordings "${R[@]}" --set runtime.threads=2 runtime.max_minutes=1.2 > "$W/flownet.log" 2>&1 & PIDS+=($!)
wait "${PIDS[@]}"
t "phase A done"
cat "$W"/sogmp.log "$W"/deeptracking.log "$W"/flownet.log
for seed in 0 1; do tail -n 3 "$W/supflow_s$seed.log"; done

pack() {  # the small files of some runs -> one tar under OUT
  local name=$1; shift
  (cd "$W" && find "$@" \( -name model.safetensors -o -name model.json -o -name config.json \
     -o -name metrics.jsonl -o -name run.json -o -name '*.log' \) -print0 2>/dev/null |
     tar --null -czf "$OUT/$name.tgz" -T -) && t "packed $name: $(du -h "$OUT/$name.tgz" | cut -f1)"
}
pack sogmp_a compare/sogmp/positive_1 compare/sogmp/positive_2 compare/sogmp/positive_3 \
  compare/sogmp/positive_4
pack sogmp_b compare/sogmp/demo_stationary_simple_environment compare/sogmp/datmo_overtakes \
  compare/sogmp/general_tracking_moving_1
pack runs compare/flownet compare/deeptracking supflow_s0 supflow_s1 sogmp.log deeptracking.log \
  flownet.log supflow_s0.log supflow_s1.log

# ---- phase B: every fold scored on the GPU, one process per held-out recording
timeout "${EVAL_SECONDS:-200}" $STUDY evaluate -o "$C" --device cuda --jobs 7 --threads 2 \
  --recordings "${R[@]}"
t "phase B done (exit $?)"
$STUDY table -o "$C" | tail -n 12
(cd "$W" && tar -czf "$OUT/evaluation.tgz" compare/evaluation compare/peer_comparison.md \
  compare/peer_comparison.json 2>/dev/null)
kill $SMI 2>/dev/null
t "end"
