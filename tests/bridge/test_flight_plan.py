"""The flight plan (mavastsm/bridge/flight_plan.py): what the preflight's findings decide, with no link and no
controller built. Parameter values come from a dict, as the preflight would have read them."""

from __future__ import annotations

import math

import pytest

from mavastsm.bridge.autopilots.profile import CLIMB_RATE, COLLECTIVE
from mavastsm.bridge.autopilots.ardupilot import ardupilot_profile
from mavastsm.bridge.autopilots.px4 import px4_profile
from mavastsm.bridge.bridge_config import load_bridge_config
from mavastsm.bridge.flight_plan import alpha_ceiling, alpha_within_ceiling, plan_flight, recognise_vehicle
from mavastsm.config_loading import per_axis
from mavastsm.control import make_controller
from mavastsm.errors import ConfigError
from mavastsm.solo_model import load_solo, packaged_vehicle_tunings

ARDUPILOT = ardupilot_profile(CLIMB_RATE)


def _astsm(vehicle: str = "solo"):
    cfg = load_bridge_config()
    return make_controller("astsm", load_solo(vehicle), getattr(cfg.presets, "astsm"))


def _plan(params: dict, *, profile=ARDUPILOT, controller=None, named=True, given=None, user_keys=(), **kw):
    cfg = load_bridge_config()
    return plan_flight(cfg, profile, granted_rate_hz=kw.pop("granted_rate_hz", cfg.timing.attitude_rate_hz),
                       report_accel_limit_radss=None, controller=controller or _astsm(), controller_named=named,
                       controller_vehicle="solo", vehicle_given=given, user_mapping_keys=set(user_keys),
                       read_parameter=params.get, **kw)


def test_a_vehicle_reporting_a_packaged_tuning_flies_that_description():
    stock = packaged_vehicle_tunings()["arducopter_sitl_quad"]
    name, why, stand_in = recognise_vehicle(ARDUPILOT, stock.get)
    assert name == "arducopter_sitl_quad" and why.startswith("recognised by its ATC_") and not stand_in
    plan = _plan(stock)
    assert plan.vehicle == "arducopter_sitl_quad" and plan.rebuild_controller  # another vehicle's I0
    assert plan.notes[0].startswith("vehicle description: arducopter_sitl_quad (recognised")


def test_an_unknown_tuning_flies_the_default_and_says_so():
    """On ArduPilot the default is the description measured at ArduCopter's default tuning, not the Solo's: a Solo
    retuned on one parameter is no longer the vehicle the Solo's loop numbers were measured on."""
    retuned = {**packaged_vehicle_tunings()["solo"], "ATC_ANG_YAW_P": 2.0}
    assert recognise_vehicle(ARDUPILOT, retuned.get).stand_in
    plan = _plan(retuned)
    assert plan.vehicle == "arducopter_sitl_quad" == ARDUPILOT.default_vehicle
    assert "no packaged description matches its tuning; arducopter_sitl_quad's loop numbers" in plan.notes[0]
    assert "pass --vehicle FILE" in plan.notes[0]




def test_recognition_stops_asking_for_a_description_at_its_first_mismatch():
    """Each name the vehicle does not answer costs link.param_timeout_s: a vehicle that answers nothing is asked one
    name per packaged ArduPilot description (the first of each), not every name of each."""
    asked = []
    found = recognise_vehicle(ARDUPILOT, lambda p: asked.append(p))
    tunings = [t for t in packaged_vehicle_tunings().values() if all(n.startswith("ATC_") for n in t)]
    assert found.stand_in and len(tunings) >= 2
    assert asked == [next(iter(t)) for t in tunings], asked

PX4_STOCK = packaged_vehicle_tunings()["px4_sih_quadx"]


