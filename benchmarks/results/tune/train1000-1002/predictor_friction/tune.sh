#!/bin/bash
# The three searches of this directory, run from the repository root (commit 6e1c76b).
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
for f in classical torque_feedback force_feedback; do
  s=$(date +%s)
  .venv/bin/ffmpc tune $f --seeds 3 --first-seed 1000 --trials 48 --workers 2 --sampler-seed 0 \
     --storage benchmarks/results/tune/train1000-1002/predictor_friction/tune.db --study-name polishing-$f-friction \
     --out benchmarks/results/tune/train1000-1002/predictor_friction/tuned_$f.yaml > benchmarks/results/tune/train1000-1002/predictor_friction/tune_$f.log 2>&1
  echo "$f rc=$? $(( $(date +%s) - s )) s" >> benchmarks/results/tune/train1000-1002/predictor_friction/tune_times.txt
done
