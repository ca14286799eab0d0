"""Plots: one colour per policy in every panel, every axis a quantity with a unit (or a ratio),
no code names, the filter band from the scene, the catch-time figure."""

from __future__ import annotations

import re

import numpy as np
import pytest

import impact_env.eval.compare_plots as CP
from impact_env.eval.compare import compare
from impact_env.eval.labels import METRIC_LABELS, policy_colors
from impact_env.scene import load_scene

SPECS = ["passive", "thesis-rig", "pd-penetration"]  # passive: no force, so no spectrum line


@pytest.fixture(scope="module")
def runs():
    return compare(load_scene("rig"), SPECS, episodes=3, seed=0, horizon=0.05, workers=1, progress=False)


def capture(monkeypatch):
    """Replace the figure writer by one that keeps each panel's line colours and axis labels."""
    seen = {}

    def finish(plt, fig, ax, title, path, legend_size, xlabel=None, which="major"):
        for a in ax:
            if xlabel:
                a.set_xlabel(xlabel)
        seen["panels"] = [{"lines": {ln.get_label(): ln.get_color() for ln in a.get_lines()},
                           "x": a.get_xlabel(), "y": a.get_ylabel()} for a in ax]
        plt.close(fig)
        return path

    monkeypatch.setattr(CP, "_finish", finish)
    return seen


@pytest.mark.parametrize("plot", [CP.plot_energy, CP.plot_force, CP.plot_motion])
def test_one_colour_per_policy_in_every_panel(runs, monkeypatch, tmp_path, plot):
    seen = capture(monkeypatch)
    scene = load_scene("rig")
    plot(runs, tmp_path / "x.png", scene)
    want = policy_colors(SPECS)
    for panel in seen["panels"]:
        for label, color in panel["lines"].items():
            spec = label.split(":")[0]
            if spec in want:
                assert color == want[spec], (plot.__name__, label)
        # every axis is a quantity with a unit, or a ratio; no code names
        for text in (panel["x"], panel["y"]):
            assert text and ("," in text or "/" in text), (plot.__name__, text)
            assert not re.search(r"[a-z]+_[a-z]+|kinetic1", text), text


def test_the_filter_band_is_the_scenes():
    assert CP.filter_band(load_scene("rig")) == (20.0, 1000.0)
    assert CP.filter_band(load_scene("rig", {"effects.filters.force.high_hz": 800.0})) == (20.0, 800.0)
    assert CP.filter_band(load_scene("ideal")) is None


def test_the_catch_time_figure(runs, tmp_path):
    path = CP.plot_catch_time(runs, tmp_path / "catch_time.png", load_scene("rig"), 0.05)
    assert path.exists() and path.stat().st_size > 5000


def test_metric_labels_are_words_with_units():
    from impact_env.eval.rollout import EPISODE_METRICS

    assert set(EPISODE_METRICS) <= set(METRIC_LABELS)
    for label in METRIC_LABELS.values():
        assert not re.search(r"[a-z]+_[a-z]+", label), label


def test_trajectory_plot_energy_legend_has_no_code_names(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    import impact_env
    from impact_env.eval.plots import plot_trajectory

    legends = []
    real_close = plt.close

    def close(fig=None):
        if fig is not None:
            for a in fig.axes:
                legends.extend(t.get_text() for t in (a.get_legend().get_texts() if a.get_legend() else []))
        real_close(fig)

    monkeypatch.setattr(plt, "close", close)
    plot_trajectory(impact_env.simulate("rig", t_end=0.02), str(tmp_path / "t.png"))
    assert legends and not any(re.search(r"kinetic\d|_", t) for t in legends), legends
    assert np.all([t for t in legends])


def test_one_style_formats_welch_and_no_flat_zero_lines(runs, tmp_path, monkeypatch):
    """Every figure at 150 dpi; compare --format writes pdf or svg; the force spectrum is a Welch
    density (steady: a pure 50 Hz sine peaks in its bin); a policy that applies no force is
    named in the title, not drawn as a flat zero line."""
    from PIL import Image

    from impact_env.eval.compare import write_outputs
    from impact_env.eval.figstyle import figure_path

    scene = load_scene("rig")
    paths = write_outputs(runs, tmp_path / "png", scene, 0, 0.05)
    assert all(Image.open(p).info["dpi"][0] >= 149 for p in paths if p.suffix == ".png")
    svg = write_outputs(runs, tmp_path / "svg", scene, 0, 0.05, fmt="svg")
    assert sum(p.suffix == ".svg" for p in svg) == 4 and b"<svg" in svg[-1].read_bytes()[:400]
    with pytest.raises(ValueError, match="png, pdf, svg"):
        figure_path(tmp_path / "x.jpg")
    dt = 1e-4
    t = np.arange(20_000) * dt
    freq, asd = CP.force_asd(np.sin(2 * np.pi * 50.0 * t), dt)
    assert abs(freq[np.argmax(asd)] - 50.0) <= freq[1]
    seen = capture(monkeypatch)
    titles = []
    monkeypatch.setattr(CP, "_finish", lambda plt, fig, ax, title, *a, **k: (titles.append(title),
                                                                              plt.close(fig))[0])
    CP.plot_force(runs, tmp_path / "f.png", scene)
    assert "no force: passive" in titles[0]
    del seen
