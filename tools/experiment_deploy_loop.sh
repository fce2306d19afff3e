#!/usr/bin/env bash
# The experiment's final policies through the deploy loop (docs/protocol.md, "Registered: the
# experiment's policies through the deploy loop"): every finished run of OUT's grid whose final
# policy.pt exists goes through `python -m ahrm_stack.robustness RUN --no-dose` (the jaco2
# profile, 30 episodes of the robustness seed range per condition, the scripted controller on
# the same episodes) into OUT/robustness/<run>. Resumable: a judged run is skipped. Unfinished
# runs and runs whose policy is lost are skipped and named.
#
#   tools/experiment_deploy_loop.sh OUT        # run from the repository root (or a worktree of it)
set -euo pipefail
out=${1:?usage: tools/experiment_deploy_loop.sh OUT}
py=${PYTHON:-.venv/bin/python}
[ -f "$out/grid.json" ] || { echo "error: $out/grid.json not found: OUT must be an experiment folder" >&2; exit 2; }
for name in $("$py" -c 'import json, sys; print(" ".join(r["name"] for r in json.load(open(sys.argv[1]))["runs"]))' "$out/grid.json"); do
  run="$out/runs/$name"
  if [ -f "$out/robustness/$name/robustness.json" ]; then
    echo "$name: judged before, skipped"
  elif [ ! -f "$run/done.json" ]; then
    echo "$name: not finished, skipped"
  elif [ ! -f "$run/policy.pt" ]; then
    echo "$name: finished, but its final policy is lost, skipped"
  else
    "$py" -m ahrm_stack.robustness "$run" --no-dose --out "$out/robustness/$name"
  fi
done
