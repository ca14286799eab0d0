"""A privileged teacher distilled into a sensor student (DAgger), the student with a history.

    python -m agents.distill --teacher runs/final/ppo_priv_s0/best_model.zip --out runs/final/distill_h4 \\
        [--history 4] [--iterations 50] [--envs 64] [--epochs 4] [--seed 0] [--eval-episodes 16]

Why: a feedback policy on the true state (``observation="privileged"``) comes much closer to the
oracle than one on the sensors (docs/agents-results.md, the gap's decomposition), and RL on the sensors
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

With ``--teacher law:NAME`` the teacher is a compiled classic law of the registry (``mpc-state``,
``thesis-ideal``, ...; :mod:`agents.law_teacher`) on the true state of the frames the student
visits, every control period: the run's scene and options are ``agents/hyperparams/ppo.yml``'s
(or ``--scene`` / ``--env-kwargs``) at ``hold_ticks`` 1, the label is the whole command (or, with
a residual law, the teacher's command less that law's), and the run is judged against the teacher
itself on the validation drops.  ``--student-observation both`` gives the student the true state
too, which separates what the sensors cannot see (the information) from what DAgger does not
learn.  ``python -m agents.train --quick --teacher law:NAME`` is this with a one-minute budget.
A law whose memory models its own demands' effect (``mpc-state``'s shaker model) is told the
command each env applied (:meth:`agents.law_teacher.LawTeacher.applied`), so that its labels
hold where the student or ``--teacher-noise`` acted.  ``--mixing M`` sets ``beta = M **
iteration`` (1 with ``--teacher-noise``: DART, the teacher always in control); ``--ignore
CHANNEL`` gives a sensor channel weight 0, as the past commands below.

The student reads the sensor frames, not its own past commands (which the observation's history
also holds: their first-layer weights are 0, unless ``--past-commands``): with them, a float32
build's rounding of one command fed back into the next ones, and the C export's float32 check of
such a student exceeded its bound (1.88e-4 of full scale against 1e-4 on drop 1 of ``rig``).
Without them the student still departs by up to 1.75e-4 on 3 of the 20 drops that
``scripts/agents_report.py`` checks (its 4 frames' differences amplify the float32 filters'
rounding), so the students are not shipped (docs/agents-results.md, the 1.2x / 1.3x goals);
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

from agents import law_teacher
from impact_env.config import ConfigError


def _settings(teacher: Path) -> dict:
    if not teacher.is_file():
        raise ConfigError(f"--teacher {str(teacher)!r}: no such file; choose {law_teacher.choices_text()}")
    for p in (teacher.with_suffix(".json"), teacher.parent / "model.json"):
        if p.is_file():
            return json.loads(p.read_text())
    raise ConfigError(f"--teacher {str(teacher)!r}: no settings file beside it (agents.train writes one)")


def _law_settings(spec: str, scene, env_kwargs) -> dict:
    """A law teacher's run settings: the scene and env options of ``agents/hyperparams/ppo.yml``
    (the shipped agent's), with ``scene`` and ``env_kwargs`` over them, every control period
    (hold_ticks 1) and no residual law (the teacher labels the whole command)."""
    from agents.run_config import default_conf_file, read_conf

    law_teacher.parse_teacher(spec)  # the name first: a bad one is the first error, before any work
    entry = read_conf(default_conf_file("ppo"), "ImpactCatch-v0")
    kw = {k: v for k, v in (entry.get("env_kwargs") or {}).items() if k not in ("observation", "history")}
    kw.update(hold_ticks=1, residual=None)  # (a residual law only when --env-kwargs names one)
    kw.update(env_kwargs or {})
    name = scene if scene is not None else kw.get("scene", "rig")
    kw.pop("scene", None)
    law_teacher.check_student_options(spec, kw.get("hold_ticks", 1), kw.get("residual"))
    return {"scene": name, "overrides": {}, "env_kwargs": kw, "observation": "privileged", "history": 1}


def _extended(space, n):
    """``space`` (a Box) with ``n`` unbounded entries after it: the filter's estimate."""
    from gymnasium import spaces

    low = np.concatenate([space.low, np.full(n, -np.inf, np.float32)])
    high = np.concatenate([space.high, np.full(n, np.inf, np.float32)])
    return spaces.Box(low, high, dtype=np.float32)


class _StudentInputs:
    """What the student reads from an observation batch: its entries ``columns`` and, with a
    ``estimator`` (:class:`agents.estimate_input.StudentEstimator`), the filter's estimate after
    them; :meth:`applied` tells the filter the commands the envs applied."""

    def __init__(self, columns: np.ndarray, estimator):
        self.columns, self.estimator = columns, estimator

    def start(self) -> None:
        if self.estimator is not None:
            self.estimator.start()

    def read(self, obs: np.ndarray) -> np.ndarray:
        x = obs[:, self.columns]
        return x if self.estimator is None else np.concatenate([x, self.estimator.read(obs)], axis=1)

    def applied(self, commands: np.ndarray) -> None:
        if self.estimator is not None:
            self.estimator.applied(commands)


class _ModelTeacher:
    """A PPO model on the privileged observation (history 1): its deterministic action on the
    true state of the newest frame."""

    def __init__(self, path: Path, columns: np.ndarray):
        from stable_baselines3 import PPO

        self.model = PPO.load(str(path), device="cpu")
        self.columns = columns
        self.low = float(self.model.action_space.low[0])
        self.high = float(self.model.action_space.high[0])

    def start(self, rows) -> None:
        pass

    def applied(self, commands) -> None:  # no memory
        pass

    def act(self, obs: np.ndarray) -> np.ndarray:
        a, _ = self.model.predict(obs[:, self.columns], deterministic=True)
        return np.clip(a, self.low, self.high)


def distill(teacher, out, *, history: int = 4, iterations: int = 50, envs: int = 64, epochs: int = 4,
            seed: int = 0, eval_episodes: int = 16, eval_seed: int = 900_000, lr: float = 1e-3,
            batch_size: int = 4096, torch_threads: int = 1, past_commands: bool = False,
            scene: str | None = None, env_kwargs: dict | None = None, train_horizon: float | None = None,
            fit_samples: int | None = None, eval_every: int = 1, student_observation: str = "sensors",
            teacher_noise: float = 0.0, per_tick: bool = False, ignore: tuple[str, ...] = (),
            mixing: float = 0.5, label: str | None = None,
            log=sys.stderr) -> dict:
    """Distil ``teacher`` into a student in ``out``; returns the student's ``model.json`` content.

    ``teacher``: an SB3 PPO model on ``observation="privileged"``, history 1 (the run's scene and
    options are the teacher's), or ``"law:NAME[:KEY=VALUE,...]"``, a compiled classic law
    (:mod:`agents.law_teacher`; the scene and options are ``agents/hyperparams/ppo.yml``'s, or
    ``scene`` and ``env_kwargs``, at hold_ticks 1 with no residual law).  ``train_horizon`` (s):
    the DAgger episodes' length (default the run's horizon; validation always runs the whole
    horizon).  ``fit_samples``: after each iteration, fit on that many samples drawn from all the
    data so far (default: ``epochs`` passes over all of it).  ``eval_every``: validate every that
    many iterations, and after the last.  ``student_observation``: ``"sensors"`` (what a rig gives),
    ``"estimate"`` (the sensors, then the scene's extended Kalman filter's estimate from them:
    :mod:`agents.estimate_input`; the model is saved with ``"estimator": "ekf"`` and runs with
    its filter wherever it runs) or ``"both"`` (the sensors and the true state: how much the
    information limits the student).  ``label``: the student's name in reports (``model.json``;
    default derived from the teacher, history and seed)."""
    from agents.run_facts import check_label

    check_label(label)  # before any work
    import torch
    from gymnasium.vector import AutoresetMode
    from stable_baselines3 import PPO

    from agents.policies import actor_indices
    from agents.run_facts import TEST_EPISODES, TEST_SEED, _load_average, _versions
    from impact_env.control.observation import make_layout
    from impact_env.env.sb3_vecenv import make_sb3_vec_env
    from impact_env.env.task import EVALUATION_OPTIONS
    from impact_env.env.vector import ImpactCatchVectorEnv
    from impact_env.scene import load_scene

    is_law = law_teacher.is_law_teacher(teacher)
    if is_law:
        meta_t = _law_settings(teacher, scene, env_kwargs)
    else:
        teacher = Path(teacher)
        if scene is not None or env_kwargs:
            raise ConfigError("scene and env_kwargs go with a law teacher; a model teacher's run takes "
                              "its own")
        meta_t = _settings(teacher)
        if meta_t.get("observation") != "privileged" or int(meta_t.get("history", 1)) != 1:
            raise ConfigError(f"--teacher {str(teacher)!r} must read observation 'privileged' with history 1 "
                              f"(it reads {meta_t.get('observation')!r}, history {meta_t.get('history')}); "
                              f"or choose {law_teacher.choices_text()}")
    for name, v, lo in (("history", history, 1), ("iterations", iterations, 1), ("envs", envs, 1),
                        ("epochs", epochs, 1), ("eval_episodes", eval_episodes, 1), ("seed", seed, 0),
                        ("eval_every", eval_every, 1), ("batch_size", batch_size, 1)):
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise ConfigError(f"{name} = {v!r} must be an integer >= {lo}")
    if fit_samples is not None and (isinstance(fit_samples, bool) or not isinstance(fit_samples, int)
                                    or fit_samples < 1):
        raise ConfigError(f"fit_samples = {fit_samples!r} must be an integer >= 1 (samples per fit) or None")
    if not (isinstance(mixing, (int, float)) and 0.0 <= mixing <= 1.0):
        raise ConfigError(f"mixing = {mixing!r} must be in [0, 1] (the teacher acts with probability "
                          "mixing ** iteration)")
    if student_observation not in ("sensors", "both", "estimate"):
        raise ConfigError(f"student_observation = {student_observation!r}; expected 'sensors' (what a rig "
                          "gives), 'estimate' (the sensors and the scene's filter's estimate from them) or "
                          "'both' (the sensors and the true state)")
    if train_horizon is not None and not (isinstance(train_horizon, (int, float))
                                          and 0 < train_horizon < 1e4):
        raise ConfigError(f"train_horizon = {train_horizon!r} s must be a time in (0, 1e4) s, or None")
    if seed < TEST_SEED + TEST_EPISODES and TEST_SEED < seed + envs:
        raise ConfigError(f"training seeds {seed}..{seed + envs - 1} meet the test drops {TEST_SEED}.."
                          f"{TEST_SEED + TEST_EPISODES - 1}")
    if (out := Path(out)).joinpath("model.json").exists():
        raise ConfigError(f"--out {str(out)!r} already holds a run; choose another folder")

    scene_name, overrides = meta_t["scene"], meta_t.get("overrides") or None
    kw = {k: v for k, v in (meta_t.get("env_kwargs") or {}).items() if k not in ("observation", "history")}
    scene_obj = load_scene(scene_name, overrides)
    both = make_layout(scene_obj, "both", history)
    sensors = make_layout(scene_obj, "sensors", 1)
    F, S = both.frame_size, sensors.frame_size
    reads = F if student_observation == "both" else S
    unknown = [c for c in ignore if c not in sensors.names]
    if unknown:
        raise ConfigError(f"ignore = {', '.join(map(repr, unknown))}: not a sensor channel of "
                          f"{scene_name!r}; choose among {', '.join(sensors.names)}")
    student_idx = np.asarray(actor_indices(F, reads, history))
    hold = int(kw.get("hold_ticks", 1))
    horizon = float(kw.get("horizon", scene_obj.episode.horizon))
    steps_per_episode = int(round((train_horizon or horizon) / (scene_obj.control_period * hold)))

    torch.set_num_threads(torch_threads)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    if is_law:
        teach = law_teacher.LawTeacher(teacher, scene_obj, both.names, both.scales, envs)
        low, high = -1.0, 1.0
        if kw.get("residual") is not None:  # the label: the teacher's command less the residual law's
            teach = law_teacher.ResidualLabel(teach, law_teacher.LawTeacher(
                law_teacher.PREFIX + kw["residual"], scene_obj, both.names, both.scales, envs))
    else:
        teach = _ModelTeacher(teacher, np.arange(S, F))  # the true state of the newest frame
        low, high = teach.low, teach.high
    # the student: a PPO MlpPolicy on its observation, built from that env's spaces
    estimating = student_observation == "estimate"

    def estimator(n):
        return StudentEstimator(scene_obj, both.names, both.scales, n) if estimating else None

    if estimating:  # the filter's constants now: a scene it does not model is refused before any work
        from agents.estimate_input import StudentEstimator
        from impact_env.control.estimation.features import N_FEATURES
        if hold != 1 or kw.get("residual") is not None:
            raise ConfigError("student_observation = 'estimate': the filter is told every tick's command, so the "
                              f"student acts every control period (hold_ticks 1, got {hold}) with no residual law "
                              f"(got {kw.get('residual')!r})")
        estimator(1)
    sensor_env = make_sb3_vec_env(scene_name, num_envs=1, monitor=False, overrides=overrides,
                                  **{**kw, "observation": "sensors" if estimating else student_observation,
                                     "history": history})
    n_extra = N_FEATURES if estimating else 0
    if estimating:
        sensor_env.observation_space = _extended(sensor_env.observation_space, n_extra)
    student = PPO("MlpPolicy", sensor_env, device="cpu", seed=seed, n_steps=8, batch_size=8,
                  policy_kwargs={"net_arch": {"pi": [64, 64], "vf": [64, 64]}, "log_std_init": -2.5})
    sensor_env.close()
    if student.observation_space.shape[0] != len(student_idx) + n_extra:
        raise ConfigError(f"the student's observation has {student.observation_space.shape[0]} entries, the "
                          f"layout {len(student_idx)}")
    pol = student.policy
    # the past commands at the end of the observation (history > 1): unless past_commands, the
    # student's first layer gives them weight 0 (set here, and the inputs are masked while it learns,
    # so they stay 0): its command is then a function of the frames alone, with no loop from its own
    # output back to its input, in which a float32 build's rounding would accumulate
    mask = torch.ones(len(student_idx) + n_extra)
    if history > 1 and not past_commands:
        mask[history * reads:] = 0.0
    for name in ignore:
        mask[[h * reads + both.names.index(name) for h in range(history)]] = 0.0
    with torch.no_grad():
        pol.mlp_extractor.policy_net[0].weight[:, mask == 0] = 0.0
    params = list(pol.mlp_extractor.policy_net.parameters()) + list(pol.action_net.parameters())
    opt = torch.optim.Adam(params, lr=lr)

    def actor(x: torch.Tensor) -> torch.Tensor:
        return pol.action_net(pol.mlp_extractor.forward_actor(pol.extract_features(x * mask)))

    def act_student(o: np.ndarray) -> np.ndarray:  # SB3's deterministic predict, without its overhead
        with torch.inference_mode():
            a = actor(torch.as_tensor(o, dtype=torch.float32)).numpy()
        return np.clip(a, low, high).astype(np.float64)

    # every DAgger episode runs the whole (training) horizon: all envs start and end together
    disabled = AutoresetMode.DISABLED
    venv = ImpactCatchVectorEnv(envs, scene_name, overrides, autoreset_mode=disabled,
                                **{**kw, "terminate_on_catch": False, "observation": "both",
                                   "history": history})
    # the validation env gives the sensors and the true state too (the same drops and readings as with
    # the sensors alone): the student reads its part, a law teacher its own
    eval_kw = {**kw, **EVALUATION_OPTIONS, "observation": "both", "history": history}
    eval_env = ImpactCatchVectorEnv(eval_episodes, scene_name, overrides, autoreset_mode=disabled, **eval_kw)
    eval_steps = int(round(horizon / (scene_obj.control_period * hold)))
    env_seconds = [0.0]

    def env_step(env, a):
        t = time.perf_counter()
        o, r, _, _, _ = env.step_arrays(a, infos=False)
        env_seconds[0] += time.perf_counter() - t
        return o, r

    inputs = _StudentInputs(student_idx, estimator(envs))
    eval_inputs = _StudentInputs(student_idx, estimator(eval_episodes))

    def eval_student(o):
        a = act_student(eval_inputs.read(o))
        eval_inputs.applied(a)
        return a

    def episode_return(policy) -> float:
        """Mean return of ``policy`` on the validation drops (the same drops at every call)."""
        eval_inputs.start()
        o, _ = eval_env.reset(seed=eval_seed)
        total = np.zeros(eval_episodes)
        for _ in range(eval_steps):
            o, r = env_step(eval_env, policy(o))
            total += r
        return float(total.mean())

    out.mkdir(parents=True, exist_ok=True)
    X: np.ndarray | None = None
    Y: np.ndarray | None = None
    history_log, best = [], None
    load0, cpu0, t0 = _load_average(), time.process_time(), time.perf_counter()
    eval_time = 0.0
    t = time.perf_counter()
    obs, _ = venv.reset(seed=seed)
    env_seconds[0] += time.perf_counter() - t
    last_loss = float("nan")
    errors: list[float] = []  # per iteration: the student's mean squared error on its new data, unfitted
    for it in range(iterations):
        beta = mixing ** it
        use_teacher = (rng.random(envs) < beta)[:, None]
        if it:
            t = time.perf_counter()
            obs, _ = venv.reset()  # each env's next drop, from its own Generator
            env_seconds[0] += time.perf_counter() - t
        teach.start(np.ones(envs, dtype=bool))
        inputs.start()
        xs = np.empty((steps_per_episode, envs, len(student_idx) + n_extra), np.float32)
        ys = np.empty((steps_per_episode, envs, 1), np.float32)
        for k in range(steps_per_episode):
            a_t = teach.act(obs)
            x = inputs.read(obs)
            a_s = act_student(x)
            xs[k], ys[k] = x, a_t
            applied = a_t
            if teacher_noise:  # DART: the teacher's applied command perturbed, its label not
                applied = np.clip(a_t + teacher_noise * rng.standard_normal(a_t.shape), low, high)
            if per_tick:  # the mixing drawn every tick, not every episode
                use_teacher = (rng.random(envs) < beta)[:, None]
            command = np.where(use_teacher, applied, a_s)
            teach.applied(command)  # a teacher whose memory models its own output follows the env's
            inputs.applied(command)
            obs, _ = env_step(venv, command)
        with torch.inference_mode():  # DAgger's own measure: the student against its labels on the new data
            error = float(torch.mean((actor(torch.from_numpy(xs.reshape(-1, xs.shape[-1])))
                                      - torch.from_numpy(ys.reshape(-1, 1))) ** 2))
        errors.append(round(error, 8))
        X = xs.reshape(-1, xs.shape[-1]) if X is None else np.concatenate([X, xs.reshape(-1, xs.shape[-1])])
        Y = ys.reshape(-1, 1) if Y is None else np.concatenate([Y, ys.reshape(-1, 1)])
        x_all, y_all = torch.from_numpy(X), torch.from_numpy(Y)
        n = len(x_all)
        order = (np.concatenate([rng.permutation(n) for _ in range(epochs)]) if fit_samples is None
                 else rng.integers(0, n, fit_samples))
        for k in range(0, len(order), batch_size):
            idx = torch.as_tensor(order[k:k + batch_size])
            loss = torch.mean((actor(x_all[idx]) - y_all[idx]) ** 2)
            opt.zero_grad()
            loss.backward()
            opt.step()
            last_loss = float(loss.detach())
        wall = time.perf_counter() - t0 - eval_time
        step = (it + 1) * steps_per_episode * envs
        if (it + 1) % eval_every and it + 1 < iterations:
            log.write(f"distill: iteration {it + 1}/{iterations} (beta {beta:.3f}, {n} samples), imitation "
                      f"error {error:.2e}, loss {last_loss:.2e}, {wall:.0f} s\n")
            log.flush()
            continue
        t_eval = time.perf_counter()
        ret = episode_return(eval_student)
        eval_time += time.perf_counter() - t_eval
        history_log.append({"step": step, "wall_s": round(wall, 3), "env_s": round(env_seconds[0], 3),
                            "return": round(ret, 4), "beta": beta, "loss": round(last_loss, 6)})
        log.write(f"distill: iteration {it + 1}/{iterations} (beta {beta:.3f}, {n} samples), imitation "
                  f"error {error:.2e}, loss {last_loss:.2e}, validation return {ret:.2f}, {wall:.0f} s\n")
        log.flush()
        if best is None or ret > best["mean_reward"]:
            best = {"step": step, "mean_reward": ret, "wall_s": round(wall, 3)}
            student.save(out / "best_model.zip")
    wall = time.perf_counter() - t0
    cpu = time.process_time() - cpu0
    load = [load0, _load_average()]
    student.save(out / "model.zip")
    assert best is not None  # the last iteration is always validated

    # what the run is judged against, on the same validation drops: a law teacher itself, or a model
    # teacher's residual law alone (action 0)
    if is_law:
        eval_teacher = law_teacher.LawTeacher(teacher, scene_obj, both.names, both.scales, eval_episodes)
        if kw.get("residual") is not None:
            eval_teacher = law_teacher.ResidualLabel(eval_teacher, law_teacher.LawTeacher(
                law_teacher.PREFIX + kw["residual"], scene_obj, both.names, both.scales, eval_episodes))
        eval_teacher.start(np.ones(eval_episodes, dtype=bool))
        best["teacher"] = teacher
        best["teacher_return"] = episode_return(eval_teacher.act)
    elif kw.get("residual") is not None:
        law = episode_return(lambda o: np.zeros((eval_episodes, 1)))
        best["residual_law"] = kw.get("residual")
        best["residual_law_return"] = law
        best["first_beats_law"] = next((h for h in history_log if h["return"] > law), None)
    best["drops"] = [eval_seed, eval_seed + eval_episodes - 1]
    best["evaluations"] = len(history_log)
    steps = iterations * steps_per_episode * envs
    observation_out = "sensors" if estimating else student_observation
    env_kwargs_out = {**kw, "observation": observation_out, "history": history}
    if is_law:
        derived = (f"dagger-{law_teacher.parse_teacher(teacher)[0]}-h{history}{'pc' if past_commands else ''}"
                 f"{'-priv' if student_observation == 'both' else ''}{'-est' if estimating else ''}-s{seed}")
        source = {"teacher": teacher, "teacher_observation": "the law's own entries of the true frame",
                  "method": "DAgger, beta = 0.5 ** iteration, labels: the law's command every control period"}
    else:
        derived = f"distill-h{history}{'pc' if past_commands else ''}-s{seed}"
        source = {"teacher": str(teacher), "teacher_observation": "privileged",
                  "method": "DAgger, beta = 0.5 ** iteration"}
    source["note"] = "the critic is not trained (the student only acts)"
    meta = {"algo": "ppo", "label": label or derived, "observation": observation_out, "history": history,
            "estimator": "ekf" if estimating else None,
            "scene": scene_name, "overrides": meta_t.get("overrides") or {}, "env_kwargs": env_kwargs_out,
            "hold_ticks": hold, "residual": kw.get("residual"), "steps": steps, "ticks": steps * hold,
            "envs": envs, "seed": seed, "wall_time_s": round(wall, 2), "steps_per_s": round(steps / wall, 1),
            "ticks_per_s": round(steps * hold / wall, 1), "env_time_s": round(env_seconds[0], 4),
            "env_share": round(env_seconds[0] / max(wall, 1e-9), 4), "torch_threads": torch_threads,
            "load_average": load, "cpu_time_s": round(cpu, 2), "policy": "MlpPolicy",
            "hyperparameters": {"iterations": iterations, "epochs": epochs, "learning_rate": lr,
                                "batch_size": batch_size, "net_arch": [64, 64],
                                "past_commands": past_commands,
                                "train_horizon_s": train_horizon, "fit_samples": fit_samples,
                                "eval_every": eval_every, "teacher_noise": teacher_noise,
                                "per_tick": per_tick, "mixing": mixing, "ignore": list(ignore)},
            "distilled_from": source,
            "validation": {"seeds": best["drops"], "best": best, "history": history_log},
            "imitation_error": errors, "versions": _versions(), "interrupted": False}
    (out / "model.json").write_text(json.dumps(meta, indent=2, default=str) + "\n")
    best_meta = {**meta, "steps": best["step"]}
    (out / "best_model.json").write_text(json.dumps(best_meta, indent=2, default=str) + "\n")
    venv.close()
    eval_env.close()
    return meta


def verdict_line(meta: dict, best_path) -> str:
    """What a distillation run says at the end: its validation figure against its reference (a law
    teacher, or a model teacher's residual law alone) and where its best student is."""
    b = meta["validation"]["best"]
    per_iteration = meta["steps"] // meta["hyperparameters"]["iterations"]
    line = (f"{meta['label']}: {meta['steps']} policy steps in {meta['wall_time_s']:.0f} s "
            f"({meta['cpu_time_s']:.0f} s of CPU; the env {100 * meta['env_share']:.0f} %); validation "
            f"energy integral {-b['mean_reward']:.2f} ms (best, iteration {b['step'] // per_iteration})")
    if b.get("teacher") is not None:
        line += (f" against its teacher {b['teacher']}'s {-b['teacher_return']:.2f} ms (x"
                 f"{b['mean_reward'] / b['teacher_return']:.2f})")
    elif b.get("residual_law") is not None:
        verdict = "beats it" if b["mean_reward"] > b["residual_law_return"] else "does NOT beat it"
        line += f" against {b['residual_law']}'s {-b['residual_law_return']:.2f} ms: {verdict}"
    return f"{line}; saved {best_path}"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m agents.distill", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--teacher", required=True,
                   help="law:NAME[:KEY=VALUE,...] (a compiled classic law, e.g. law:mpc-state) or an SB3 PPO "
                        "model.zip on observation 'privileged'")
    p.add_argument("--out", required=True, help="the student's run folder")
    p.add_argument("--history", type=int, default=4, help="frames (and past commands) the student reads")
    p.add_argument("--iterations", type=int, default=50,
                   help="DAgger iterations (one episode per env each)")
    p.add_argument("--envs", type=int, default=64)
    p.add_argument("--epochs", type=int, default=4, help="passes over all the data after each iteration")
    p.add_argument("--fit-samples", type=int, default=None, metavar="N",
                   help="instead of --epochs passes, fit on N samples drawn from all the data after each "
                        "iteration")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--label", default=None, metavar="NAME",
                   help="the student's name in reports (model.json; default derived from the teacher, "
                        "history and seed, e.g. distill-h4pc-s0)")
    p.add_argument("--eval-episodes", type=int, default=16)
    p.add_argument("--eval-every", type=int, default=1, metavar="K",
                   help="validate every K iterations and after the last (default 1)")
    p.add_argument("--scene", default=None, help="with a law teacher: the training scene (default ppo.yml's)")
    p.add_argument("--env-kwargs", action="append", default=[], metavar="KEY=VALUE",
                   help="with a law teacher: an env option over ppo.yml's (hold_ticks 1 and no residual "
                        "are required); repeatable")
    p.add_argument("--train-horizon", type=float, default=None, metavar="S",
                   help="length of the DAgger episodes, s (default: the run's horizon; validation runs "
                        "the whole horizon)")
    p.add_argument("--student-observation", choices=("sensors", "estimate", "both"), default="sensors",
                   help="sensors (what a rig gives, default), estimate (the sensors and the scene's extended "
                        "Kalman filter's estimate from them, the filter part of the policy wherever it runs; "
                        "hold 1, no residual) or both (the sensors and the true state: how much the "
                        "information limits the student)")
    p.add_argument("--teacher-noise", type=float, default=0.0, metavar="SIGMA",
                   help="std of Gaussian noise on the teacher's applied command (fraction of the command "
                        "scale; its label stays clean: DART); default 0")
    p.add_argument("--mixing", type=float, default=0.5, metavar="M",
                   help="the teacher acts in an env with probability M ** iteration (default 0.5: DAgger; "
                        "1 with --teacher-noise: DART, the teacher always in control)")
    p.add_argument("--ignore", action="append", default=[], metavar="CHANNEL",
                   help="a sensor channel the student does not read (its first-layer weights 0, as the "
                        "past commands'); repeatable")
    p.add_argument("--per-tick", action="store_true",
                   help="draw who acts (teacher or student) every tick instead of every episode")
    p.add_argument("--torch-threads", type=int, default=1)
    p.add_argument("--past-commands", action="store_true",
                   help="let the student read its own past commands (the observation's history holds "
                        "them); by default their weights are 0: a float32 build's rounding then has no "
                        "loop to grow in")
    a = p.parse_args(argv)
    try:
        from agents.run_facts import _pairs

        meta = distill(a.teacher, a.out, history=a.history, iterations=a.iterations, envs=a.envs,
                       epochs=a.epochs, seed=a.seed, eval_episodes=a.eval_episodes,
                       torch_threads=a.torch_threads, past_commands=a.past_commands, scene=a.scene,
                       env_kwargs=_pairs(a.env_kwargs, "--env-kwargs") or None, train_horizon=a.train_horizon,
                       fit_samples=a.fit_samples, eval_every=a.eval_every,
                       student_observation=a.student_observation, teacher_noise=a.teacher_noise,
                       per_tick=a.per_tick, mixing=a.mixing, ignore=tuple(a.ignore),
                       label=a.label)
    except ConfigError as exc:
        print(f"agents.distill: {exc}", file=sys.stderr)
        return 2
    print(verdict_line(meta, Path(a.out) / "best_model.zip"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
