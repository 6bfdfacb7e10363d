"""Pair halves (issue 26): a pair whose two cantilevers differ, each its own resonator,
both striking the same slider; identical halves change nothing."""

from __future__ import annotations

import numpy as np
import pytest

import model
from model import Drive, Impacter, PairHalves, Slider, pair_of
from planner.fabrication.tolerances import ChipDesign, NodeDesign, sample_chip
from planner.core.nodes import Node
from planner.planning.verify import device_motion, pair_responses
from planner.arrayspec import ArraySpec

#: The paper's Fig. 7 device (5.2 kHz in 10 mTorr) and a slider of Table I.
IMP = Impacter.from_geometry(1.5e-8, 4e-6, 1242e-6, 3e-6).with_natural_frequency(5200.0)
SLIDER = Slider.from_geometry(8.0e-8)
A1F = Node("A1", "forward")
DRIVE = Drive.tone(6200.0)


def test_equal_halves_are_the_symmetric_pair():
    assert pair_of(IMP, IMP) is IMP
    assert model.halves(IMP) == ((IMP, 1.0),)
    p = PairHalves(IMP, IMP.with_natural_frequency(5300.0))
    assert [s for _, s in model.halves(p)] == [0.5, 0.5]
    with pytest.raises(ValueError):
        PairHalves(IMP, "not an impacter")


def test_two_equal_halves_striking_alone_move_the_slider_as_the_pair():
    """Under eq. (10) (the paper's law, linear in m/M) two equal halves, each simulated
    on its own and kicking with half the pair's mass, move the slider exactly as the
    symmetric pair: the half-pair bookkeeping adds up to the pair's."""
    start = {A1F: (0.0, 0.0, False)}
    z_pair, v_pair = device_motion({A1F: IMP}, SLIDER, DRIVE, 3e-3, start, "paper")
    halves = {A1F: PairHalves(IMP, IMP)}
    z_h, v_h = device_motion(halves, SLIDER, DRIVE, 3e-3, start, "paper")
    assert z_pair > 1e-7                       # it moves (Fig. 7: um in 3 ms)
    assert z_h == pytest.approx(z_pair, rel=1e-12)
    assert v_h == pytest.approx(v_pair, rel=1e-12, abs=1e-15)


def test_a_detuned_half_leaves_the_other_to_push_alone():
    """One half tuned 30 % away no longer hits at 6.2 kHz: the slider moves less than half
    as far (one cantilever kicking instead of two, and the same Coulomb friction taking its
    toll of a slower slider), but it moves; an idle check sees the half that answers."""
    start = {A1F: (0.0, 0.0, False)}
    z_pair, _ = device_motion({A1F: IMP}, SLIDER, DRIVE, 3e-3, start, "paper")
    off = IMP.with_natural_frequency(5200.0 * 1.3)
    z_one, _ = device_motion({A1F: PairHalves(IMP, off)}, SLIDER, DRIVE, 3e-3, start,
                             "paper")
    assert 0.1 * z_pair < z_one < 0.5 * z_pair
    # the pair answers where either half does, from each x0 of the grid
    r = pair_responses(PairHalves(off, IMP), DRIVE, 5, 3e-3)
    assert np.array_equal(r, np.maximum(pair_responses(off, DRIVE, 5, 3e-3),
                                        pair_responses(IMP, DRIVE, 5, 3e-3)))


def _design():
    spec = ArraySpec.model_validate({"fabrication": {"line_width_um": {"die": 0.05,
                                                                       "device": 0.02}}})
    nodes = (NodeDesign("A1.forward", "A1", "forward", 3e-8, 5.5e-6, 4e-4, 4e-6, 0.785, 0.5),
             NodeDesign("A1.backward", "A1", "backward", 2e-8, 5.5e-6, 6e-4, 4e-6, 0.785, 0.5))
    return spec, ChipDesign(spec, nodes, ("A1",))


def test_no_pair_level_gives_the_same_chips():
    """The halves are drawn after every other draw: with pair sigma 0 a chip's impacters
    are exactly those of the same seed without the level, and symmetric pairs."""
    spec, design = _design()
    a = sample_chip(design, spec.fabrication, np.random.default_rng(7))
    fab = spec.fabrication.model_copy(update={"line_width_um": spec.fabrication.line_width_um
                                              .model_copy(update={"pair": 0.0})})
    b = sample_chip(design, fab, np.random.default_rng(7))
    assert a.impacters == b.impacters
    assert all(isinstance(i, Impacter) for i in a.impacters.values())


def test_a_pair_level_splits_the_halves_by_its_sigma():
    """line_width pair sigma 0.01 um on 5.5 um beams (S ~ 0.26/um): the halves' natural
    frequencies differ by sqrt(2) x 0.26 % per chip (one sigma), the pair's draws and
    the chip's other draws unchanged."""
    spec, design = _design()
    fab = ArraySpec.model_validate({"fabrication": {"line_width_um": {
        "die": 0.05, "device": 0.02, "pair": 0.01}}}).fabrication
    diffs = []
    for seed in range(200):
        chip = sample_chip(design, fab, np.random.default_rng(seed))
        p = chip.impacters["A1.forward"]
        assert isinstance(p, PairHalves)
        diffs.append(p.a.natural_frequency / p.b.natural_frequency - 1.0)
        plain = sample_chip(design, spec.fabrication, np.random.default_rng(seed))
        assert chip.sliders == plain.sliders and chip.errors == plain.errors
    sd = float(np.std(diffs))
    assert sd == pytest.approx(np.sqrt(2) * 0.26 * 0.01 * 0.01 * 100, rel=0.2)


def test_the_pair_level_lowers_the_predicted_yield():
    from planner.fabrication.tolerances import ERRORS
    from planner.manufacturability import collision_free_yield

    nu = np.array([30000.0, 30700.0])
    sens = np.zeros((2, len(ERRORS)))
    sens[:, 0] = 0.25                                      # 1/um
    zero = np.zeros(len(ERRORS))
    dev = zero.copy()
    dev[0] = 0.02
    kw = dict(silent_below=[400, 400], silent_above=[400, 400], responds_below=[80, 80],
              responds_above=[80, 80], chips=20000, seed=1)
    base = collision_free_yield(["a", "b"], nu, nu, sens, zero, dev, [[0, 1]], **kw)
    same = collision_free_yield(["a", "b"], nu, nu, sens, zero, dev, [[0, 1]],
                                sigma_pair=zero, **kw)
    pair = dev.copy()
    pair[0] = 0.02
    split = collision_free_yield(["a", "b"], nu, nu, sens, zero, dev, [[0, 1]],
                                 sigma_pair=pair, **kw)
    assert same.value == base.value
    assert split.value < base.value - 0.02
