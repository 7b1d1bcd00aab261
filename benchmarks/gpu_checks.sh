#!/usr/bin/env bash
# The GPU measurements (docs/gpu.md), prepared for a GPU machine without network access where one
# command may run 10 minutes. Each mode leaves one $OUT/MODE.tar.gz (benchmark JSON, logs, the
# demo's report and images) and prints the stage summary and every JSON result, so that
# the command's output alone already holds the figures.
#
#   bash benchmarks/gpu_checks.sh fetch     here, once: .whl/ with what the GPU image lacks (cp312:
#                                           av, embreex, trimesh, pytorch-msssim, kornia, kornia-rs;
#                                           55 MiB). The image has torch, numpy, scipy, opencv, PIL,
#                                           torchmetrics, tensorboard, tqdm, PyYAML, threadpoolctl,
#                                           pytest and pytest-timeout; not imagehash (realset only,
#                                           imported on use) nor imageio-ffmpeg (the video fallback
#                                           where PyAV lacks libx264, imported on use).
#                                           Where the tree and .whl must fit 64 MiB together, leave
#                                           the shipped model (27 MiB; no check uses it) behind:
#                                           tree without it 5 MiB + .whl 55 MiB.
#   bash benchmarks/gpu_checks.sh checks    there (with .whl), within 10 min on one GPU: sim2real doctor, CUDA tests, a
#                                           short paper-preset training run (it/s, data-wait share from
#                                           metrics.jsonl, peak GPU memory), the training step, its
#                                           peak memory, host syncs and GPU-busy share (bench_train),
#                                           translation frames/s and the networks' share of the
#                                           matmul rate, the data path per stage, translation with --compile (while time
#                                           is left), and a 20-step DDP run when there are >1
#                                           GPUs; CONV_SHARE=1 adds the conv share of the bf16 peak
#   bash benchmarks/gpu_checks.sh demo      there (with .whl): `sim2real demo` on the paper preset,
#                                           DEMO_MINUTES (4) of training, then the learning statistics
#   PY=.venv/bin/python DEV=cpu bash benchmarks/gpu_checks.sh smoke
#                                           here: the same stages at tiny sizes on the CPU, to check
#                                           the script itself before device time is spent on it
#
# Each stage has its own time limit; a stage that fails or runs out is logged and the next one runs.
set -u
cd "$(dirname "$0")/.."
MODE=${1:-checks}
OUT=${OUT:-gpu_out}
PY=${PY:-python3}
DEV=${DEV:-cuda}
W=$(mktemp -d /tmp/gpu_checks.XXXXXX)
mkdir -p "$OUT"

if [ "$MODE" = fetch ]; then
    grep -qx '/.whl/' .git/info/exclude 2>/dev/null || echo '/.whl/' >> .git/info/exclude
    mkdir -p .whl
    for pkg in av embreex trimesh pytorch-msssim kornia kornia-rs; do
        python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
            --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
            --platform manylinux2014_x86_64 -d .whl "$pkg" || exit 1
    done
    du -sh .whl
    exit 0
fi

