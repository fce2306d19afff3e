#!/usr/bin/env bash
# The default configuration over five seeds (docs/protocol.md, "Registered: the default
# configuration over five seeds"): train seeds 1-4 with configs/ as committed, then evaluate each
# final policy once on the sealed test split. Resumable: rerun it; a trained run is not retrained,
# an evaluated one not re-evaluated, a stopped training resumes from its last checkpoint.
#
#   tools/default_seeds.sh OUT_DIR        # run from the repository root (or a worktree of it)
set -euo pipefail
out=${1:?usage: tools/default_seeds.sh OUT_DIR}
py=${PYTHON:-.venv/bin/python}
mkdir -p "$out"
for seed in 1 2 3 4; do
  run="$out/ahrm-default-seed$seed"
  if [ ! -f "$run/policy.pt" ]; then
    if [ -d "$run/checkpoints" ] && ls "$run/checkpoints" | grep -q .; then
      "$py" -m ahrm_stack.train --resume "$run" --no-progress
    else
      rm -rf "$run"
      "$py" -m ahrm_stack.train "train.seed=$seed" --run-dir "$run" --no-progress
    fi
  fi
  if [ ! -f "$run/suite-test/suite.json" ]; then
    "$py" -m ahrm_stack.evaluate "$run" --suite --split test
  fi
done