def test_px4_is_recognised_by_its_mc_gains_and_never_asked_for_arducopters():
    """PX4 recognises px4_sih_quadx by PX4's default MC_* rate and angle gains; any other (the Solo's PX4 tuning,
    configs/px4/solo.params: MC_ROLLRATE_P 0.135) flies its numbers as a stand-in. It is never asked for ATC_*, nor
    ArduPilot for MC_* (each unanswered name costs link.param_timeout_s)."""
    asked = []
    stock = recognise_vehicle(px4_profile(), lambda p: asked.append(p) or PX4_STOCK.get(p))
    assert stock.vehicle == "px4_sih_quadx" and stock.why.startswith("recognised by its MC_") and not stock.stand_in
    assert asked and all(p.startswith("MC_") for p in asked), asked
    solo_tuned = recognise_vehicle(px4_profile(), {**PX4_STOCK, "MC_ROLLRATE_P": 0.135}.get)
    assert solo_tuned.vehicle == "px4_sih_quadx" and solo_tuned.stand_in
    asked.clear()
    recognise_vehicle(ARDUPILOT, lambda p: asked.append(p))
    assert asked and all(p.startswith("ATC_") for p in asked), asked


RETUNED_YAW = {**packaged_vehicle_tunings()["arducopter_sitl_quad"], "ATC_ANG_YAW_P": 8.0, "ATC_ACCEL_Y_MAX": 45000.0,
               "ATC_RAT_YAW_P": 0.6}


def test_an_unknown_tuning_flies_the_yaw_tau_its_heading_loop_asks_for():
    """Issue 27: tau_z x ATC_ANG_YAW_P x ATC_RAT_YAW_P is the heading-trim path's gain; on a vehicle no description
    matches, tau_z keeps it at mapping.yaw_loop_gain (0.09: under the 0.108 of ArduCopter's default tuning, 0.08 s x
    4.5 x 0.3, and the Solo's 0.094). Roll
    and pitch keep the default description's tau; the note says where the number came from."""
    plan = _plan(RETUNED_YAW)
    assert plan.vehicle == "arducopter_sitl_quad"
    tau = plan.config.mapping.rate_time_constant_s
    assert tau[:2] == (0.05, 0.05) and tau[2] == pytest.approx(0.09 / (8.0 * 0.6)), tau
    assert f"yaw tau_z {0.09 / 4.8:.3g} s = mapping.yaw_loop_gain 0.09 / (ATC_ANG_YAW_P 8 x ATC_RAT_YAW_P 0.6)" in plan.notes, plan.notes
    # ArduCopter's default tuning one count off (not recognised) flies 0.09 / 1.35 s, a sixth under the 0.08 s its
    # description measured: the rule keeps a margin from the limit cycle
    default_tuning = {**packaged_vehicle_tunings()["arducopter_sitl_quad"], "ATC_ANG_YAW_P": 4.5, "ATC_RAT_YAW_P": 0.3,
                      "ATC_ACCEL_Y_MAX": 27001.0}
    assert _plan(default_tuning).config.mapping.rate_time_constant_s[2] == pytest.approx(0.09 / 1.35)


def test_the_yaw_tau_rule_leaves_what_was_measured_or_asked_for_alone():
    """A recognised description, a given --vehicle, the user's --set of the time constants and an unreadable yaw rate P
    keep their tau_z; the derived one is bounded to 5-200 ms; mapping.yaw_loop_gain 0 turns the rule off; PX4 (no
    attitude target behind its rate setpoints, M2 on yaw) never uses it."""
    stock = packaged_vehicle_tunings()["arducopter_sitl_quad"]
    assert _plan({**stock, "ATC_RAT_YAW_P": 0.6}).config.mapping.rate_time_constant_s[2] == 0.08  # recognised
    assert _plan(RETUNED_YAW, given="arducopter_sitl_quad").config.mapping.rate_time_constant_s[2] == 0.08
    user = load_bridge_config().mapping.rate_time_constant_s  # what --set put in the config (here bridge.yaml's)
    assert _plan(RETUNED_YAW, user_keys={"rate_time_constant_s"}).config.mapping.rate_time_constant_s == user
    blind = _plan({k: v for k, v in RETUNED_YAW.items() if k != "ATC_RAT_YAW_P"})
    assert blind.config.mapping.rate_time_constant_s[2] == 0.08
    assert "yaw tau_z not derived from the heading loop (ATC_ANG_YAW_P 8, ATC_RAT_YAW_P unreadable)" in " ".join(blind.notes)
    assert _plan({**RETUNED_YAW, "ATC_RAT_YAW_P": 50.0}).config.mapping.rate_time_constant_s[2] == 0.005
    off = plan_flight_with_mapping(RETUNED_YAW, yaw_loop_gain=0.0)
    assert off.config.mapping.rate_time_constant_s[2] == 0.08 and not any("yaw tau_z" in n for n in off.notes)
    assert not px4_profile().heading_loop_params


