#!/bin/bash
# The three searches of this directory, run from the repository root at the same time: the
# three-scenario searches of ../three_scenarios again (the same space, objective, sampler seed,
# training seeds 1000-1002, the slow circle, the fast circle and the push, the hard constraints
# and the robot's reflexes on), now with the joint-position observer on
# (mpc.position_observer_time 0.1 s) and with that directory's fixed free-space settings
# (c4 in free space 1000, the velocity box at 70 % of the limits). Trial 0 is the scenario
# files' weights; trial 1 that directory's best (free_space_candidate.yaml). 16 trials each.
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
D=benchmarks/results/tune/train1000-1002/observer
T=benchmarks/results/tune/train1000-1002
TRIALS=${TRIALS:-16}
for f in torque_feedback classical force_feedback; do
  ( s=$(date +%s)
    .venv/bin/ffmpc tune $f --scenario polishing --scenario polishing_fast --scenario push \
      --seeds 3 --first-seed 1000 --trials $TRIALS --workers 1 --sampler-seed 0 \
      --start-from $T/three_scenarios/free_space_candidate.yaml \
      --set mpc.position_observer_time=0.1 \
      --set mpc.weights.$f.ee_position_free=1000 \
      --set mpc.constraints.velocity_margin=0.3 \
      --storage $D/tune.db --study-name observer-$f --cache-dir /tmp/ffmpc-tune-cache-obs \
      --out $D/tuned_$f.yaml \
      >> $D/tune_$f.log 2>&1
    echo "$f rc=$? $(( $(date +%s) - s )) s" >> $D/tune_times.txt ) &
  sleep 20
done
wait
