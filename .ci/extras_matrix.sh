#!/usr/bin/env bash
# Each extra is self-contained for what its docs say: in a fresh venv per extra, every
# script's documented use (cut short) either runs, or exits 2 with ONE line on stderr naming
# the extra to install (pip install -e ".[EXTRA]"). Not run by CI (it installs torch and ray
# several times); run it by hand before a release:
#
#     bash .ci/extras_matrix.sh                 # all extras
#     bash .ci/extras_matrix.sh . .[render]     # some of them
#
# Venvs go to $MATRIX_DIR (default /tmp/coop_loc_extras); a pip cache makes reinstalls fast.
# Prints PASS/FAIL per command and extra (SKIP: a command that evaluates a training run or
# runs BenchMARL where the venv could not make or run it); exits 1 if any command failed.
set -uo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
MATRIX_DIR=${MATRIX_DIR:-/tmp/coop_loc_extras}
EXTRAS=("$@")
[ ${#EXTRAS[@]} -eq 0 ] && EXTRAS=(. ".[render]" ".[train]" ".[rllib]" ".[torchrl]" ".[benchmarl]")
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 PYTHONHASHSEED=0 MPLBACKEND=Agg

# name | command (run from the repository root; $OUT is a scratch folder)
COMMANDS=(
  "run_episode|python scripts/run_episode.py --scenario outdoor_terrain --steps 20 --frame \$OUT/frame.png"
  "evaluate|python scripts/evaluate.py --scenario outdoor_terrain --policy fsm --episodes 1 --max-cycles 50 --json \$OUT/eval.json"
  "evaluate --plot-dir|python scripts/evaluate.py --policy fsm --episodes 1 --max-cycles 50 --plot-dir \$OUT --no-progress"
  "evaluate --config|python scripts/evaluate.py --config examples/configs/mixed_team.yaml --policy seek --episodes 1 --max-cycles 20 --no-progress"
  "evaluate --compare|python scripts/evaluate.py --compare fsm,random --episodes 2 --max-cycles 20 --plot-dir \$OUT --no-progress"
  "render_episode|python scripts/render_episode.py --policy fsm --max-cycles 20 --out \$OUT/episode.gif"
  "plot_trajectories|python scripts/plot_trajectories.py --scenario rendezvous --policies gather --set max_cycles=40 --out \$OUT/traj.png"
  "reproduce_madhavan|python scripts/reproduce_madhavan.py --json \$OUT/madhavan.json --plot \$OUT/madhavan.png"
  "replay_logs|python scripts/replay_logs.py tests/data/mrclam_excerpt --duration 20 --no-progress --plot \$OUT/replay.png"
  "train (sb3)|python scripts/train.py --scenario outdoor_terrain --timesteps 1000 --n-envs 1 --eval-freq 0 --no-progress --out \$OUT/ppo"
  "evaluate the sb3 run|test -f \$OUT/ppo/final_model.zip || exit 99; python scripts/evaluate.py --policy \$OUT/ppo --episodes 1 --max-cycles 20 --no-progress"
  "plot_training|test -f \$OUT/ppo/train_summary.json || exit 99; python scripts/plot_training.py --run \$OUT/ppo --out \$OUT/training.png"
  "train (rllib)|python scripts/train.py --backend rllib --scenario rendezvous --timesteps 1000 --num-env-runners 0 --out \$OUT/rllib"
  "evaluate the rllib run|test -d \$OUT/rllib/checkpoint || exit 99; python scripts/evaluate.py --scenario rendezvous --policy \$OUT/rllib --episodes 1 --max-cycles 20 --no-progress"
  "torchrl env|python scripts/bench/torchrl_step.py --scenario rendezvous --steps 20 --reps 1"
  "benchmarl one-liner|python -c 'import benchmarl' 2>/dev/null || exit 99; python -m benchmarl.run algorithm=mappo task=coop_loc/rendezvous experiment=coop_loc_short experiment.max_n_frames=200 experiment.on_policy_collected_frames_per_batch=200 experiment.on_policy_minibatch_size=100 experiment.evaluation_interval=200 task.max_cycles=50 hydra.run.dir=\$OUT/benchmarl"
)

failed=0
for extra in "${EXTRAS[@]}"; do
  name=$(echo "$extra" | tr -c 'a-z0-9\n' '_')
  venv="$MATRIX_DIR/venv$name"
  echo "=== $extra ($venv)"
  rm -rf "$venv"
  python3 -m venv "$venv"
  if ! "$venv/bin/python" -m pip install -q -e "$ROOT$( [ "$extra" = . ] || echo "${extra#.}")" \
      > "$MATRIX_DIR/install$name.log" 2>&1; then
    echo "FAIL  $extra: pip install (see $MATRIX_DIR/install$name.log)"; failed=1; continue
  fi
  OUT=$(mktemp -d "$MATRIX_DIR/out$name.XXXX")
  for entry in "${COMMANDS[@]}"; do
    label=${entry%%|*}
    cmd=${entry#*|}
    start=$(date +%s)
    err=$(PATH="$venv/bin:$PATH" OUT=$OUT timeout 900 bash -c "$cmd" 2>&1 >/dev/null)
    rc=$?
    secs=$(( $(date +%s) - start ))
    lines=$(printf '%s' "$err" | grep -c . || true)
    # stderr of a run that succeeded may hold warnings and progress bars; a refusal must be
    # exactly one line naming an extra
    if [ $rc -eq 99 ]; then
      echo "SKIP  $extra  $label: what it needs was not made in this venv"
    elif [ $rc -eq 0 ]; then
      echo "PASS  $extra  $label: ran (${secs} s)"
    elif [ $rc -eq 2 ] && [ "$lines" -eq 1 ] && printf '%s' "$err" | grep -q 'pip install -e "\.\['; then
      echo "PASS  $extra  $label: exit 2, $err"
    else
      echo "FAIL  $extra  $label: exit $rc, $lines lines on stderr; last: $(printf '%s' "$err" | tail -n 3 | tr '\n' ' ')"
      failed=1
    fi
  done
done
exit $failed
