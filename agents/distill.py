"""A privileged teacher distilled into a sensor student (DAgger), the student with a history.

    python -m agents.distill --teacher runs/final/ppo_priv_s0/best_model.zip --out runs/final/distill_h4 \\
        [--history 4] [--iterations 50] [--envs 64] [--epochs 4] [--seed 0] [--eval-episodes 16]

Why: a feedback policy on the true state (``observation="privileged"``) comes much closer to the
oracle than one on the sensors (docs/agents.md, the gap's decomposition), and RL on the sensors
alone has to find by trial what the teacher already does.  The student reads what a rig gives
(``observation="sensors"``) with the last ``history`` sensor frames, so that it can see a contact
start (the force's rise) and estimate what the teacher saw directly; it is trained to act as the
teacher does on the states the student itself visits (DAgger, Ross et al. 2011):

1. every iteration runs one whole episode per env, ``envs`` envs of the teacher's scene and
   options (hold, residual law, penalties) with ``observation="both"``, so that each step gives
   the student's input (the sensor entries of every frame, the past commands) and the teacher's
   (the true state of the newest frame); the command applied is the teacher's in env i with
   probability ``beta = 0.5 ** iteration`` (drawn per env and episode), the student's otherwise;
2. every step is kept with the teacher's deterministic action as the label (the data of all
   iterations together), and the student's actor is fitted to it by least squares on its
   deterministic action, ``epochs`` passes of minibatches of 4096 (Adam);
3. the student is evaluated on the validation drops (``agents.train``'s: 900000 + j, the whole
   horizon, no penalties) after each iteration; the best is kept.

The student reads the sensor frames, not its own past commands (which the observation's history
also holds: their first-layer weights are 0, unless ``--past-commands``): with them, a float32
build's rounding of one command fed back into the next ones, and the C export's float32 check of
such a student exceeded its bound (1.88e-4 of full scale against 1e-4 on drop 1 of ``rig``).
Without them the student still departs by up to 1.75e-4 on 3 of the 20 drops that
``scripts/agents_report.py`` checks (its 4 frames' differences amplify the float32 filters'
rounding), so the students are not shipped (docs/agents.md, "Issue 26's 1.2x / 1.3x goals");
a student trained to be robust to that rounding is the open step.  It is an SB3 PPO
``MlpPolicy`` (64x64 actor, the teacher's action bounds) on the sensor observation, saved as
``best_model.zip`` / ``model.zip`` with the settings files that ``impact-env compare``, the
export and the rig read: a model like any other of ``agents.train``, which runs compiled (its
history is part of the compiled observation).  Its critic is not
trained (it only acts; fine-tuning it with PPO from here was not tried).  ``model.json`` says
what it was distilled from, and keeps the run's wall and CPU time, the env's share and every
evaluation, as ``agents.train``'s does (``scripts/agents_report.py`` reads it).

Units: actions are fractions of the command scale (the teacher's bounds, e.g. +-1 = +-200 N on
``rig``), added to the residual law's command; a policy step is ``hold_ticks`` control periods;
``steps`` in ``model.json`` count policy steps, ``ticks`` control periods; the validation return is
minus the energy integral in ms (``agents.train``'s).

Seeds: env i starts from ``seed + i`` and draws its next drops from its own Generator; the
mixing draws and the minibatches come from ``numpy.random.default_rng(seed)`` and torch's seed
``seed``: one seed, one result (on one machine and torch build; ``tests/test_agents.py`` checks
that two runs give the same student).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from impact_env.config import ConfigError


def _settings(teacher: Path) -> dict:
    for p in (teacher.with_suffix(".json"), teacher.parent / "model.json"):
        if p.is_file():
            return json.loads(p.read_text())
    raise ConfigError(f"--teacher {str(teacher)!r}: no settings file beside it (agents.train writes one)")


def distill(teacher, out, *, history: int = 4, iterations: int = 50, envs: int = 64, epochs: int = 4,
            seed: int = 0, eval_episodes: int = 16, eval_seed: int = 900_000, lr: float = 1e-3,
            batch_size: int = 4096, torch_threads: int = 1, past_commands: bool = False,
            log=sys.stderr) -> dict:
    """Distil ``teacher`` (an SB3 PPO model on ``observation="privileged"``, history 1) into a sensor
    student in ``out``; returns the student's ``model.json`` content."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor

    from agents.callbacks import FixedSeeds, StepTimer
    from agents.policies import actor_indices
    from agents.train import TEST_EPISODES, TEST_SEED, _load_average, _versions
    from impact_env.control.observation import make_layout
    from impact_env.env.sb3_vecenv import make_sb3_vec_env
    from impact_env.env.task import EVALUATION_OPTIONS
    from impact_env.scene import load_scene

    teacher, out = Path(teacher), Path(out)
    meta_t = _settings(teacher)
    if meta_t.get("observation") != "privileged" or int(meta_t.get("history", 1)) != 1:
        raise ConfigError(f"--teacher {str(teacher)!r} must read observation 'privileged' with history 1 "
                          f"(it reads {meta_t.get('observation')!r}, history {meta_t.get('history')})")
    for name, v, lo in (("history", history, 1), ("iterations", iterations, 1), ("envs", envs, 1),
                        ("epochs", epochs, 1), ("eval_episodes", eval_episodes, 1), ("seed", seed, 0)):
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise ConfigError(f"{name} = {v!r} must be an integer >= {lo}")
    if seed < TEST_SEED + TEST_EPISODES and TEST_SEED < seed + envs:
        raise ConfigError(f"training seeds {seed}..{seed + envs - 1} meet the test drops {TEST_SEED}.."
                          f"{TEST_SEED + TEST_EPISODES - 1}")
    if (out / "model.json").exists():
        raise ConfigError(f"--out {str(out)!r} already holds a run; choose another folder")
    torch.set_num_threads(torch_threads)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)

    scene_name, overrides = meta_t["scene"], meta_t.get("overrides") or None
    kw = {k: v for k, v in (meta_t.get("env_kwargs") or {}).items() if k not in ("observation", "history")}
    scene = load_scene(scene_name, overrides)
    both = make_layout(scene, "both", history)
    sensors = make_layout(scene, "sensors", 1)
    F, S = both.frame_size, sensors.frame_size
    student_idx = np.asarray(actor_indices(F, S, history))
    teacher_idx = np.arange(S, F)  # the true state of the newest frame: the teacher's observation

    teacher_model = PPO.load(str(teacher), device="cpu")
    low, high = float(teacher_model.action_space.low[0]), float(teacher_model.action_space.high[0])
    # the student: a PPO MlpPolicy on the sensor observation, built from the sensor env's spaces
    sensor_env = make_sb3_vec_env(scene_name, num_envs=1, monitor=False, overrides=overrides,
                                  **{**kw, "observation": "sensors", "history": history})
    student = PPO("MlpPolicy", sensor_env, device="cpu", seed=seed, n_steps=8, batch_size=8,
                  policy_kwargs={"net_arch": {"pi": [64, 64], "vf": [64, 64]}, "log_std_init": -2.5})
    if student.observation_space.shape[0] != len(student_idx):
        raise ConfigError(f"the student's observation has {student.observation_space.shape[0]} entries, the "
                          f"layout {len(student_idx)}")
    pol = student.policy
    # the past commands at the end of the sensor observation (history > 1): unless past_commands, the
    # student's first layer gives them weight 0 (set here, and the inputs are masked while it learns,
    # so they stay 0): its command is then a function of the sensor frames alone, with no loop from
    # its own output back to its input, in which a float32 build's rounding would accumulate
    mask = torch.ones(len(student_idx))
    if history > 1 and not past_commands:
        mask[history * S:] = 0.0
        with torch.no_grad():
            pol.mlp_extractor.policy_net[0].weight[:, history * S:] = 0.0
    params = list(pol.mlp_extractor.policy_net.parameters()) + list(pol.action_net.parameters())
    opt = torch.optim.Adam(params, lr=lr)

    venv = StepTimer(make_sb3_vec_env(scene_name, num_envs=envs, monitor=False, overrides=overrides,
                                      **{**kw, "observation": "both", "history": history}))
    venv.seed(seed)
    obs = venv.reset()
    steps_per_episode = int(round(float(kw.get("horizon", scene.episode.horizon))
                                  / (scene.control_period * int(kw.get("hold_ticks", 1)))))
    eval_kw = {**kw, **EVALUATION_OPTIONS, "observation": "sensors", "history": history}
    eval_env = VecMonitor(FixedSeeds(make_sb3_vec_env(scene_name, num_envs=eval_episodes, monitor=False,
                                                      overrides=overrides, **eval_kw), eval_seed))

    def act_teacher(o):
        a, _ = teacher_model.predict(o[:, teacher_idx], deterministic=True)
        return np.clip(a, low, high)

    def act_student(o):
        a, _ = student.predict(o, deterministic=True)
        return np.clip(a, low, high)

    def evaluate() -> float:
        o = eval_env.reset()
        total, done = np.zeros(eval_episodes), np.zeros(eval_episodes, dtype=bool)
        while not done.all():
            o, r, d, _ = eval_env.step(act_student(o))
            total += np.where(done, 0.0, r)
            done |= d
        return float(total.mean())

    out.mkdir(parents=True, exist_ok=True)
    X, Y = [], []
    history_log, best = [], None
    load0, cpu0, t0 = _load_average(), time.process_time(), time.perf_counter()
    eval_time, env0 = 0.0, venv.seconds
    for it in range(iterations):
        beta = 0.5 ** it
        use_teacher = rng.random(envs) < beta
        for _ in range(steps_per_episode):
            a_t = act_teacher(obs)
            a_s = act_student(obs[:, student_idx])
            X.append(obs[:, student_idx].astype(np.float32))
            Y.append(a_t.astype(np.float32))
            obs, _, dones, _ = venv.step(np.where(use_teacher[:, None], a_t, a_s))
            if dones.any():  # every episode is the whole horizon: all envs end together
                use_teacher = rng.random(envs) < beta
        x = torch.as_tensor(np.concatenate(X))
        y = torch.as_tensor(np.concatenate(Y))
        n = len(x)
        for _ in range(epochs):
            perm = torch.as_tensor(rng.permutation(n))
            for k in range(0, n, batch_size):
                idx = perm[k:k + batch_size]
                mean = pol.action_net(pol.mlp_extractor.forward_actor(pol.extract_features(x[idx] * mask)))
                loss = torch.mean((mean - y[idx]) ** 2)
                opt.zero_grad()
                loss.backward()
                opt.step()
        last_loss = float(loss.detach())
        t_eval = time.perf_counter()
        ret = evaluate()
        wall = t_eval - t0 - eval_time
        eval_time += time.perf_counter() - t_eval
        step = (it + 1) * steps_per_episode * envs
        history_log.append({"step": step, "wall_s": round(wall, 3), "env_s": round(venv.seconds - env0, 3),
                            "return": round(ret, 4), "beta": beta, "loss": round(last_loss, 6)})
        log.write(f"distill: iteration {it + 1}/{iterations} (beta {beta:.3f}, {n} samples), loss "
                  f"{last_loss:.2e}, validation return {ret:.2f}, {wall:.0f} s\n")
        log.flush()
        if best is None or ret > best["mean_reward"]:
            best = {"step": step, "mean_reward": ret, "wall_s": round(wall, 3)}
            student.save(out / "best_model.zip")
    wall = time.perf_counter() - t0
    cpu = time.process_time() - cpu0
    load = [load0, _load_average()]
    student.save(out / "model.zip")

    # the residual's law alone on the same validation drops: action 0
    eval_env.reset()
    total, done = np.zeros(eval_episodes), np.zeros(eval_episodes, dtype=bool)
    while not done.all():
        _, r, d, _ = eval_env.step(np.zeros((eval_episodes, 1), np.float32))
        total += np.where(done, 0.0, r)
        done |= d
    law = float(total.mean())
    best["residual_law"] = kw.get("residual")
    best["residual_law_return"] = law
    best["first_beats_law"] = next((h for h in history_log if h["return"] > law), None)
    best["drops"] = [eval_seed, eval_seed + eval_episodes - 1]
    best["evaluations"] = len(history_log)
    steps = iterations * steps_per_episode * envs
    hold = int(kw.get("hold_ticks", 1))
    env_kwargs = {**kw, "observation": "sensors", "history": history}
    meta = {"algo": "ppo", "label": f"distill-h{history}{'pc' if past_commands else ''}-s{seed}", "observation": "sensors",
            "history": history,
            "scene": scene_name, "overrides": meta_t.get("overrides") or {}, "env_kwargs": env_kwargs,
            "hold_ticks": hold, "residual": kw.get("residual"), "steps": steps, "ticks": steps * hold,
            "envs": envs, "seed": seed, "wall_time_s": round(wall, 2), "steps_per_s": round(steps / wall, 1),
            "ticks_per_s": round(steps * hold / wall, 1), "env_time_s": round(venv.seconds, 4),
            "env_share": round(venv.seconds / max(wall, 1e-9), 4), "torch_threads": torch_threads,
            "load_average": load, "cpu_time_s": round(cpu, 2), "policy": "MlpPolicy",
            "hyperparameters": {"iterations": iterations, "epochs": epochs, "learning_rate": lr,
                                "batch_size": batch_size, "net_arch": [64, 64],
                                "past_commands": past_commands},
            "distilled_from": {"teacher": str(teacher), "teacher_observation": "privileged",
                               "method": "DAgger, beta = 0.5 ** iteration",
                               "note": "the critic is not trained (the student only acts)"},
            "validation": {"seeds": best["drops"], "best": best, "history": history_log},
            "versions": _versions(), "interrupted": False}
    (out / "model.json").write_text(json.dumps(meta, indent=2, default=str) + "\n")
    best_meta = {**meta, "steps": best["step"]}
    (out / "best_model.json").write_text(json.dumps(best_meta, indent=2, default=str) + "\n")
    venv.close()
    eval_env.close()
    return meta


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m agents.distill", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--teacher", required=True, help="an SB3 PPO model.zip on observation 'privileged'")
    p.add_argument("--out", required=True, help="the student's run folder")
    p.add_argument("--history", type=int, default=4, help="frames (and past commands) the student reads")
    p.add_argument("--iterations", type=int, default=50,
                   help="DAgger iterations (one episode per env each)")
    p.add_argument("--envs", type=int, default=64)
    p.add_argument("--epochs", type=int, default=4, help="passes over all the data after each iteration")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eval-episodes", type=int, default=16)
    p.add_argument("--torch-threads", type=int, default=1)
    p.add_argument("--past-commands", action="store_true",
                   help="let the student read its own past commands (the observation's history holds "
                        "them); by default their weights are 0: a float32 build's rounding then has no "
                        "loop to grow in")
    a = p.parse_args(argv)
    try:
        meta = distill(a.teacher, a.out, history=a.history, iterations=a.iterations, envs=a.envs,
                       epochs=a.epochs, seed=a.seed, eval_episodes=a.eval_episodes,
                       torch_threads=a.torch_threads, past_commands=a.past_commands)
    except ConfigError as exc:
        print(f"agents.distill: {exc}", file=sys.stderr)
        return 2
    b = meta["validation"]["best"]
    verdict = "beats it" if b["mean_reward"] > b["residual_law_return"] else "does NOT beat it"
    print(f"{meta['label']}: {meta['steps']} policy steps in {meta['wall_time_s']:.0f} s (the env "
          f"{100 * meta['env_share']:.0f} %); validation energy integral {-b['mean_reward']:.2f} ms (best, "
          "iteration "
          f"{b['step'] // (meta['steps'] // meta['hyperparameters']['iterations'])}) against "
          f"{b['residual_law']}'s {-b['residual_law_return']:.2f} ms: {verdict}; saved "
          f"{a.out}/best_model.zip")
    return 0


if __name__ == "__main__":
    sys.exit(main())
