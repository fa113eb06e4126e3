"""Benchmark plumbing: latency pairing (pure), the stub vehicle's ACKs, and the report's fields.

These tests check that the measurement is computed correctly; they never assert on how fast
anything is (performance goals are printed by ``mavastsm bench``, not asserted).
"""

from __future__ import annotations

import math
import os
import struct

import pytest

from mavastsm.bench.latency import (
    BASELINE_KP,
    CODE_PERIOD,
    CyclePairing,
    PairingRule,
    baseline_rates_rads,
    decode_roll_code,
    roll_code_rad,
)

MS = 1_000_000  # ns


def _f32(x: float) -> float:
    return struct.unpack("f", struct.pack("f", x))[0]


# ---- pure pairing ----------------------------------------------------------------------------


def test_echo_pairing_latency_missed_and_unanswered():
    p = CyclePairing(PairingRule.ECHO)
    period = 2_500_000  # 400 Hz
    for k in range(5):
        p.on_sent(1000 + 2 * k, k * period)
    # sample 0 answered after 100 us, sample 1 answered late (after sample 2 was sent), sample 2 never,
    # sample 3 answered twice (second is extra)
    assert p.on_reply(100_000, 1000, (0.0, 0.0, 0.0), 0.5) == "answer"
    assert p.on_reply(2 * period + 300_000, 1002, (0.0, 0.0, 0.0), 0.5) == "answer"
    assert p.on_reply(3 * period + 50_000, 1006, (0.0, 0.0, 0.0), 0.5) == "answer"
    assert p.on_reply(3 * period + 60_000, 1006, (0.0, 0.0, 0.0), 0.5) == "extra"
    assert p.on_reply(3 * period + 70_000, 4242, (0.0, 0.0, 0.0), 0.5) == "undecodable"
    s = p.stats(0, 3)
    assert s.samples == 4
    assert s.answered == 3
    assert s.unanswered == 1
    assert s.missed == 2  # the late one and the unanswered one
    assert s.extra == 1 and s.undecodable == 1
    assert s.max_us == pytest.approx((period + 300_000) / 1e3)
    assert s.p50_us == pytest.approx(100.0)  # median of 100, 2800, 50 us
    assert s.stub_max_send_gap_us == pytest.approx(period / 1e3)


def test_roll_code_round_trip_through_float32_degrees():
    """The code survives what MAVSDK does: float32 rad -> degrees -> P law -> float32 deg/s -> rad/s."""
    for seq in (0, 1, 499, 500, 999, 1000, 123_457):
        roll = _f32(roll_code_rad(seq))
        roll_deg = math.degrees(roll)
        rate_deg_s = _f32(math.degrees(baseline_rates_rads(math.radians(roll_deg), 0.0, 0.0)[0]))
        rate_rads = _f32(math.radians(rate_deg_s))
        assert decode_roll_code(-rate_rads / BASELINE_KP) == seq % CODE_PERIOD
    assert decode_roll_code(float("nan")) is None
    assert decode_roll_code(1.0) is None  # outside the sawtooth


def test_roll_code_pairs_a_late_answer_with_the_sample_it_was_computed_from():
    p = CyclePairing(PairingRule.ROLL_CODE)
    period = MS
    for k in range(CODE_PERIOD + 3):
        p.on_sent(k, k * period)
    newest = CODE_PERIOD + 2
    # the client answers sample newest-1 after sample `newest` was already sent
    rate = baseline_rates_rads(roll_code_rad(newest - 1), 0.0, 0.0)[0]
    assert p.on_reply(newest * period + 200_000, 0, (rate, 0.0, 0.0), 0.5) == "answer"
    assert p.answer_ns[newest - 1] == newest * period + 200_000
    assert p.answer_ns[newest - 1 - CODE_PERIOD] is None  # not the same residue one period earlier
    # a keep-alive re-send of the same setpoint is extra, not a second answer
    assert p.on_reply(newest * period + 900_000, 0, (rate, 0.0, 0.0), 0.5) == "extra"
    s = p.stats(newest - 1, newest - 1)
    assert s.missed == 1 and s.answered == 1
    assert s.p50_us == pytest.approx((period + 200_000) / 1e3)


