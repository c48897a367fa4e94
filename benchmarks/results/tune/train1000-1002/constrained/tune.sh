#!/bin/bash
# The three searches of this directory, run from the repository root: the hard constraints and
# the robot's reflexes on (the scenario defaults), the same search space, budget (48 trials),
# training seeds (1000-1002) and sampler seed for the three formulations. Each search's first
# trial is the weights of the previous searches (../predictor_friction/tuned_weights.yaml).
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
D=benchmarks/results/tune/train1000-1002/constrained
P=benchmarks/results/tune/train1000-1002/predictor_friction/tuned_weights.yaml
for f in force_feedback classical torque_feedback; do
  sets=$(grep "^mpc.weights.$f\." $P | sed 's/: /=/' | sed 's/^/--set /' | tr '\n' ' ')
  s=$(date +%s)
  .venv/bin/ffmpc tune $f --seeds 3 --first-seed 1000 --trials 48 --workers 2 --sampler-seed 0 \
     --storage $D/tune.db --study-name polishing-$f-constrained $sets \
     --out $D/tuned_$f.yaml > $D/tune_$f.log 2>&1
  echo "$f rc=$? $(( $(date +%s) - s )) s" >> $D/tune_times.txt
done
