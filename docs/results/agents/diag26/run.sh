#!/bin/bash
# Issue 26's diagnostic runs: one change at a time, seed 0, one process at a time, nice 19, on the
# 2-core machine shared with two other engineers.  Each argument pair is NAME "OPTIONS"; series.log
# (kept here) holds every run's options, the uptime before and after, and the run's last lines.
#   docs/results/agents/diag26/run.sh p64a "--algo ppo --seed 0 --envs 64 --hp n_steps=1000 --hp n_epochs=5 --steps 1000000 --eval-every 64000" ...
#   python docs/results/agents/diag26/collect.py runs/x      # NAME.json: what docs/agents-results.md's tables read
cd "$(git rev-parse --show-toplevel)" && export PYTHONPATH=$PWD
mkdir -p runs/x
while [ $# -gt 0 ]; do
  name=$1; args=$2; shift 2
  echo "=== $name: $args  ($(uptime))" >> runs/x/series.log
  /usr/bin/time -f "%e s wall %U user" nice -n 19 python -m agents.train --out runs/x/$name --checkpoint-every 0 \
    --no-progress $args > runs/x/$name.log 2>&1
  tail -5 runs/x/$name.log >> runs/x/series.log
  echo "load after: $(uptime)" >> runs/x/series.log
done
