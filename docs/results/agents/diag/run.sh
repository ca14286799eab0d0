#!/bin/bash
# SAC diagnostics: one change at a time, same budget, one process at a time
cd "$(git rev-parse --show-toplevel)" && export PYTHONPATH=$PWD MPLBACKEND=Agg  # in the project venv
STEPS=${STEPS:-40000}
run() { name=$1; shift; rm -rf runs/diag/$name
  /usr/bin/time -f "%e s wall" timeout 400 nice -n 5 python -m agents.train --algo sac --out runs/diag/$name --seed 0 \
    --steps $STEPS --eval-every 10000 --checkpoint-every 0 --no-progress "$@" > runs/diag/$name.log 2>&1; }
for spec in "$@"; do eval run $spec; done
