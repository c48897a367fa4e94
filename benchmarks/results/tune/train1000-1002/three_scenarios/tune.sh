#!/bin/bash
# The three searches of this directory, run from the repository root at the same time: the same
# space, objective, budget, training seeds (1000-1002) and sampler seed for the three
# formulations, each trial running the slow circle (polishing), the fast circle
# (polishing_fast) and the push (push, its force rising and falling over 0.05 s) on every
# training seed, with the hard constraints and the robot's reflexes on (the scenario defaults).
# Trial 0 is the scenario files' weights at the time; trials 1 and 2 the earlier searches' best
# (--start-from). 12 trials, then the same command with --trials 8 (20 in all).
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
D=benchmarks/results/tune/train1000-1002/three_scenarios
T=benchmarks/results/tune/train1000-1002
TRIALS=${TRIALS:-12}
for f in torque_feedback classical force_feedback; do
  ( s=$(date +%s)
    .venv/bin/ffmpc tune $f --scenario polishing --scenario polishing_fast --scenario push \
      --seeds 3 --first-seed 1000 --trials $TRIALS --workers 1 --sampler-seed 0 \
      --start-from $T/predictor_friction/tuned_weights.yaml \
      --start-from $T/constrained/tuned_weights.yaml \
      --storage $D/tune.db --study-name three-scenarios-$f --cache-dir /tmp/ffmpc-tune-cache \
      >> $D/tune_$f.log 2>&1
    echo "$f rc=$? $(( $(date +%s) - s )) s" >> $D/tune_times.txt ) &
  sleep 20
done
wait
