"""Plots: one colour per policy in every panel, every axis a quantity with a unit (or a ratio),
no code names, the filter band from the scene, the catch-time figure."""

from __future__ import annotations

import re

import numpy as np
import pytest

from impact_env.eval import compare_plots
from impact_env.eval.labels import METRIC_LABELS, policy_colors
from impact_env.scene import load_scene

SPECS = ["passive", "thesis-rig", "pd-penetration"]  # passive: no force, so no spectrum line


@pytest.fixture
def runs(rig_runs):  # tests/conftest.py: built once per session
    assert list(rig_runs) == SPECS
    return rig_runs


def capture(monkeypatch):
    """Replace the figure writer by one that keeps each panel's line colours and axis labels."""
    seen = {}

    def finish(plt, fig, ax, title, path, legend_size, xlabel=None, which="major", legend_below=None):
        for a in ax:
            if xlabel:
                a.set_xlabel(xlabel)
        seen["panels"] = [{"lines": {ln.get_label(): ln.get_color() for ln in a.get_lines()},
                           "x": a.get_xlabel(), "y": a.get_ylabel()} for a in ax]
        seen["legend_below"] = None if legend_below is None else {
            h.get_label(): (h.get_color(), h.get_linestyle()) for h in legend_below}
        plt.close(fig)
        return path

    monkeypatch.setattr(compare_plots, "_finish", finish)
    return seen


@pytest.mark.parametrize("plot", [compare_plots.plot_energy, compare_plots.plot_force, compare_plots.plot_motion])
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
    assert compare_plots.filter_band(load_scene("rig")) == (20.0, 1000.0)
    assert compare_plots.filter_band(load_scene("rig", {"effects.filters.force.high_hz": 800.0})) == (20.0, 800.0)
    assert compare_plots.filter_band(load_scene("ideal")) is None


def test_the_catch_time_figure(runs, tmp_path):
    path = compare_plots.plot_catch_time(runs, tmp_path / "catch_time.png", load_scene("rig"), 0.05)
    assert path.exists() and path.stat().st_size > 5000


def test_the_catch_time_figure_is_in_ms_from_the_touch_like_the_others(runs, tmp_path, monkeypatch):
    """It said "time after the release, s" while the catch times are from the first touch (the
    episode starts 1 ms before it on rig) and every other figure says "time from first touch,
    ms": now the same axis, the medians' dots at the table's medians in ms, and the censored
    drops' triangles at the episode's end, the horizon less the time before the touch."""
    import matplotlib.pyplot as plt

    figs = []
    monkeypatch.setattr(compare_plots, "save_figure", lambda fig, path: (figs.append(fig), path)[1])
    run = runs["passive"]
    ttc = np.array([0.01, 0.02, np.inf])
    from impact_env.eval.compare import PolicyRun

    one = PolicyRun.__new__(PolicyRun)
    one.metrics, one.episodes = {"time_to_catch_s": ttc}, [0, 1, 2]
    one.summary = {"time_to_catch_median_s": 0.02}
    one.t_touch0 = run.t_touch0
    compare_plots.plot_catch_time({"passive": one}, tmp_path / "c.png", load_scene("rig"), 0.05)
    ax = figs[0].axes[0]
    assert ax.get_xlabel() == compare_plots.TOUCH_MS == "time from first touch, ms"
    assert 0.0 < run.t_touch0 < 0.05  # the episode starts before the touch
    marks = {ln.get_marker(): ln.get_xdata()[0] for ln in ax.get_lines() if ln.get_marker() in ("o", ">")}
    assert marks["o"] == pytest.approx(20.0)  # the median, 0.02 s after the touch
    assert marks[">"] == pytest.approx((0.05 - run.t_touch0) * 1e3)  # the episode's end after the touch
    plt.close(figs[0])


