"""Words and colours for plots: what each metric is (quantity and unit, no code names) and one
colour per policy that every panel and figure of a comparison shares."""

from __future__ import annotations

# per-episode metrics of impact_env.eval.rollout, as an axis label: quantity, unit
METRIC_LABELS = {
    "impact_speed_mps": "impact speed, m/s",
    "time_to_catch_s": "catch time (body 1 at rest on the pad: relative energy below 1 %, no bounce), s",
    "time_to_catch_absolute_s": "time until body 1's absolute catch energy stays below 1 %, s",
    "residual_vibration_mps": "body 2's RMS velocity over the last 50 ms, m/s",
    "residual_energy_10ms": "catch energy 10 ms after the touch / impact energy",
    "residual_energy_50ms": "catch energy 50 ms after the touch / impact energy",
    "residual_energy_100ms": "catch energy 100 ms after the touch / impact energy",
    "exit_speed_ratio": "body 1's speed at the first separation / impact speed",
    "exit_velocity_ratio": "body 1's velocity (up) at the first separation / impact speed",
    "bounces": "detected bounces (contact onsets after the first)",
    "peak_force_N": "peak force on body 2, N",
    "rms_force_N": "RMS force on body 2, N",
    "peak_demand_N": "peak force demand, N",
    "energy_integral_ms": "time integral of catch energy / impact energy, ms",
    "energy_integral_ticks_ms": "catch energy / impact energy summed over the ticks x period, ms",
    "contact_fraction": "fraction of the episode in contact",
    "saturation_time_s": "time at the force limit, s",
}


def metric_label(name: str) -> str:
    """The axis label of a metric (its name if it has none)."""
    return METRIC_LABELS.get(name, name.replace("_", " "))


def policy_colors(specs) -> dict[str, str]:
    """One matplotlib colour per policy, in the order given (``C0``, ``C1``, ...): the same
    policy gets the same colour in every panel, whatever a panel leaves out."""
    return {spec: f"C{i % 10}" for i, spec in enumerate(specs)}
