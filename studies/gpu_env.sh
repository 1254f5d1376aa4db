# Sourced by the GPU scripts (gpu_session.sh, gpu_followup.sh) on the lent machine: OUT and its
# work folder W, everything printed also kept in $OUT/log.txt, t() to stamp a line with the
# seconds since the start, the carried wheels (.whl/) installed for the image's Python, and
# LF, the lidarflow command from this checkout.
mkdir -p "$W"
exec > >(tee -a "$OUT/log.txt") 2>&1
T0=$(date +%s)
t() { echo "[$(( $(date +%s) - T0 )) s] $*"; }
if [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD/src:$PWD
else
  export PYTHONPATH=$PWD/src:$PWD
fi
export PYTHONUNBUFFERED=1
LF="python3 -m lidarflow"