def test_the_motion_legend_sits_below_the_curves_one_entry_per_policy_and_per_body(runs, tmp_path,
                                                                                   monkeypatch):
    """motion.png had an 8-entry legend in each panel, over the curves: now one row under the
    panels, a colour per policy and a line style per body."""
    seen = capture(monkeypatch)
    compare_plots.plot_motion(runs, tmp_path / "m.png", load_scene("rig"))
    want = policy_colors(SPECS)
    legend = seen["legend_below"]
    assert {k: v[0] for k, v in legend.items() if k in want} == want
    styles = {v[1] for k, v in legend.items() if k not in want}
    assert len(legend) == len(SPECS) + 2 and styles == {"-", "--"}


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
    plot_trajectory(impact_env.simulate("rig", t_end=0.02, plant_only=True), str(tmp_path / "t.png"))
    assert legends and not any(re.search(r"kinetic\d|_", t) for t in legends), legends
    assert np.all([t for t in legends])


def test_one_style_formats_welch_and_no_flat_zero_lines(runs, tmp_path, monkeypatch):
    """Every figure at 150 dpi; compare --format writes pdf or svg; the force spectrum is a Welch
    density (steady: a pure 50 Hz sine peaks in its bin); a policy that applies no force is
    named in the title, not drawn as a flat zero line."""
    from PIL import Image

    from impact_env.eval.compare import write_outputs
    from impact_env.figstyle import figure_path

    scene = load_scene("rig")
    paths = write_outputs(runs, tmp_path / "png", scene, 0, 0.05)
    assert all(Image.open(p).info["dpi"][0] >= 149 for p in paths if p.suffix == ".png")
    svg = write_outputs(runs, tmp_path / "svg", scene, 0, 0.05, fmt="svg")
    assert sum(p.suffix == ".svg" for p in svg) == 4 and b"<svg" in svg[-1].read_bytes()[:400]
    with pytest.raises(ValueError, match="png, pdf, svg"):
        figure_path(tmp_path / "x.jpg")
    dt = 1e-4
    t = np.arange(20_000) * dt
    freq, asd = compare_plots.force_asd(np.sin(2 * np.pi * 50.0 * t), dt)
    assert abs(freq[np.argmax(asd)] - 50.0) <= freq[1]
    seen = capture(monkeypatch)
    titles = []
    monkeypatch.setattr(compare_plots, "_finish", lambda plt, fig, ax, title, *a, **k: (titles.append(title),
                                                                              plt.close(fig))[0])
    compare_plots.plot_force(runs, tmp_path / "f.png", scene)
    assert "no force: passive" in titles[0]
    del seen


# -- --format on every command that plots, and the rig log's plot ------------------------------------------
MAGIC = {"png": b"\x89PNG", "pdf": b"%PDF", "svg": b"<svg"}


@pytest.fixture(scope="module")
def rig_logs(tmp_path_factory, wait_until):
    """Episode logs of ``passive`` and ``pd-penetration`` run onboard on the virtual rig (lock-step,
    the target in a thread of this process): {policy: path}."""
    import threading

    from impact_env.policy.export import export_policy
    from impact_env.rig.driver import VirtualRig
    from impact_env.rig.host import RigClient
    from impact_env.rig.target import Target, TargetConfig

    logs = tmp_path_factory.mktemp("rig-logs")
    target = Target(VirtualRig("rig"), config=TargetConfig(lockstep=True, log_dir=logs))
    threading.Thread(target=target.serve, daemon=True).start()
    client = RigClient(target.address)
    out = {}
    try:
        for policy in ("passive", "pd-penetration"):
            before = set(logs.glob("episode_*.h5"))
            client.arm("onboard", 3, 1500, policy=export_policy(policy, load_scene("rig")))
            def new(before=before):
                return set(logs.glob("episode_*.h5")) - before

            # a 1500-tick episode takes about a second here: 120 s only guards against a hang
            wait_until(lambda: bool(new()), f"the {policy} episode's log", 120)
            out[policy] = new().pop()
    finally:
        client.close()
        target.stop()
    return out


