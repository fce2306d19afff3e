#!/usr/bin/env bash
# The two missing rows of the default policy's comparison with its teacher (docs/protocol.md,
# "Registered: the clone-only rows and the teacher at the policy's speed cap"): for each committed
# default seed, its clone retrained from the committed config (demonstrations, behaviour cloning and
# DAgger, stopped after one PPO episode; the clone is the policy before any PPO update) and read once
# on the sealed test suite; and the scripted controller at the policy's tip speed cap on the same
# test suite. Resumable: a finished step is skipped.
#
#   tools/reanalysis_rows.sh OUT_DIR        # from the repository root (or a worktree of it)
set -euo pipefail
out=${1:?usage: tools/reanalysis_rows.sh OUT_DIR}
py=${PYTHON:-.venv/bin/python}
mkdir -p "$out"
for seed in 0 1 2 3 4; do
  run="$out/clone-seed$seed"
  if [ ! -f "$run/policies/clone.pt" ]; then
    rm -rf "$run" && mkdir -p "$run"
    cp "docs/policies/ahrm-default-seed$seed/config.yaml" "$run/config.yaml"
    "$py" -m ahrm_stack.train --resume "$run" train.episodes=1 train.eval_episodes=0 train.eval_every=0 --no-progress
  fi
  if [ ! -f "$run/suite-clone-test/suite.json" ]; then
    "$py" -m ahrm_stack.evaluate "$run" --suite --split test --no-scripted --policy-file "$run/policies/clone.pt"
  fi
done
cap=$("$py" -c "import yaml; print(yaml.safe_load(open('configs/task.yaml'))['action']['cartesian_max_speed'])")
if [ ! -f "$out/scripted-at-policy-cap/suite.json" ]; then
  "$py" -m ahrm_stack.evaluate --policy scripted --suite --split test --out "$out/scripted-at-policy-cap" \
    --config "scripted.travel_speed=$cap" "scripted.push_speed=$cap"
fi