if [ -d .whl ] && ls .whl/*.whl >/dev/null 2>&1; then
    "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
        || { echo "wheel install failed"; exit 1; }
    export PYTHONPATH=/tmp/site
fi
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
# the view pools of the paper preset (3,000 views, 6.6 GiB per scene, built before the first step)
# go to a scratch cache outside $W, so that they stay out of the archive
export SIM2REAL_CACHE=${SIM2REAL_CACHE:-$(mktemp -d /tmp/gpu_checks_cache.XXXXXX)}

finish() {  # always: one archive, and the figures on stdout
    tar -czf "$OUT/$MODE.tar.gz" -C "$W" . 2>/dev/null
    echo "== stages"; cat "$W/stages.txt" 2>/dev/null
    for f in "$W"/*.json; do [ -f "$f" ] && { echo "== $(basename "$f")"; cat "$f"; }; done
}
trap finish EXIT

stage() {  # stage NAME SECONDS COMMAND...: stdout to NAME.json (JSON) or NAME.out, stderr to NAME.err
    local name=$1 limit=$2; shift 2
    local t0=$SECONDS
    timeout "$limit" "$@" > "$W/$name.out" 2> "$W/$name.err"
    local rc=$?
    echo "$name: rc=$rc, $((SECONDS - t0)) s" >> "$W/stages.txt"
    if head -c1 "$W/$name.out" 2>/dev/null | grep -q '{'; then mv "$W/$name.out" "$W/$name.json"; fi
}

if [ "$MODE" = smoke ]; then
    PRESET=tiny; TRAIN_ITERS=tiny=5; RUN_ITERS=6; LOG_EVERY=3; CONV=(--preset tiny --steps 2 --warmup 1); DEMO=(--preset tiny --scenes 1
        --real-images 8 --frames 6 --eval-views 4 --seg-iterations 5); DEMO_MINUTES=${DEMO_MINUTES:-0.1}
    TRANSLATE=(--presets small --frames 4 --batch 2 --repeats 1 --precisions auto,fp32)  # as checks: bf16 on a CPU without it is emulated, slow
    COMPILED=(--presets small --frames 4 --batch 2 --repeats 1 --precisions auto,auto+compile); DATA=(--preset small --samples 3 --device "$DEV")
else
    PRESET=paper; TRAIN_ITERS=paper=20; RUN_ITERS=200; LOG_EVERY=50; CONV=(--preset paper); DEMO=(); DEMO_MINUTES=${DEMO_MINUTES:-4}
    TRANSLATE=(--presets paper --frames 64 --batch 16 --repeats 3 --end-to-end --precisions auto,fp32)
    COMPILED=(--presets paper --frames 64 --batch 16 --repeats 3 --end-to-end --precisions auto,auto+compile)
    DATA=(--samples 20 --device "$DEV")
fi

case "$MODE" in
checks|smoke)
    { "$PY" -c "import torch, platform; print(platform.platform()); print('torch', torch.__version__, 'cuda', torch.version.cuda,
'device', torch.cuda.get_device_name(0) if torch.cuda.is_available() else 'none')"; nvidia-smi 2>/dev/null | head -15; } \
        > "$W/environment.txt" 2>&1
    stage doctor 120 "$PY" -m sim2real.cli.main doctor --json --compile
    # the tests that need CUDA first (they skip on a CPU), then the device-clean and bf16 tests
    stage pytest_cuda 90 "$PY" -m pytest -q -p no:cacheprovider -k cuda tests
    stage pytest_device 90 "$PY" -m pytest -q -p no:cacheprovider -k "(device_clean or precision) and not cuda" tests
    # a real training run: loader workers by the worker rule, data-wait share and it/s from metrics.jsonl
    "$PY" - "$W/inputs" <<'PYEOF' > "$W/inputs.out" 2>&1
import sys
from pathlib import Path
import numpy as np
from PIL import Image
from sim2real.scene.procedural import generate_scene
base = Path(sys.argv[1]); (base / "real").mkdir(parents=True)
generate_scene(0).save(base / "scene")
rng = np.random.default_rng(0)
for k in range(8):
    Image.fromarray(rng.integers(0, 256, (480, 854, 3), dtype=np.uint8)).save(base / "real" / f"{k}.jpg", quality=90)
PYEOF
    stage train_run 180 "$PY" -m sim2real.cli.main train --preset "$PRESET" --scenes "$W/inputs/scene" \
        --real "$W/inputs/real" --out "$W/run" --iterations "$RUN_ITERS" --device "$DEV" --no-progress \
        --set log_every="$LOG_EVERY"
    [ -f "$W/run/metrics.jsonl" ] && "$PY" -c "
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
print(json.dumps({'train_run': [{k: r[k] for k in ('step', 'time/iterations_per_s', 'time/data_wait_s',
      'time/data_wait_share') if k in r} for r in rows]}))" "$W/run/metrics.jsonl" > "$W/train_run_metrics.json"
    rm -rf "$W/run/checkpoints"
    stage bench_train 120 "$PY" benchmarks/bench_train.py --device "$DEV" --presets "$PRESET" --iters "$TRAIN_ITERS"
    [ -n "${CONV_SHARE:-}" ] && stage bench_conv_share 120 "$PY" benchmarks/bench_conv_share.py --device "$DEV" "${CONV[@]}"
    stage bench_translate 120 "$PY" benchmarks/bench_translate.py --device "$DEV" "${TRANSLATE[@]}"
    stage bench_data 60 "$PY" benchmarks/bench_data.py "${DATA[@]}"
    # translate --compile (its first pass compiles: warmup_seconds), while the 10 minutes allow it
    [ "$SECONDS" -lt 450 ] && stage bench_translate_compiled 120 "$PY" benchmarks/bench_translate.py --device "$DEV" \
        "${COMPILED[@]}"
    NGPU=$("$PY" -c "import torch; print(torch.cuda.device_count())" 2>/dev/null || echo 0)
    if [ "${NGPU:-0}" -gt 1 ]; then
        stage ddp_run 90 "$PY" -m torch.distributed.run --standalone --nproc-per-node "$NGPU" -m sim2real.cli.main \
            train --preset small --scenes "$W/inputs/scene" --real "$W/inputs/real" --out "$W/ddp" --iterations 20 \
            --device cuda --no-progress --set log_every=10
        rm -rf "$W/ddp/checkpoints"
    fi
    [ "$MODE" = smoke ] || exit 0
    ;&
demo)
    D=$W/demo_out
    stage demo $((90 + ${DEMO_MINUTES%.*} * 60 + 240)) "$PY" -m sim2real.cli.main demo --out "$D" \
        --train --minutes "$DEMO_MINUTES" --device "$DEV" "${DEMO[@]}"
    if [ -d "$D/run/checkpoints" ]; then
        stage learn_stats 120 "$PY" benchmarks/learn_stats.py "$D/run" --texture-png "$W/textures"
        # keep the report, metrics, grids and video; drop what is large and can be made again
        rm -rf "$D/run/checkpoints" "$D/video/frames" "$D/video/ground_truth" "$D/real" "$D/scenes"
    fi
    ;;
*)
    echo "usage: $0 fetch|checks|demo|smoke" >&2
    exit 2
    ;;
esac
