"""Training-time helpers: episode statistics (also to TensorBoard) and the fixed held-out drops
of the evaluation callback."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback, EvalCallback
from stable_baselines3.common.vec_env import VecEnvWrapper


class EpisodeStats(BaseCallback):
    """Return, length, caught and diverged flags of every finished training episode; logs the
    caught fraction of the last ``window`` episodes as ``rollout/caught_fraction``."""

    def __init__(self, window: int = 100):
        super().__init__()
        self.window = window
        self.returns: list[float] = []
        self.lengths: list[int] = []
        self.caught: list[bool] = []
        self.diverged = 0

    def _on_step(self) -> bool:
        for info in self.locals.get("infos", ()):
            ep = info.get("episode")
            if ep is not None:
                self.returns.append(float(ep["r"]))
                self.lengths.append(int(ep["l"]))
                self.caught.append(bool(info.get("caught", False)))
                self.diverged += bool(info.get("diverged", False))
        return True

    def _on_rollout_end(self) -> None:
        if self.caught:
            self.logger.record("rollout/caught_fraction", float(np.mean(self.caught[-self.window:])))
            self.logger.record("rollout/diverged_total", self.diverged)

    def stats(self, step_time: float) -> dict:
        """Summary of the first and last ``window`` episodes; ``step_time`` s per counted step."""
        n = min(self.window, len(self.returns))
        if n == 0:
            return {"episodes_last": 0}
        r = np.asarray(self.returns[-n:])
        m = min(self.window, len(self.returns) - n) or n  # the first episodes, apart from the last ones
        return {"episodes_last": n, "return_mean": float(r.mean()), "return_min": float(r.min()),
                "return_max": float(r.max()),
                "length_mean_s": float(np.mean(self.lengths[-n:]) * step_time),
                "caught_fraction": float(np.mean(self.caught[-n:])), "diverged": int(self.diverged),
                "episodes_first": m, "return_first_mean": float(np.mean(self.returns[:m]))}


class EvalLine(BaseCallback):
    """EvalCallback's ``callback_after_eval``: one line on ``stream`` per evaluation (what a log or
    a run without a terminal shows in place of the progress bar): policy steps done of the
    planned budget, the validation return, the best so far, the training episodes' caught
    fraction, the wall time and the speed."""

    def __init__(self, stats: EpisodeStats, total: int, stream, start_step: int = 0):
        super().__init__()
        self.stats, self.total, self.stream, self.start_step = stats, int(total), stream, int(start_step)
        self._t0: float | None = None

    def _on_training_start(self) -> None:
        import time

        self._t0 = time.perf_counter()

    def _on_step(self) -> bool:
        import time

        ev = self.parent  # the EvalCallback that called us
        s = self.stats
        n = min(s.window, len(s.returns))
        caught = f", training caught {100 * np.mean(s.caught[-n:]):.0f} %" if n else ""
        wall = time.perf_counter() - (self._t0 or time.perf_counter())
        done = self.num_timesteps
        speed = (done - self.start_step) / wall if wall > 0 else 0.0
        self.stream.write(f"eval: step {done}/{self.total} ({100 * done / self.total:.0f} %), validation "
                          f"return {ev.last_mean_reward:.2f} (best {ev.best_mean_reward:.2f}){caught}, "
                          f"{wall:.0f} s, {speed:.0f} steps/s\n")
        self.stream.flush()
        return True


class FinalEval(EvalCallback):
    """SB3's EvalCallback that also evaluates at the end of training when the last evaluation was
    not at the last step: every run, however short (below ``eval_freq`` too), ends with an
    evaluation of its final model and a ``best_model.zip``.

    It also keeps, for every evaluation, the wall time since training started (``wall_s``: the
    evaluations' own time excluded, so that the figure is the training's) and the training
    env's time so far (``env_s``, from a :class:`StepTimer` given as ``timer``): what the run's
    ``model.json`` reports as the time until the model first beat a reference and until its best."""

    def __init__(self, *args, timer: StepTimer | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.timer = timer
        self.wall_s: list[float] = []
        self.env_s: list[float] = []
        self._t0: float | None = None
        self._env0 = 0.0
        self._eval_time = 0.0

    def _init_callback(self) -> None:
        super()._init_callback()
        import time

        self._t0 = time.perf_counter()
        self._env0 = self.timer.seconds if self.timer is not None else 0.0

    def _on_step(self) -> bool:
        import time

        n = len(self.evaluations_timesteps)
        t = time.perf_counter()
        ok = super()._on_step()
        if len(self.evaluations_timesteps) > n:  # an evaluation ran in this call
            self.wall_s.append(t - (self._t0 or t) - self._eval_time)
            self.env_s.append(self.timer.seconds - self._env0 if self.timer is not None else float("nan"))
            self._eval_time += time.perf_counter() - t
        return ok

    def _on_training_end(self) -> None:
        self.evaluate_now()

    def evaluate_now(self) -> None:
        """Evaluate the model as it is, unless it was just evaluated at this step."""
        if self.evaluations_timesteps and self.evaluations_timesteps[-1] == self.num_timesteps:
            return
        freq, self.eval_freq = self.eval_freq, 1  # EvalCallback evaluates when n_calls % eval_freq == 0
        try:
            self._on_step()
        finally:
            self.eval_freq = freq


class StepTimer(VecEnvWrapper):
    """Wall time spent inside the wrapped vector env (``reset`` and ``step``), in ``seconds``: the
    env's share of a training run is ``seconds`` over the run's wall time."""

    def __init__(self, venv):
        super().__init__(venv)
        self.seconds = 0.0

    def reset(self):
        import time

        t = time.perf_counter()
        obs = self.venv.reset()
        self.seconds += time.perf_counter() - t
        return obs

    def step_async(self, actions) -> None:
        import time

        t = time.perf_counter()
        self.venv.step_async(actions)
        self.seconds += time.perf_counter() - t

    def step_wait(self):
        import time

        t = time.perf_counter()
        out = self.venv.step_wait()
        self.seconds += time.perf_counter() - t
        return out


class FixedSeeds(VecEnvWrapper):
    """Every ``reset()`` seeds env i with ``seed + i``: each evaluation of ``EvalCallback`` then
    meets the same drops and the same sensor noise, so evaluations compare models, not luck."""

    def __init__(self, venv, seed: int):
        super().__init__(venv)
        self.base_seed = int(seed)

    def reset(self):
        self.venv.seed(self.base_seed)
        return self.venv.reset()

    def step_wait(self):
        return self.venv.step_wait()


def write_settings(model_path: Path, settings: dict, **extra) -> Path:
    """``PATH.json`` beside the model ``PATH.zip`` (the file compare reads)."""
    path = Path(model_path).with_suffix(".json")
    path.write_text(json.dumps({**settings, **extra}, indent=2, default=str) + "\n")
    return path


class SettingsBeside(BaseCallback):
    """EvalCallback's ``callback_on_new_best``: the new best_model.zip gets its settings file."""

    def __init__(self, model_path: Path, settings: dict):
        super().__init__()
        self.model_path, self.settings = Path(model_path), settings

    def _on_step(self) -> bool:
        write_settings(self.model_path, self.settings, steps=int(self.model.num_timesteps))
        return True