def _written_type(path) -> str:
    head = path.read_bytes()[:2000]
    return next(fmt for fmt, magic in MAGIC.items()
                if (head.startswith(magic) if fmt != "svg" else magic in head))  # svg: after <?xml ...>


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["png", "pdf", "svg"])
@pytest.mark.parametrize("command", ["sweep", "rig log", "rig log (suffix)", "drop"])
def test_every_plotting_command_writes_the_format_asked(command, fmt, tmp_path, request, capsys):
    """sweep --format, rig log --plot FILE --format (or the file's suffix alone), drop --plot with
    --format: the file written is of that type (its magic bytes, not only its name), PNG at 150 dpi."""
    from PIL import Image

    from impact_env.cli.main import main

    if command == "sweep":
        argv = ["sweep", "--scene", "rig", "--h01", "1e5:1e6:2", "--h11", "1:10:2", "--t-end", "0.005",
                "--workers", "1", "--no-progress", "--out", str(tmp_path), "--format", fmt]
        want = tmp_path / f"sweep.{fmt}"
    elif command.startswith("rig log"):
        log = request.getfixturevalue("rig_logs")["pd-penetration"]
        suffix = command.endswith("(suffix)")
        want = tmp_path / f"log.{fmt}"
        argv = ["rig", "log", str(log), "--plot", str(want if suffix else tmp_path / "log")] + \
            ([] if suffix else ["--format", fmt])
    else:
        want = tmp_path / f"drop.{fmt}"
        argv = ["drop", "--scene", "rig", "--t-end", "0.02", "--plot", str(tmp_path / "drop"),
                "--format", fmt]
    assert main(argv) == 0, capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix != ".csv") == [want.name]
    assert _written_type(want) == fmt
    if fmt == "png":
        assert Image.open(want).info["dpi"][0] >= 149


@pytest.mark.parametrize("argv, names", [
    (["rig", "log", "LOG", "--plot", "x.jpg"], ["--plot", "x.jpg", ".png, .pdf, .svg"]),
    (["rig", "log", "LOG", "--plot", "x.png", "--format", "pdf"], ["--plot", ".png", "--format is pdf"]),
    (["drop", "--scene", "rig", "--plot", "x.gif"], ["--plot", "x.gif"]),
    (["sweep", "--format", "jpg"], ["--format", "'jpg'"]),
])
def test_a_bad_figure_format_is_refused_naming_the_option(argv, names, tmp_path, capsys, monkeypatch):
    """Refused before anything runs (no log read, no simulation), exit 2."""
    from impact_env.cli.main import main

    log = tmp_path / "episode.h5"
    log.write_bytes(b"not read: the plot's name is checked first")
    monkeypatch.chdir(tmp_path)
    argv = [str(log) if a == "LOG" else a for a in argv]
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's choices
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2, err
    for name in names:
        assert name in err, (name, err)
    assert not list(tmp_path.glob("x.*"))


@pytest.mark.slow
def test_rig_log_plot_draws_no_flat_zero_force_lines(rig_logs, tmp_path, monkeypatch):
    """A passive episode's log has no force panel (no lines at 0 N that read like data): the title
    says 'no force demanded or applied'; an episode with a force keeps the panel and both lines."""
    from impact_env import figstyle
    from impact_env.rig.log import read_episode
    from impact_env.rig.log_plot import plot_log

    figs = {}
    real = figstyle.save_figure

    def keep(fig, path):
        figs[path.stem] = {"title": fig._suptitle.get_text(),
                           "lines": [ln.get_label() for a in fig.axes for ln in a.get_lines()],
                           "ylabels": [a.get_ylabel() for a in fig.axes]}
        return real(fig, path)

    monkeypatch.setattr(figstyle, "save_figure", keep)
    for policy, path in rig_logs.items():
        plot_log(read_episode(path), tmp_path / f"{policy}.png")
    passive, pd = figs["passive"], figs["pd-penetration"]
    assert "no force demanded or applied (0 N throughout)" in passive["title"]
    assert not {"demanded (after safety)", "applied"} & set(passive["lines"])
    assert "force on body 2, N (up)" not in passive["ylabels"]
    assert {"demanded (after safety)", "applied"} <= set(pd["lines"]) and "no force" not in pd["title"]
