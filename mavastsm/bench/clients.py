"""The offboard clients the benchmark times, each run as its own process: ``python -m mavastsm.bench.clients KIND``.

KIND is one of
- ``pymavlink``: the loop a user would write first (``recv_match(type='ATTITUDE', blocking=True)``
  then ``mav.set_attitude_target_send``), flying the baseline P law (``bench_latency.baseline_rates_rads``)
  and echoing the ATTITUDE's ``time_boot_ms``;
- ``pymavlink-astsm``: the same loop that also computes this package's law on every sample (``tracking_error`` and
  ASTSM's ``update``, the bridge's one vehicle, default preset) and answers as ``pymavlink`` does: the floor of
  any bridge that flies the package's law, with nothing of the bridge around it (issue 30's 1.25 x is held
  against it in the report's targets);
- ``mavsdk-async``: MAVSDK's asyncio API as in its examples: ``async for`` over
  ``telemetry.subscribe_attitude_euler()`` then ``await offboard.set_attitude_rate(...)``, same P law;
- ``mavsdk-callback``: MAVSDK's native callback: ``Telemetry.subscribe_attitude_euler(cb)`` calls
  ``Offboard.set_attitude_rate`` directly on MAVSDK's thread, same P law;
- ``bridge``: our ``mavastsm.bridge.Bridge`` with ASTSM holding level (``--dashboard`` renders the rich
  dashboard to /dev/null at 10 Hz, to measure its cost).

Each client connects with ``udpout`` to the stub's port, runs until SIGTERM/SIGINT or ``--duration-s``,
and exits 0. A client that cannot run prints the exception on stderr and exits 3, so the bench can
say exactly why.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time
import traceback

from .latency import BASELINE_THRUST, baseline_rates_rads

KINDS = ("pymavlink", "pymavlink-astsm", "mavsdk-async", "mavsdk-callback", "bridge")
#: type_mask: ignore attitude (0x80): body rates + thrust, the only rate mask ArduCopter accepts
RATES_ONLY_MASK = 0x80


def law_on_attitude(period_s: float = 2.5e-3):
    """A function of one ATTITUDE message that computes the package's law on it as the bridge does for one vehicle
    (``tracking_error`` toward level and ASTSM's ``update``, default preset) and returns the body torque [N m, FRD]:
    what a floor client adds to the naive loop (also ``benchmarks/sim_realtime_factor.py --peer-law``)."""
    from ..control import make_controller, tracking_error
    from ..solo_model import load_solo

    controller, level = make_controller("astsm", load_solo()), (0.0, 0.0, 0.0)

    def law(msg):
        err = tracking_error((msg.roll, msg.pitch, msg.yaw), (msg.rollspeed, msg.pitchspeed, msg.yawspeed),
                             level, level, level)
        return controller.update(err, period_s)

    return law


def run_pymavlink_loop(port: int, stop: threading.Event, with_law: bool = False) -> None:
    """The straightforward pymavlink loop (docs/design-decisions.md, MAV-8): blocking recv_match, then send.
    ``with_law``: also compute the package's ASTSM on each sample (its torque is not flown: the answer stays the
    P law's, which the stub pairs by the echoed ``time_boot_ms``)."""
    os.environ["MAVLINK20"] = "1"
    from pymavlink import mavutil

    law = law_on_attitude() if with_law else None

    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    if conn.wait_heartbeat(timeout=10) is None:
        raise TimeoutError("no HEARTBEAT from the vehicle within 10 s")
    last_hb = time.monotonic()
    while not stop.is_set():
        msg = conn.recv_match(type="ATTITUDE", blocking=True, timeout=0.5)
        if msg is None:
            continue
        if law is not None:
            law(msg)
        p, q, r = baseline_rates_rads(msg.roll, msg.pitch, msg.yaw)
        conn.mav.set_attitude_target_send(msg.time_boot_ms, conn.target_system, conn.target_component,
                                          RATES_ONLY_MASK, [1.0, 0.0, 0.0, 0.0], p, q, r, BASELINE_THRUST)
        if time.monotonic() - last_hb > 1.0:
            conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            last_hb = time.monotonic()
    conn.close()


def _deg_rates(e) -> tuple[float, float, float]:
    """[deg/s] the P law applied to MAVSDK's EulerAngle (degrees in, degrees/s out; same gain)."""
    import math

    p, q, r = baseline_rates_rads(math.radians(e.roll_deg), math.radians(e.pitch_deg), math.radians(e.yaw_deg))
    return (math.degrees(p), math.degrees(q), math.degrees(r))


def _require_mavsdk() -> None:
    try:
        import mavsdk  # noqa: F401
    except ImportError as exc:
        raise RuntimeError(f"MAVSDK is not installed ({exc}); install the extra: pip install \"mavastsm[bench]\"") from None


def run_mavsdk_async(port: int, stop: threading.Event) -> None:
    """MAVSDK asyncio: attitude stream drives offboard.set_attitude_rate (thrust 0.5 = hold on ArduCopter)."""
    import asyncio

    _require_mavsdk()
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.offboard import AttitudeRate, OffboardAsync
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    async def main() -> None:
        async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as sdk:
            await sdk.add_any_connection(f"udpout://127.0.0.1:{port}")
            system = await sdk.first_autopilot(timeout_s=10.0)
            if system is None:
                raise TimeoutError("MAVSDK found no autopilot within 10 s")
            telemetry, offboard = TelemetryAsync(system), OffboardAsync(system)
            await offboard.set_attitude_rate(AttitudeRate(0.0, 0.0, 0.0, BASELINE_THRUST))
            await offboard.start()
            async for euler in telemetry.subscribe_attitude_euler():
                await offboard.set_attitude_rate(AttitudeRate(*_deg_rates(euler), BASELINE_THRUST))
                if stop.is_set():
                    break

    asyncio.run(main())


def run_mavsdk_callback(port: int, stop: threading.Event) -> None:
    """MAVSDK native API: the telemetry callback calls offboard.set_attitude_rate on MAVSDK's thread."""
    _require_mavsdk()
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.offboard import AttitudeRate, Offboard
    from mavsdk.plugins.telemetry import Telemetry

    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        sdk.add_any_connection(f"udpout://127.0.0.1:{port}")
        system = sdk.first_autopilot(10.0)
        if system is None:
            raise TimeoutError("MAVSDK found no autopilot within 10 s")
        telemetry, offboard = Telemetry(system), Offboard(system)
        offboard.set_attitude_rate(AttitudeRate(0.0, 0.0, 0.0, BASELINE_THRUST))
        offboard.start()

        def on_attitude(euler, _user_data) -> None:
            offboard.set_attitude_rate(AttitudeRate(*_deg_rates(euler), BASELINE_THRUST))

        handle = telemetry.subscribe_attitude_euler(on_attitude)
        stop.wait()
        telemetry.unsubscribe_attitude_euler(handle)
    finally:
        sdk.destroy()


def run_bridge(port: int, stop: threading.Event, rate_hz: float, dashboard: bool, log_dir: str | None = None) -> None:
    """Our bridge (``mavastsm.bridge.Bridge``) against the stub, holding level with ASTSM; ``log_dir``: ``--log``."""
    from .bridge_runner import run_bridge_until

    run_bridge_until(f"udpout:127.0.0.1:{port}", stop, rate_hz=rate_hz, dashboard=dashboard, log_dir=log_dir)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m mavastsm.bench.clients", description=__doc__.splitlines()[0])
    parser.add_argument("kind", choices=KINDS)
    parser.add_argument("--port", type=int, required=True, help="stub vehicle UDP port on 127.0.0.1")
    parser.add_argument("--rate-hz", type=float, default=400.0, help="ATTITUDE rate the stub streams [Hz]")
    parser.add_argument("--duration-s", type=float, default=600.0, help="exit after this long [s]")
    parser.add_argument("--dashboard", action="store_true", help="bridge only: render the dashboard (to /dev/null)")
    parser.add_argument("--log-dir", default=None, help="bridge only: keep the flight's CSV and .tlog there (--log)")
    args = parser.parse_args(argv)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    threading.Timer(args.duration_s, stop.set).start() if args.duration_s > 0 else None
    try:
        if args.kind in ("pymavlink", "pymavlink-astsm"):
            run_pymavlink_loop(args.port, stop, with_law=args.kind == "pymavlink-astsm")
        elif args.kind == "mavsdk-async":
            run_mavsdk_async(args.port, stop)
        elif args.kind == "mavsdk-callback":
            run_mavsdk_callback(args.port, stop)
        else:
            run_bridge(args.port, stop, args.rate_hz, args.dashboard, args.log_dir)
    except Exception as exc:  # the bench reports this line verbatim
        traceback.print_exc(file=sys.stderr)
        print(f"BENCH-CLIENT-ERROR {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
        os._exit(3)
    os._exit(0)  # do not wait for the duration timer / MAVSDK threads


if __name__ == "__main__":
    sys.exit(main())
