"""Laser operating limits from Python (issue 14, part 4): ``Beam`` and ``plan`` refuse an
operating point outside the given ``laser_limits`` (a laser profile's ``[limits]`` keys) with a
``ValueError`` naming the limit, as ``trimctl beam``/``plan`` do for ``cell.laser_profile``."""

import pytest

import trimctl

# The source the paper names (§4): 60 W, at most 30 µJ, 1 Hz-2 MHz.
STATED = {
    "pulse_energy_uj_max": 30.0,
    "average_power_w_max": 60.0,
    "rep_rate_khz_min": 0.001,
    "rep_rate_khz_max": 2000.0,
}
# crates/io/profiles/high-energy.toml, the default profile.
HIGH_ENERGY = {
    "pulse_energy_uj_max": 250.0,
    "average_power_w_max": 60.0,
    "rep_rate_khz_min": 200.0,
    "rep_rate_khz_max": 2000.0,
}


def test_beam_checks_the_operating_point_against_the_given_limits():
    # The paper's figures pass on the high-energy source and without limits.
    assert trimctl.Beam(laser_limits=HIGH_ENERGY).pulse_energy_uj == pytest.approx(214.36, abs=1e-9)
    assert trimctl.Beam().pulse_energy_uj == pytest.approx(214.36, abs=1e-9)
    # ... and not on the source the paper names: 214.36 µJ against 30 µJ.
    with pytest.raises(ValueError, match=r"pulse energy 214\.36 µJ .* limits\.pulse_energy_uj_max = 30 µJ"):
        trimctl.Beam(laser_limits=STATED)
    # At 2 MHz the same 53.59 W is 26.8 µJ: within it.
    fast = trimctl.Beam(repetition_rate_hz=2e6, laser_limits=STATED)
    assert fast.pulse_energy_uj == pytest.approx(26.795, abs=1e-9)
    with pytest.raises(ValueError, match=r"average power 70 W \(beam\.power_w\) is above limits\.average_power_w_max"):
        trimctl.Beam(power_w=70.0, repetition_rate_hz=1e6, laser_limits=HIGH_ENERGY)
    with pytest.raises(ValueError, match=r"limits\.rep_rate_khz_min = 200 kHz"):
        trimctl.Beam(power_w=1.0, repetition_rate_hz=1e5, laser_limits=HIGH_ENERGY)
    # Bad limits are refused by key, never a panic.
    with pytest.raises(ValueError, match="rep_rate_khz_min"):
        trimctl.Beam(laser_limits={**STATED, "rep_rate_khz_min": 5000.0})
    with pytest.raises(ValueError, match="pulse_energy_uj_maxx"):
        trimctl.Beam(laser_limits={**STATED, "pulse_energy_uj_maxx": 1.0})
    with pytest.raises(ValueError, match="average_power_w_max"):
        trimctl.Beam(laser_limits={k: v for k, v in STATED.items() if k != "average_power_w_max"})
    with pytest.raises(ValueError, match="pulse_energy_uj_max"):
        trimctl.Beam(laser_limits={**STATED, "pulse_energy_uj_max": float("nan")})


def test_plan_refuses_a_point_outside_the_limits_before_planning():
    case = trimctl.synth(seed=3, scan_points=20_000, cad_points=20_000)
    with pytest.raises(ValueError, match=r"limits\.pulse_energy_uj_max = 30 µJ"):
        trimctl.plan(case.path, laser_limits=STATED)
    # The limits a Beam was made with carry over to plan().
    with pytest.raises(ValueError, match=r"limits\.average_power_w_max = 60 W"):
        trimctl.plan(case.path, beam=trimctl.Beam(power_w=61.0, repetition_rate_hz=1e6),
                     laser_limits=HIGH_ENERGY)
    plan = trimctl.plan(case.path, beam=trimctl.Beam(laser_limits=HIGH_ENERGY))
    assert len(plan.zones) > 0
