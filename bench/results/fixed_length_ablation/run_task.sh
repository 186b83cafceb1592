#!/bin/bash
# issue 42 ablations at fixed-length episodes: temperature start x replay sampling, 5 seeds, one task
task=$1
cd /work/frozen42
for v in "base:" "alpha1:--set sac.alpha=1" "uniform:--set replay.priority_exponent=0" "alpha1_uniform:--set sac.alpha=1 --set replay.priority_exponent=0"; do
  name=${v%%:*}; sets=${v#*:}
  echo "=== $task $name start $(date -u +%FT%TZ)"
  python bench/time_to_success.py --tasks $task --contenders ours_fixed --seeds 5 --max-steps 30000 $sets \
     --out /work/abl/tts_fixed_${task}_${name}.json
  echo "=== $task $name rc $? end $(date -u +%FT%TZ)"
done