def test_the_loop_is_identified_in_flight_where_no_description_says_what_to_fly():
    """Issue 27: mapping.identify_in_flight auto flies the identification phase on a tuning no packaged description
    matches and says so; not on a recognised vehicle, a given --vehicle, a user's --set of the rate loop's tau, nor on
    PX4's stock tuning; on PX4 another tuning is a stand-in as on ArduPilot; always: on every flight; never: never."""
    stock = packaged_vehicle_tunings()["arducopter_sitl_quad"]
    unknown = _plan(RETUNED_YAW)
    assert unknown.identify_in_flight
    assert any(n.startswith("the loop is identified in flight before the profile (mapping.identify_in_flight=auto)")
               for n in unknown.notes), unknown.notes
    assert not _plan(stock).identify_in_flight
    assert not _plan(RETUNED_YAW, given="arducopter_sitl_quad").identify_in_flight
    assert not _plan(RETUNED_YAW, user_keys={"rate_time_constant_s"}).identify_in_flight
    assert not _plan(PX4_STOCK, profile=px4_profile()).identify_in_flight
    assert _plan({**PX4_STOCK, "MC_PITCH_P": 5.0}, profile=px4_profile()).identify_in_flight
    assert plan_flight_with_mapping(stock, identify_in_flight="always").identify_in_flight
    assert not plan_flight_with_mapping(RETUNED_YAW, identify_in_flight="never").identify_in_flight


def test_a_given_description_says_when_the_vehicle_is_no_longer_tuned_as_it_was(tmp_path):
    """--vehicle FILE whose autopilot_tuning differs from what the vehicle reports flies FILE and says which parameters
    changed (its loop numbers were chosen at the old tuning); the same tuning, or a description without one, says
    nothing."""
    solo = packaged_vehicle_tunings()["solo"]
    same = _plan(solo, given="solo")
    assert not any("another tuning" in n for n in same.notes), same.notes
    drifted = _plan({**solo, "ATC_ANG_YAW_P": 5.0}, given="solo")
    assert drifted.vehicle == "solo"
    assert "solo was chosen at another tuning (ATC_ANG_YAW_P 3.42 -> 5): its loop numbers may not apply" in " ".join(drifted.notes)
    assert not any("another tuning" in n for n in _plan(PX4_STOCK, profile=px4_profile(), given="px4_sih_quadx").notes)
    assert "px4_sih_quadx was chosen at another tuning (MC_ROLLRATE_P 0.15 -> 0.135)" in " ".join(
        _plan({**PX4_STOCK, "MC_ROLLRATE_P": 0.135}, profile=px4_profile(), given="px4_sih_quadx").notes)
    # another autopilot's tuning in the description says nothing: a Solo description flown on PX4
    assert not any("another tuning" in n for n in _plan(PX4_STOCK, profile=px4_profile(), given="solo").notes)


def plan_flight_with_mapping(params: dict, **mapping):
    import dataclasses

    cfg = load_bridge_config()
    cfg = dataclasses.replace(cfg, mapping=dataclasses.replace(cfg.mapping, **mapping))
    return plan_flight(cfg, ARDUPILOT, granted_rate_hz=cfg.timing.attitude_rate_hz, report_accel_limit_radss=None,
                       controller=_astsm(), controller_named=True, controller_vehicle="solo", vehicle_given=None,
                       user_mapping_keys=set(), read_parameter=params.get)