def test_arrival_pairing_ignores_bit_identical_repeats():
    p = CyclePairing(PairingRule.ARRIVAL)
    p.on_sent(0, 0)
    assert p.on_reply(150_000, 0, (0.1, 0.0, 0.0), 0.5) == "answer"
    p.on_sent(1, MS)
    assert p.on_reply(MS + 10_000, 0, (0.1, 0.0, 0.0), 0.5) == "repeat"  # keep-alive, not an answer
    assert p.on_reply(MS + 90_000, 0, (0.2, 0.0, 0.0), 0.5) == "answer"
    p.on_sent(2, 2 * MS)
    s = p.stats(0, 1)
    assert s.answered == 2 and s.missed == 0 and s.repeats == 1
    assert s.max_us == pytest.approx(150.0)


def test_stats_with_no_answers_are_nan_not_zero():
    p = CyclePairing(PairingRule.ECHO)
    for k in range(3):
        p.on_sent(k, k * MS)
    s = p.stats()
    assert s.samples == 2 and s.missed == 2 and math.isnan(s.p50_us)


# ---- the stub vehicle on the wire -----------------------------------------------------------


def test_stub_acks_what_clients_need_and_times_an_echoing_client():
    os.environ["MAVLINK20"] = "1"
    from pymavlink import mavutil

    from mavastsm.bench.stub_vehicle import StubVehicle

    stub = StubVehicle(200.0, PairingRule.ECHO, duration_s=0.25, warmup_s=0.05).start()
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{stub.port}", source_system=255, source_component=190)
    try:
        conn.mav.heartbeat_send(6, 8, 0, 0, 0)
        hb = conn.wait_heartbeat(timeout=5)
        assert hb is not None and hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
        assert hb.custom_mode == 4
        conn.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 30, 2500, 0, 0, 0, 0, 0)
        ack = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
        assert ack is not None and ack.command == 511 and ack.result == 0
        conn.mav.param_request_read_send(1, 1, b"GUID_OPTIONS", -1)
        pv = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=5)
        assert pv is not None and pv.param_id == "GUID_OPTIONS" and pv.param_value == 0.0
        conn.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 9, 0, 0, 0, 0, 0)
        ack = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
        assert ack is not None and ack.command == 176 and ack.result == 0 and stub.custom_mode == 9
        # echo-answer every ATTITUDE until the window is complete
        while not stub.done.is_set():
            msg = conn.recv_match(type="ATTITUDE", blocking=True, timeout=5)
            assert msg is not None, "stub stopped streaming ATTITUDE"
            conn.mav.set_attitude_target_send(msg.time_boot_ms, 1, 1, 0x80, [1, 0, 0, 0], 0.0, 0.0, 0.0, 0.5)
        result = stub.wait_result(5.0)
    finally:
        conn.close()
        stub.stop()
    s = result.stats
    assert result.error == "" and s is not None
    assert s.samples == 50  # 0.25 s at 200 Hz
    assert s.answered + s.unanswered == s.samples
    assert s.p50_us > 0 and s.max_us >= s.p99_us >= s.p50_us


def test_measure_client_reports_why_a_client_cannot_run(monkeypatch):
    """A client process that dies is reported with its exception line, not a hang or a crash."""
    from mavastsm import bench

    monkeypatch.setitem(bench.CLIENT_LABELS, "nonexistent", "bogus")
    monkeypatch.setitem(bench.CLIENT_RULES, "nonexistent", PairingRule.ECHO)
    row = bench.measure_client("nonexistent", 100.0, 0.2, 0.1, start_timeout_s=5.0)
    assert row["p50_us"] is None and "invalid choice" in row["error"]


# ---- the report -----------------------------------------------------------------------------

LATENCY_FIELDS = {"client", "label", "rate_hz", "dashboard", "window_s", "pairing", "samples", "answered", "missed",
                  "unanswered", "extra", "repeats", "p50_us", "p99_us", "max_us", "mean_us", "cpu_per_cycle_us",
                  "stub_max_send_gap_us", "load_1m", "error"}


