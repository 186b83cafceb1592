#!/bin/bash
# issue 42 ablations at fixed-length episodes: temperature start x replay sampling, 5 seeds, one task.
# Run from the repository root of a clone at e84d9da: bash bench/results/fixed_length_ablation/run_task.sh TASK
# (as run: from a frozen clone, into a scratch folder, files renamed to these after the run). On a tree after
# 25d44ac, ours_fixed has a default fixed-length setting; --fixed-set none keeps the preset as these runs had it.
task=$1
commit=$(git rev-parse --short HEAD)
for v in "base:" "alpha1:--set sac.alpha=1" "uniform:--set replay.priority_exponent=0" "alpha1_uniform:--set sac.alpha=1 --set replay.priority_exponent=0"; do
  name=${v%%:*}; sets=${v#*:}
  none=$(grep -q OURS_FIXED bench/time_to_success.py && echo "--fixed-set none")
  echo "=== $task $name start $(date -u +%FT%TZ)"
  python bench/time_to_success.py --tasks $task --contenders ours_fixed --seeds 5 --max-steps 30000 $sets $none \
     --out bench/results/fixed_length_ablation/${task}_${name}_cpuB_${commit}.json
  echo "=== $task $name rc $? end $(date -u +%FT%TZ)"
done