class CheckpointWithSettings(CheckpointCallback):
    """SB3's CheckpointCallback, each checkpoint with its settings file beside it, keeping the
    newest ``keep`` checkpoints (None: all)."""

    def __init__(self, settings: dict, keep: int | None = None, **kwargs):
        super().__init__(**kwargs)
        self.settings = settings
        self.keep = keep

    def _on_step(self) -> bool:
        ok = super()._on_step()
        if self.n_calls % self.save_freq == 0:
            write_settings(Path(self._checkpoint_path(extension="zip")), self.settings,
                           steps=int(self.model.num_timesteps))
            prune_checkpoints(Path(self.save_path), self.keep)
        return ok


def prune_checkpoints(folder: Path, keep: int | None) -> None:
    """Remove all but the newest ``keep`` checkpoints of ``folder`` (each one's model, settings
    file and SAC replay buffer); None keeps all.  --resume needs only the newest, and a run that
    checkpoints every 100k steps would otherwise leave two files per 100k."""
    if keep is None:
        return
    steps = sorted({int(p.stem.split("_")[1]) for p in folder.glob("model_*_steps.zip")
                    if p.stem.split("_")[1].isdigit()})
    for old in steps[:-keep]:
        for name in (f"model_{old}_steps.zip", f"model_{old}_steps.json",
                     f"model_replay_buffer_{old}_steps.pkl"):
            (folder / name).unlink(missing_ok=True)
