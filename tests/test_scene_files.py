"""Scene files: ``base = "rig"`` and only the changes; missing or broken files name the file;
output paths are checked before anything runs."""

from __future__ import annotations

import pytest

from impact_env.cli import compare as cli_compare
from impact_env.cli import main
from impact_env.config import ConfigError
from impact_env.scene import load_scene


def write(path, text):
    path.write_text(text)
    return str(path)


def test_a_file_starts_from_a_preset(tmp_path):
    f = write(tmp_path / "heavy.toml", 'base = "rig"\nname = "rig-heavy"\n[plant]\nm1 = 0.2\n'
                                       '[effects.saturation]\npeak_n = 300.0\n')
    s = load_scene(f)
    rig = load_scene("rig")
    assert s.name == "rig-heavy" and s.plant.m1 == 0.2 and s.effects.saturation.peak_n == 300.0
    assert s.with_overrides({"name": "rig", "plant.m1": 0.1, "effects.saturation.peak_n": 200.0}) == rig


def test_bases_chain_relative_to_the_file_and_impact_speed_replaces_the_drop(tmp_path):
    write(tmp_path / "heavy.toml", 'base = "rig"\n[plant]\nm1 = 0.2\n')
    sub = tmp_path / "sub"
    sub.mkdir()
    f = write(sub / "fast.toml", 'base = "../heavy.toml"\n[initial]\nimpact_speed = 1.5\n')
    s = load_scene(f)
    assert s.plant.m1 == 0.2 and s.initial.impact_speed == 1.5 and s.initial.drop_height is None
    assert s.plant.restitution == 0.8  # from rig, two bases down


def test_scene_show_prints_the_resolved_scene(tmp_path, capsys):
    f = write(tmp_path / "s.toml", 'base = "rig"\n[plant]\nc = 3e6\n')
    assert main(["scene", "show", f]) == 0
    out = capsys.readouterr().out
    assert "c = 3000000.0" in out and "restitution = 0.8" in out and "base" not in out


def test_a_base_cycle_is_refused(tmp_path):
    write(tmp_path / "a.toml", 'base = "b.toml"\n')
    write(tmp_path / "b.toml", 'base = "a.toml"\n')
    with pytest.raises(ConfigError, match="a cycle"):
        load_scene(str(tmp_path / "a.toml"))


@pytest.mark.parametrize("text,match", [
    (None, "does not exist"),
    ("[plant\nm1 = 1\n", r"is not valid TOML: .*line 1"),
    ('base = "rig"\n[plant]\nm3 = 1\n', "unknown key 'plant.m3'"),
    ('base = "rgi"\n', "did you mean 'rig'"),
])
def test_file_errors_name_the_file(tmp_path, capsys, text, match):
    path = tmp_path / "scene.toml"
    if text is not None:
        path.write_text(text)
    assert main(["drop", "--scene", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err
    import re

    assert re.search(match, err), err


def test_out_is_checked_before_anything_runs(tmp_path, capsys, monkeypatch):
    def boom(*a, **k):
        raise AssertionError("simulated before checking --out")

    monkeypatch.setattr(cli_compare, "compare", boom)
    monkeypatch.setattr("impact_env.cli.sweep.sweep", boom)
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert main(["compare", "--policies", "passive", "--episodes", "1", "--out", str(afile)]) == 2
    assert "is a file" in capsys.readouterr().err
    assert main(["compare", "--policies", "passive", "--episodes", "1", "--out", str(afile / "sub")]) == 2
    assert "cannot create the folder" in capsys.readouterr().err
    assert main(["sweep", "--out", str(afile)]) == 2
    assert "is a file" in capsys.readouterr().err
    assert main(["drop", "--plot", str(tmp_path / "nope" / "x.png")]) == 2
    assert "does not exist" in capsys.readouterr().err
