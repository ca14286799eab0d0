"""Messages a user meets on a wrong first try: each names what was wrong and what is accepted,
and a retry with the suggested fix does not meet a second, contradicting one."""

from __future__ import annotations

import gymnasium as gym
import pytest

import impact_env  # noqa: F401  (registers the envs)
from impact_env.cli.main import main
from impact_env.env.vector import ImpactCatchVectorEnv


def test_export_c_onto_a_file_says_so_once_with_or_without_force(tmp_path, capsys):
    """``--c FILE`` on an existing file: "exists and is not a folder" at once, not first "the
    folder exists; pass --force" and then, with --force, the other; the file is left as it was."""
    target = tmp_path / "policy.c"
    target.write_text("keep me")
    for extra in ([], ["--force"]):
        assert main(["export", "pd-penetration", "--scene", "rig", "--c", str(target), *extra]) == 2
        err = capsys.readouterr().err
        assert f"--c {target}: exists and is not a folder" in err and "--force" not in err, err
    assert target.read_text() == "keep me"
    folder = tmp_path / "c"  # an existing folder still asks for --force, which then writes into it
    folder.mkdir()
    assert main(["export", "pd-penetration", "--scene", "rig", "--c", str(folder)]) == 2
    assert "the folder exists; pass --force" in capsys.readouterr().err
    assert main(["export", "pd-penetration", "--scene", "rig", "--c", str(folder), "--force"]) == 0
    assert sorted(p.suffix for p in folder.iterdir()) == [".c", ".h"]


def test_a_misspelt_env_argument_names_the_env_arguments_too():
    """``gym.make("ImpactCatch-v0", scne=...)``: the error lists ``scene`` (the env's own argument)
    beside the task's options, and suggests it."""
    with pytest.raises(TypeError) as err:
        gym.make("ImpactCatch-v0", scne="rig")
    message = str(err.value)
    assert "'scne' (did you mean 'scene'?)" in message
    assert "scene, overrides, render_mode and the catch task's options observation, history" in message
    with pytest.raises(TypeError, match=r"'thraeds' \(did you mean 'threads'\?\).* num_envs, scene"):
        ImpactCatchVectorEnv(2, thraeds=1)
    with pytest.raises(TypeError, match=r"'hold_tick' \(did you mean 'hold_ticks'\?\)"):
        gym.make("ImpactCatch-v0", hold_tick=2)
