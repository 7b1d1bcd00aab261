#!/usr/bin/env bash
# The study against real footage (docs/footage.md, "A study against real footage"), rerunnable:
#
#   benchmarks/footage_study.sh STUDY NAME=SRC[,SRC...] [NAME=SRC[,SRC...] ...]
#
# e.g. benchmarks/footage_study.sh /data/study cholec=/data/cholec_frames,/data/cholecseg_frames \
#                                  prostate=/data/prostatectomy_frames
#
# SRC are what `sim2real realset` takes (videos and folders of frames). Everything is written
# under STUDY (never into the repository): the demo's simulated scenes (seeds 0 and 1, those of the
# shipped model) and its 100-frame test trajectory, per NAME a real set, a run trained from the
# shipped model with the cpu preset, its translation of the trajectory, its evaluation against
# the real set, the border measure (benchmarks/footage_borders.py) and the real held-out reference
# row (benchmarks/realset_reference.py); the shipped model is
# translated and evaluated against each real set as the "before" row.
#
# NAME=plain:DIR trains on DIR as a plain folder of whole frames (no real set, no content mask):
# the comparison that shows what the mask prevents.
#
# Trainings run one at a time on one core: CORE (default 1), MINUTES (default 25) per run.
# Rerunning skips what is done; a run cut short resumes (--resume) for another MINUTES.
# SIM2REAL (default: the sim2real on PATH) and PYTHON (default python) name the tools.
set -euo pipefail

if [ $# -lt 2 ]; then
    sed -n '2,8p' "$0" >&2
    exit 2
fi
STUDY=$1; shift
MINUTES=${MINUTES:-25}
CORE=${CORE:-1}
SIM2REAL=${SIM2REAL:-sim2real}
PYTHON=${PYTHON:-python}
HERE=$(cd "$(dirname "$0")" && pwd)
export OMP_NUM_THREADS=1
pin() { nice -n 10 taskset -c "$CORE" "$@"; }

mkdir -p "$STUDY"
for seed in 0 1; do
    [ -d "$STUDY/scenes/sim_$seed" ] || pin "$SIM2REAL" scene generate --seed "$seed" --out "$STUDY/scenes/sim_$seed"
done
TRAJ=$STUDY/trajectory.txt
[ -f "$TRAJ" ] || pin "$SIM2REAL" scene trajectory "$STUDY/scenes/sim_0" --frames 100 --height 128 --width 256 \
    --seed 0 --out "$TRAJ"
[ -d "$STUDY/shipped_run" ] || "$PYTHON" -c "from sim2real import shipped; shipped.install_run('$STUDY/shipped_run')"
[ -f "$STUDY/translate_shipped/translate.json" ] || pin "$SIM2REAL" translate "$STUDY/shipped_run" \
    --scene "$STUDY/scenes/sim_0" --trajectory "$TRAJ" --out "$STUDY/translate_shipped" --no-progress

evaluate() {  # RUN REAL OUT
    [ -f "$3/metrics.json" ] || pin "$SIM2REAL" evaluate "$1" --scenes "$STUDY/scenes/sim_0" --trajectory "$TRAJ" \
        --real "$2" --out "$3" --workers 1 --no-progress
}

all=()
for spec in "$@"; do
    name=${spec%%=*}
    srcs=${spec#*=} run=$STUDY/run_$name
    if [ "${srcs#plain:}" != "$srcs" ]; then
        real=${srcs#plain:} srcs=${srcs#plain:}
    else
        real=$STUDY/real_$name
        IFS=, read -r -a list <<< "$srcs"
        [ -f "$real/manifest.json" ] || pin "$SIM2REAL" realset "${list[@]}" --out "$real"
    fi
    if [ ! -f "$run/trained" ]; then
        if [ -f "$run/checkpoints/last.pt" ]; then
            pin "$SIM2REAL" train --out "$run" --resume --max-minutes "$MINUTES" --no-progress
        else
            pin "$SIM2REAL" train --init-from shipped --preset cpu --scenes "$STUDY/scenes/sim_0" "$STUDY/scenes/sim_1" \
                --real "$real" --out "$run" --max-minutes "$MINUTES" --set data.workers=1 --no-progress
        fi
        touch "$run/trained"
    fi
    [ -f "$STUDY/translate_$name/translate.json" ] || pin "$SIM2REAL" translate "$run" --scene "$STUDY/scenes/sim_0" \
        --trajectory "$TRAJ" --out "$STUDY/translate_$name" --no-progress
    evaluate "$STUDY/shipped_run" "$real" "$STUDY/eval_shipped_$name"
    evaluate "$run" "$real" "$STUDY/eval_$name"
    pin "$PYTHON" "$HERE/footage_borders.py" --scene "$STUDY/scenes/sim_0" --trajectory "$TRAJ" \
        --translated shipped="$STUDY/translate_shipped" "$name=$STUDY/translate_$name" \
        --real "$name=$real" "${name}_whole_frames=$srcs" \
        --figure "$STUDY/borders_$name.png" --json "$STUDY/borders_$name.json" > /dev/null
    [ ! -f "$real/manifest.json" ] || pin "$PYTHON" "$HERE/realset_reference.py" "$real" > "$STUDY/realref_$name.json"
    all+=("$name=$STUDY/translate_$name")
    echo "$name: $STUDY/eval_$name/report.html, $STUDY/borders_$name.json, $STUDY/borders_$name.png"
done
# every run's translation of the same views in one figure (simulated views only)
pin "$PYTHON" "$HERE/footage_borders.py" --scene "$STUDY/scenes/sim_0" --trajectory "$TRAJ" \
    --translated shipped="$STUDY/translate_shipped" "${all[@]}" \
    --figure "$STUDY/borders_all.png" --json "$STUDY/borders_all.json" > /dev/null
echo "all: $STUDY/borders_all.png, $STUDY/borders_all.json"
