"""``mpc``'s hand-over to ``pd-penetration`` when its filter shows the model wrong
(:mod:`impact_env.control.laws.mpc`): on ``rig-randomized`` drops, with the nominal model taken
as exact (``untold_error=0``), it hands over in the first ticks, counted, and from then on its
commands are ``pd-penetration``'s, bitwise; with the model's error allowed for (the default
there) it keeps planning; on ``rig``'s drops, whose plant is the filter's model, it does not hand
over in the first contact; the C export replays a drop with the hand-over bitwise."""

from __future__ import annotations

import numpy as np
import pytest

from impact_env.control.laws import mpc
from impact_env.control.policy import act_batch
from impact_env.policy.export import export_policy
from impact_env.scene import load_scene
from impact_env.sim.simulator import Simulator

SPEC = "mpc:horizon=8"  # a short horizon: the same code as the default 40, cheaper
EXACT = SPEC + ",untold_error=0"  # the nominal model taken as exact on a rig it is not told
N_DROPS = 8
TICKS = 300  # the touch at tick 10, the first contact and its bounce
FIRST_WINDOW = 50  # ticks of the filter's first lost-track window (estimation.model.SETTINGS)


def _drive(scene_name: str, seed: int, spec: str = SPEC):
    """N_DROPS drops driven by ``mpc``, with ``pd-penetration`` fed the same observations beside
    it: (mpc's commands, pd's commands, the hand-over flag per tick, mpc's memory at the end)."""
    scene = load_scene(scene_name)
    law, fallback = export_policy(spec, scene), export_policy("pd-penetration", scene)
    assert law.layout.names == fallback.layout.names
    sim = Simulator(scene, N_DROPS, layout=law.layout)
    sim.reset([np.random.default_rng(seed + i) for i in range(N_DROPS)])
    (pi, pf, m), (fpi, fpf, fm) = law.arrays(), fallback.arrays()
    mem, fmem = np.zeros((N_DROPS, m)), np.zeros((N_DROPS, fm))
    commands, fallback_commands, on = (np.zeros((N_DROPS, TICKS)) for _ in range(3))
    for t in range(TICKS):
        obs = np.ascontiguousarray(sim.obs)
        commands[:, t] = act_batch(pi, pf, obs, mem, np.empty(N_DROPS))
        fallback_commands[:, t] = act_batch(fpi, fpf, obs, fmem, np.empty(N_DROPS))
        on[:, t] = mem[:, mpc.FALLBACK_ON]
        sim.step(commands[:, t])
    return commands, fallback_commands, on, mem


def test_off_its_model_mpc_hands_over_to_pd_penetration_counted_and_bitwise():
    commands, fallback_commands, on, mem = _drive("rig-randomized", 7020000, EXACT)
    for i in range(N_DROPS):
        ticks_on = np.flatnonzero(on[i])
        assert ticks_on.size, f"drop {i} never handed over"
        first = ticks_on[0]
        assert first < FIRST_WINDOW, (i, first)  # by the one-tick gate, before the first window's test
        assert np.all(on[i, first:] == 1.0), "latched"
        np.testing.assert_array_equal(commands[i, first:], fallback_commands[i, first:])
        assert mem[i, mpc.FALLBACK_TICKS] == TICKS - first
    # before the hand-over the plan acted: mpc's commands are not pd's
    firsts = [np.flatnonzero(on[i])[0] for i in range(N_DROPS)]
    assert any(np.any(commands[i, :first] != fallback_commands[i, :first]) for i, first in enumerate(firsts))


def test_allowing_for_its_models_error_mpc_keeps_planning_on_untold_rigs():
    commands, fallback_commands, on, _mem = _drive("rig-randomized", 7020000)
    assert not on.any(), np.flatnonzero(on.any(axis=1))
    assert np.any(commands != fallback_commands)


def test_on_its_model_mpc_keeps_planning_through_the_first_contact():
    commands, fallback_commands, on, mem = _drive("rig", 7010000)
    first_contact = slice(0, FIRST_WINDOW + 10)
    assert not on[:, first_contact].any(), np.flatnonzero(on.any(axis=1))
    assert np.any(commands[:, first_contact] != fallback_commands[:, first_contact])


@pytest.mark.slow
def test_the_c_export_replays_the_hand_over_bitwise(tmp_path):
    from impact_env.deploy import parity
    from impact_env.deploy.c_export import write_c

    scene = load_scene("rig-randomized")
    policy = export_policy(EXACT, scene)
    write_c(policy, scene, tmp_path / "c")
    cp = parity.CPolicy(parity.build_shared(tmp_path / "c", tmp_path / "lib.so"), False)
    rec = parity.record(policy, scene, 3, 600)
    assert rec.memory[mpc.FALLBACK_ON] == 1.0 and 0 < rec.memory[mpc.FALLBACK_TICKS] < 600, "it handed over"
    got = parity.replay(cp, rec)
    np.testing.assert_array_equal(got.command, rec.command)
    np.testing.assert_array_equal(got.status, rec.status)
