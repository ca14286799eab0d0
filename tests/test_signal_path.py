"""The signal path's order is written once, in code: the hardware stage's ``hardware_tick`` runs
the hardware effects under their flag bits, then the controller's front end ``condition`` runs
the controller effects.  Every doc and docstring that spells the path out must name those stages
in that order (the sensor delay acts on the raw readings, before the controller's filters)."""

from __future__ import annotations

import inspect
import re

from impact_env import effects
from impact_env.control import front_end
from impact_env.effects import registry
from impact_env.hardware import stage

#: how the docs name each effect's stage (another effect: its name, "_" read as a space)
WORDS = {"actuator_delay": r"actuator delay", "shaker": r"shaker",
         "saturation": r"saturation|amplifier limit", "sensors": r"sensors", "sensor_delay": r"sensor delay",
         "filters": r"filters", "detector": r"detector"}


def _stages(func, module, side: str) -> list[str]:
    """The effects ``func`` runs, in the order its code tests their flag bits."""
    bits = {name: value for name, value in vars(module).items() if name.startswith("F_")}
    by_bit = {registry.flag(e.name): e.name for e in registry.side(side)}
    out = []
    for const in re.findall(r"flags & (F_\w+)", inspect.getsource(func)):
        name = by_bit.get(bits[const])
        if name is not None and name not in out and bits[const] == registry.flag(name):
            out.append(name)
    return out


HARDWARE = _stages(stage.hardware_tick, stage, registry.HARDWARE)
CONTROLLER = _stages(front_end.condition, front_end, registry.CONTROLLER)


def test_the_code_runs_every_effect_once():
    assert sorted(HARDWARE + CONTROLLER) == sorted(registry.NAMES)
    assert "sensor_delay" in HARDWARE and "filters" in CONTROLLER  # raw readings delayed, then filtered


def _between(text: str, start: str, end: str) -> str:
    assert start in text, start
    return text.split(start, 1)[1].split(end, 1)[0]


def _order(text: str, names: list[str]) -> list[str]:
    """``names`` that ``text`` mentions in that order, each after the one before."""
    at, found = 0, []
    for name in names:
        m = re.compile(WORDS.get(name, name.replace("_", " "))).search(text, at)
        if m is None:
            return found
        found.append(name)
        at = m.end()
    return found


def _docs(root) -> list[tuple[str, str, list[str]]]:
    explanation = (root / "docs" / "explanation" / "signal-path.md").read_text()
    scenes = (root / "docs" / "scenes.md").read_text()
    both = HARDWARE + CONTROLLER
    return [
        ("impact_env/effects/__init__.py",
         _between(effects.__doc__ or "", "One signal path", "Each effect"), both),
        ("impact_env/hardware/stage.py", _between(stage.__doc__ or "", "Order (fixed", "A stage runs"),
         HARDWARE),
        ("docs/explanation/signal-path.md",
         _between(explanation, "hardware stage (hardware/stage.py):", "=> observation"), both),
        ("docs/scenes.md", _between(scenes, "`action -> command scaling", "front end"), both),
    ]


def test_every_written_signal_path_follows_the_code(root):
    for where, text, expected in _docs(root):
        assert _order(text, expected) == expected, f"{where}: the signal path's order is {expected}"


def test_a_path_in_another_order_is_caught():
    """The old docstrings' order (filters before the delay) fails the check."""
    written = "sensors (gain, offset, noise, ADC) -> filters -> delay -> observation"
    assert _order(written, ["sensors", "sensor_delay", "filters"]) == ["sensors"]
