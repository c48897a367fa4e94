#!/bin/bash
# The classical and torque-feedback searches (24 trials each), run from the repository root at
# the same time as each other; the force-feedback search (tune.sh) was stopped after 24
# completed trials, so that the three have the same budget.
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
D=benchmarks/results/tune/train1000-1002/constrained
P=benchmarks/results/tune/train1000-1002/predictor_friction/tuned_weights.yaml
for f in classical torque_feedback; do
  sets=$(grep "^mpc.weights.$f\." $P | sed 's/: /=/' | sed 's/^/--set /' | tr '\n' ' ')
  ( s=$(date +%s)
    .venv/bin/ffmpc tune $f --seeds 3 --first-seed 1000 --trials 24 --workers 2 --sampler-seed 0 \
       --storage $D/tune_$f.db --study-name polishing-$f-constrained $sets \
       --out $D/tuned_$f.yaml > $D/tune_$f.log 2>&1
    echo "$f rc=$? $(( $(date +%s) - s )) s" >> $D/tune_times.txt ) &
done
wait
