#!/usr/bin/env bash
# The checks a GPU session runs in one call (docs/results.md, "On an H200"):
#
#   bash benchmarks/device_check.sh OUT [CAPTURE_DIR] [SECONDS]
#
# 1. builds and installs the package against the machine's own jax/jaxlib (no build isolation, no
#    index: a machine without network), after the wheels in $WHEELS if set (pure or cp312 wheels of
#    what the machine lacks: libigl, trimesh, rtree, embreex, manifold3d);
# 2. runs the tests that differ on an accelerator (float32 products, native kernels pinned to the
#    CPU, the remesher from a GPU program, photo-consistency);
# 3. side by side, within SECONDS (default 480) from the start: the CLI at full size on CAPTURE_DIR
#    (NeuS layout; photos may be JPEG to travel light) through benchmarks/captures.py, and the
#    issue-31 synthetic photos (eight, mother_child, `highfreq`, 256^2) through benchmarks/photometric.py
#    ($JAXGENUS_SHARED_MESHES: a folder with manifest.json, eight.obj, mother_child.obj).
# Everything lands in OUT: logs.tgz, captures.md, photometric_*.md; the tables are printed last.
set -u
out=${1:?usage: device_check.sh OUT [CAPTURE_DIR] [SECONDS]}
capture=${2:-}
budget=${3:-480}
repo=$(cd "$(dirname "$0")/.." && pwd)
t0=$(date +%s)
deadline=$((t0 + budget))
mkdir -p "$out" /tmp/device_check/logs
logs=/tmp/device_check/logs
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
nvidia-smi --query-gpu=name,memory.total,clocks.sm --format=csv 2>/dev/null

site=/tmp/device_check/site
if [ -n "${WHEELS:-}" ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target "$site" "$WHEELS"/*.whl || exit 1
fi
python3 -m pip install --no-index --no-deps --no-build-isolation --target "$site" "$repo" > "$logs/build.log" 2>&1 \
  || { tail -40 "$logs/build.log"; exit 1; }
export PYTHONPATH=$site
cd /tmp/device_check || exit 1  # not the checkout: its jaxgenus/ has no built extension
python3 -c "import jax, jaxgenus; print('jax', jax.__version__, jax.devices())" || exit 1
echo "installed in $(( $(date +%s) - t0 )) s"

left() { local s=$((deadline - $(date +%s))); echo $((s > 1 ? s : 1)); }
timeout "$(left)" python3 -m pytest -q -p no:cacheprovider --rootdir "$repo" \
  "$repo/tests/test_precision.py" "$repo/tests/test_native_fields.py" "$repo/tests/test_splat_native.py" \
  "$repo/tests/test_consistency.py" -k "not finite_differences" > "$logs/tests.log" 2>&1 &
if [ -n "$capture" ]; then
  timeout "$(left)" python3 "$repo/benchmarks/captures.py" --capture "$capture" --genus auto --downsample 1 \
    --out /tmp/device_check/capture > "$logs/capture.log" 2>&1 &
fi
for shape in eight mother_child; do
  timeout "$(left)" python3 "$repo/benchmarks/photometric.py" --shapes "$shape" --albedo highfreq --targets photo \
    --res 256 --out "/tmp/device_check/photo_$shape" > "$logs/photo_$shape.log" 2>&1 &
done
(while sleep 20; do echo "t=$(( $(date +%s) - t0 )) s $(nvidia-smi --query-gpu=utilization.gpu,memory.used \
  --format=csv,noheader 2>/dev/null)"; done) > "$logs/gpu.log" 2>&1 &
monitor=$!
for job in $(jobs -p); do [ "$job" = "$monitor" ] || wait "$job"; done
kill "$monitor" 2>/dev/null
echo "done in $(( $(date +%s) - t0 )) s"
cp /tmp/device_check/capture/captures.md "$out/" 2>/dev/null
for shape in eight mother_child; do
  cp "/tmp/device_check/photo_$shape/photometric_benchmark.md" "$out/photometric_$shape.md" 2>/dev/null
done
tar czf "$out/logs.tgz" -C /tmp/device_check logs capture photo_eight photo_mother_child 2>/dev/null
tail -3 "$logs/tests.log"
cat "$out"/*.md 2>/dev/null