def test_a_given_vehicle_is_flown_without_reading_a_parameter():
    plan = _plan({}, given="arducopter_sitl_quad")
    assert plan.vehicle == "arducopter_sitl_quad" and "pass --vehicle" not in plan.notes[0]


def test_the_users_set_of_a_mapping_key_wins_over_the_vehicle_description():
    stock = packaged_vehicle_tunings()["solo"]
    described = _plan(stock).config.mapping.rate_time_constant_s
    cfg_default = load_bridge_config().mapping.rate_time_constant_s
    kept = _plan(stock, user_keys={"rate_time_constant_s"}).config.mapping.rate_time_constant_s
    assert kept == cfg_default and described != cfg_default


def test_the_adaptive_gain_is_bounded_by_the_loop_delay_ceiling():
    """eq. 34: alpha_max = min(preset, sqrt(mu) / (0.709 L)) per axis, alpha_min at most half of it; the rebuilt law's
    clamp then sits at or below the ceiling (no ADAPTIVE_GAIN_PINNED for a designed maximum)."""
    plan = _plan(packaged_vehicle_tunings()["solo"])
    lo, hi = plan.controller_overrides["alpha_min"], plan.controller_overrides["alpha_max"]
    ceiling = alpha_ceiling(_astsm(), plan.config.mapping)
    preset = _astsm().adaptive_gain()
    assert all(h == pytest.approx(min(p, c)) for h, p, c in zip(hi, per_axis(preset.alpha_max), ceiling))
    assert all(l_ <= 0.5 * h + 1e-12 for l_, h in zip(lo, hi))
    assert any("adaptive gain bounded by the loop delay" in n for n in plan.notes)
    rebuilt = make_controller("astsm", plan.solo, getattr(plan.config.presets, "astsm"), plan.controller_overrides)
    assert alpha_within_ceiling(rebuilt, plan.config.mapping) and not alpha_within_ceiling(_astsm(), plan.config.mapping)


def test_the_bound_is_off_when_asked_and_a_controller_object_is_flown_as_built():
    off = load_bridge_config(overrides={"mapping": {"bound_adaptive_gain": False}})
    plan = plan_flight(off, ARDUPILOT, granted_rate_hz=off.timing.attitude_rate_hz, report_accel_limit_radss=None,
                       controller=_astsm(), controller_named=True, controller_vehicle="solo", vehicle_given="solo",
                       user_mapping_keys=set(), read_parameter={}.get)
    assert "alpha_max" not in plan.controller_overrides
    as_built = _plan({}, named=False, given="arducopter_sitl_quad")
    assert as_built.controller_overrides == {} and not as_built.rebuild_controller


def test_the_yaw_integral_is_left_to_arducopters_attitude_target_not_px4s():
    """M7: on ArduPilot (a hidden attitude target, yaw on the reference: M6) the law's yaw integral is off; PX4 keeps it."""
    ap = _plan({}, given="solo")
    assert ap.controller_overrides["epsilon"][2] == 0.0 and any("yaw integral left to" in n for n in ap.notes)
    px4 = _plan({}, profile=px4_profile(), given="solo")
    assert "epsilon" not in px4.controller_overrides


def test_the_granted_rate_and_the_torque_authority_are_planned():
    plan = _plan({}, given="solo", granted_rate_hz=320.0)
    assert plan.config.timing.attitude_rate_hz == 320.0
    assert len(plan.torque_authority_nm) == 3 and all(math.isfinite(t) and t > 0 for t in plan.torque_authority_nm)
    assert plan.controller_overrides["torque_limit_nm"] == pytest.approx(plan.torque_authority_nm)


def test_options_the_autopilot_cannot_fly_are_a_config_error():
    with pytest.raises(ConfigError, match="--mode OFFBOARD: .* only in GUIDED"):
        _plan({}, given="solo", mode="OFFBOARD")
    with pytest.raises(ConfigError, match="--takeoff-m needs climb-rate thrust"):
        _plan({}, profile=ardupilot_profile(COLLECTIVE), given="solo", takeoff_alt_m=2.0)