def test_report_has_every_field_on_a_reduced_configuration():
    from mavastsm.bench import BenchConfig, render_markdown, render_tables, run_all_measurements

    cfg = BenchConfig(rates_hz=(200.0,), clients=("pymavlink",), window_s=0.3, warmup_s=0.1,
                      sustained_window_s=0.3, sustained_ladder_hz=(200.0,), sim_seconds=0.5,
                      run_reproduce=False, offline_seconds=0.2, offline_batch=2, sweep_runs=4, sweep_seconds=1.0,
                      mavlink_sweep_runs=0, quick=True)
    report = run_all_measurements(cfg)
    assert set(report) == {"meta", "latency", "comparison", "cpu_per_cycle_us", "sustained_rate", "sim_lockstep",
                           "offline", "sweep", "targets"}
    assert {"date_utc", "quick", "machine", "versions", "notes", "bench_wall_s"} <= set(report["meta"])
    assert {"cpu", "logical_cpus", "load_average_1m_start", "load_average_1m_end"} <= set(report["meta"]["machine"])
    (row,) = report["latency"]
    assert set(row) == LATENCY_FIELDS
    assert row["error"] == "" and row["samples"] == 60 and row["p50_us"] > 0
    assert row["cpu_per_cycle_us"] is not None
    for key in ("dashboard_off", "dashboard_on"):
        assert {"highest_rate_hz_without_miss", "window_s", "ladder_hz", "dashboard", "trials", "error"} \
            <= set(report["sustained_rate"][key])
    assert {"control_hz", "physics_hz", "sim_s", "wall_s", "real_time_factor", "sim_s_two_processes",
            "wall_s_two_processes", "real_time_factor_two_processes", "real_time_factor_minimal_peer",
            "cpu_bound_real_time_factor_minimal_peer", "real_time_factor_minimal_peer_law", "minimal_peer_error", "error"} <= set(report["sim_lockstep"])
    assert report["sim_lockstep"]["real_time_factor_minimal_peer_law"] > 0, report["sim_lockstep"]
    assert {"reproduce_wall_s", "single_sim_s_per_wall_s", "batched_sim_s_per_wall_s", "batch", "error"} \
        <= set(report["offline"])
    sweep = report["sweep"]
    assert sweep["error"] == "" and sweep["mavlink"] is None, sweep
    assert sweep["offline"]["runs"] == 4 and sweep["offline"]["sim_s_per_wall_s"] > 0
    for t in report["targets"]:
        assert set(t) == {"target", "measured", "unit", "status", "bound", "bound_label"}
        assert t["status"] in ("met", "MISSED", "not measured")
    assert render_tables(report)  # renders without error
    md = render_markdown(report, "mavastsm bench --quick")
    assert "naive pymavlink loop" in md and report["meta"]["machine"]["cpu"] in md
    assert "(ceiling: the sim against a minimal peer computing the law, " in md, md


def test_the_law_floor_client_computes_the_law_and_the_targets_hold_the_ratios_against_it():
    """``pymavlink-astsm`` answers every sample as the naive loop does (echo pairing) while computing the law; the
    report's CPU and p50 targets carry its ratio to the naive loop as their floor, the lockstep target the sim's
    real-time factor against a peer computing the law as its ceiling."""
    from mavastsm.bench import evaluate_targets, measure_client

    row = measure_client("pymavlink-astsm", 200.0, 0.3, 0.1)
    assert row["error"] == "" and row["samples"] == 60 and row["answered"] == 60, row

    def client(kind, p50, cpu):
        return {"client": kind, "rate_hz": 400.0, "dashboard": False, "p50_us": p50, "cpu_per_cycle_us": cpu, "missed": 0}

    report = {"latency": [client("bridge", 300.0, 400.0), client("pymavlink", 100.0, 125.0),
                          client("pymavlink-astsm", 140.0, 175.0)],
              "sim_lockstep": {"real_time_factor": 4.0, "real_time_factor_minimal_peer_law": 8.5}}
    cpu, p50, late, lockstep, sweep = evaluate_targets(report)
    assert (cpu["measured"], cpu["bound"], cpu["status"]) == (3.2, 1.4, "MISSED")
    assert (p50["measured"], p50["bound"]) == (3.0, 1.4)
    assert cpu["bound_label"].startswith("floor") and lockstep["bound_label"].startswith("ceiling")
    assert (lockstep["measured"], lockstep["bound"]) == (4.0, 8.5)
    assert late["bound"] is None and sweep["bound"] is None


def test_bench_bad_options_exit_2_with_one_line(capsys):
    from mavastsm.cli import main

    assert main(["bench", "--clients", "foo"]) == 2
    assert main(["bench", "--rates-hz", "2000"]) == 2
    assert main(["bench", "--json", "/nonexistent-dir/x.json"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and "foo" in err[0] and "2000" in err[1] and "nonexistent" in err[2]
