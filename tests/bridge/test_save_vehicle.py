"""``--save-vehicle FILE`` then ``--vehicle FILE`` (issue 27, "keep what was learned"): the description a flight flew,
written at its end and flown again, against our sim in lockstep; a failsafe-ended flight writes nothing."""

from __future__ import annotations

import pytest

from mavastsm.bridge.bridge_api import Bridge
from mavastsm.lockstep_pair import LockstepPair
from mavastsm.solo_model import load_autopilot_tuning, load_offboard_loop, load_solo, packaged_vehicle_tunings

QUIET = {"timing.prestream_s": 0.2, "timing.overrun_cycles": 2000, "timing.stale_timeout_s": 0.5}


def _fly(lines: list[str], **options):
    with LockstepPair(sim=dict(lockstep_timeout_s=0.1)) as pair:
        opts = pair.bridge_options(controller="astsm", reference="paper_steps", duration_s=5.0, mode="GUIDED_NOGPS", arm=True,
                                   takeoff_alt_m=2.0, on_exit="LAND", print_fn=lines.append,
                                   overrides={**QUIET, **options.pop("overrides", {})}, **options)
        return Bridge(opts).run()


def test_a_saved_description_flies_the_same_numbers_again(tmp_path):
    saved = tmp_path / "my_vehicle.yaml"
    first_lines: list[str] = []
    first = _fly(first_lines, save_vehicle=str(saved))
    assert first.failsafe is None, first.end_reason
    assert any(line.startswith(f"vehicle description saved: {saved}") for line in first_lines), first_lines[-5:]
    # what the Solo's description and the plan gave the loop, and the tuning it was chosen at (the sim reports the Solo's)
    loop = load_offboard_loop(saved)
    assert loop["rate_time_constant_s"] == load_offboard_loop("solo")["rate_time_constant_s"]
    assert loop["roll_pitch_command_base"] == "integrated"
    tuning = load_autopilot_tuning(saved)
    assert {k: tuning[k] for k in packaged_vehicle_tunings()["solo"]} == pytest.approx(packaged_vehicle_tunings()["solo"])
    assert "ATC_RAT_YAW_P" in tuning
    assert load_solo(saved).inertia_diag.tolist() == load_solo("solo").inertia_diag.tolist()

    again_lines: list[str] = []
    again = _fly(again_lines, vehicle_config=str(saved))
    assert again.failsafe is None, again.end_reason
    said = "\n".join(again_lines)
    assert f"vehicle description: {saved}" in said and "was chosen at another tuning" not in said, said[:3000]
    for a, b in zip(first.axes, again.axes):  # the same loop numbers fly the same steps
        assert b.settling_time_5pct_s == pytest.approx(a.settling_time_5pct_s, abs=0.05), (a, b)
        assert b.overshoot_pct == pytest.approx(a.overshoot_pct, abs=1.0), (a, b)


def test_a_flight_a_failsafe_ended_writes_no_description(tmp_path):
    saved = tmp_path / "my_vehicle.yaml"
    lines: list[str] = []
    ended = _fly(lines, save_vehicle=str(saved), overrides={"limits.envelope_tilt_deg": 6.0})
    assert ended.failsafe is not None and not saved.exists()
    assert f"--save-vehicle: {saved} not written: the flight ended in ENVELOPE_BREACH" in lines, lines[-5:]


def test_save_vehicle_into_a_missing_folder_is_refused_at_start_up(tmp_path):
    from mavastsm.bridge.bridge_api import BridgeOptions
    from mavastsm.errors import ConfigError

    with pytest.raises(ConfigError, match="--save-vehicle .*its folder does not exist"):
        BridgeOptions("udpout:127.0.0.1:9", save_vehicle=str(tmp_path / "absent" / "v.yaml")).validate()
