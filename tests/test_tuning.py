"""RL Zoo + Optuna tuning as docs/agents-zoo.md runs it ("Tuning across machines"): two tuning
processes share one Optuna journal storage and get different trials.

Each process is rl_zoo3's own ``train`` with the documented flags (``-optimize``, ``--storage
FILE.log``: rl_zoo3 opens a JournalFileBackend, ``--study-name``, ``--max-total-trials``, TPE, the
median pruner), so the storage, the study created by one process and joined by the other, the
trial budget over both, the sampler of PPO's hyperparameters and the report are rl_zoo3's code.
Only the trial's training is replaced by a stand-in score of the sampled hyperparameters (a real
trial takes minutes here; training through rl_zoo3 is tests/test_rl_zoo.py's).  Each process holds
its first trial open until the other process has one too, so the two really ask the storage for
trials at the same time."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
pytest.importorskip("rl_zoo3")
optuna = pytest.importorskip("optuna")
ROOT = Path(__file__).resolve().parents[1]
TOTAL = 6  # --max-total-trials over both processes

CHILD = r'''
import json, sys, time
import rl_zoo3.exp_manager as em
import rl_zoo3.train
from rl_zoo3.hyperparams_opt import HYPERPARAMS_SAMPLER

me, other, out = sys.argv[1], sys.argv[2], sys.argv[3]
mine = []

def objective(self, trial):
    # rl_zoo3's own sampling of PPO's hyperparameters, then a stand-in for the training
    params = HYPERPARAMS_SAMPLER[self.algo](trial, self.n_actions, self.n_envs, {})
    trial.set_user_attr("process", me)
    mine.append(trial.number)
    if len(mine) == 1:  # hold the first trial open until the other process has one too
        deadline = time.monotonic() + 240
        while not any(t.user_attrs.get("process") == other for t in trial.study.get_trials(deepcopy=False)):
            if time.monotonic() > deadline:
                sys.exit(f"process {me}: the other process never got a trial")
            time.sleep(0.05)
    return -abs(params["learning_rate"] - 3e-4) * 1e3 - abs(params["gamma"] - 0.999)

em.ExperimentManager.objective = objective
sys.argv = ["rl_zoo3.train", *sys.argv[4:]]
rl_zoo3.train.train()
with open(out, "w") as fh:
    json.dump(mine, fh)
'''


def test_two_tuning_processes_share_one_journal_and_get_different_trials(tmp_path):
    storage = tmp_path / "optuna-ppo.log"
    script = tmp_path / "tune.py"
    script.write_text(CHILD)
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    env = {**os.environ, "PYTHONPATH": path, "MPLBACKEND": "Agg"}
    procs = []
    for me, other, seed in (("a", "b", 0), ("b", "a", 1)):
        # the documented command (docs/agents-zoo.md), one --seed per process
        cmd = [sys.executable, str(script), me, other, str(tmp_path / f"trials_{me}.json"),
               "--algo", "ppo", "--env", "ImpactCatch-v0", "--gym-packages", "impact_env",
               "--conf-file", str(ROOT / "agents" / "hyperparams" / "ppo.yml"),
               "-optimize", "--storage", str(storage), "--study-name", "impact-ppo",
               "--max-total-trials", str(TOTAL), "--n-jobs", "1", "--sampler", "tpe", "--pruner", "median",
               "-n", "1000", "--n-evaluations", "1", "--eval-episodes", "1", "--num-threads", "1",
               "--seed", str(seed), "--device", "cpu", "-f", str(tmp_path / f"logs_{me}"), "--no-optim-plots"]
        procs.append(subprocess.Popen(cmd, cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True))
    outs = []
    try:
        for p in procs:
            outs.append(p.communicate(timeout=600)[0])
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(30)
    for p, out in zip(procs, outs, strict=True):
        assert p.returncode == 0, out[-4000:]
    got = {me: json.loads((tmp_path / f"trials_{me}.json").read_text()) for me in ("a", "b")}
    assert got["a"] and got["b"], got  # both processes ran trials
    assert not set(got["a"]) & set(got["b"]), got  # no trial handed to both

    study = optuna.load_study(study_name="impact-ppo", storage=optuna.storages.JournalStorage(
        optuna.storages.journal.JournalFileBackend(str(storage))))
    trials = study.get_trials()
    numbers = [t.number for t in trials]
    assert sorted(numbers) == list(range(len(trials)))  # every trial once, none lost
    assert sorted(got["a"] + got["b"]) == numbers
    # the budget is the study's: TOTAL, plus at most one trial a process started before it saw the end
    assert TOTAL <= len(trials) <= TOTAL + 2, numbers
    assert all(t.state == optuna.trial.TrialState.COMPLETE for t in trials)
    for t in trials:
        assert t.user_attrs["process"] == ("a" if t.number in got["a"] else "b")
    # different seeds per process: no two trials drew the same hyperparameters
    drawn = [json.dumps(t.params, sort_keys=True) for t in trials]
    assert len(set(drawn)) == len(drawn), drawn
    for me in ("a", "b"):  # each process wrote rl_zoo3's report of the whole study
        assert list((tmp_path / f"logs_{me}" / "ppo").glob("report_ImpactCatch-v0_*.csv")), me
