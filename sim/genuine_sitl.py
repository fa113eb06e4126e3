"""Start genuine ArduCopter SITL and PX4 SITL (SIH), each in a private network namespace.

The user builds the autopilots; this module only runs them, from paths given as configuration:

- ``MAVASTSM_ARDUCOPTER``: the ``arducopter`` SITL binary, or the folder holding it (and, optionally,
  ``copter.parm``, loaded as extra defaults). ArduPilot: ``./waf configure --board sitl && ./waf copter``
  gives ``build/sitl/bin/arducopter``.
- ``MAVASTSM_PX4``: PX4's build folder with ``bin/px4`` and ``etc/`` (``make px4_sitl_default`` gives
  ``build/px4_sitl_default``).

Why a namespace: ArduCopter and PX4 talk to fixed UDP ports (PX4's GCS link always sends to 14550),
and any other process on the machine may use those. ``unshare -n`` gives each instance a loopback of
its own; every process that must talk to it (the bridge, a ground station) is started inside with
``NetNamespace.command`` (``nsenter``), and Python sockets are opened inside with
``NetNamespace.call`` (``setns`` on a helper thread: a socket keeps its namespace for life).

Everything started here is a process group killed by PID on ``stop()``, also after a failed test.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence, TypeVar

from mavastsm.processes import end_process_group

ARDUCOPTER_ENV = "MAVASTSM_ARDUCOPTER"
PX4_ENV = "MAVASTSM_PX4"
CLONE_NEWNET = 0x40000000
T = TypeVar("T")


class SitlUnavailable(RuntimeError):
    """The configured autopilot cannot be run here (path unset, missing, or namespaces not permitted)."""


# ---------------------------------------------------------------------- configuration
def arducopter_paths(value: str | None = None) -> tuple[Path, Path | None]:
    """(binary, copter.parm or None) from ``value`` or ``$MAVASTSM_ARDUCOPTER``; SitlUnavailable naming the rule."""
    raw = value if value is not None else os.environ.get(ARDUCOPTER_ENV)
    if not raw:
        raise SitlUnavailable(f"{ARDUCOPTER_ENV} is not set (path to ArduCopter's SITL binary or its folder)")
    p = Path(raw).expanduser()
    binary = p / "arducopter" if p.is_dir() else p
    if not binary.is_file() or not os.access(binary, os.X_OK):
        raise SitlUnavailable(f"{ARDUCOPTER_ENV}={raw}: no executable arducopter there")
    parm = binary.parent / "copter.parm"
    return binary, (parm if parm.is_file() else None)


def px4_paths(value: str | None = None) -> tuple[Path, Path]:
    """(bin/px4, etc folder) from ``value`` or ``$MAVASTSM_PX4``; SitlUnavailable naming the rule."""
    raw = value if value is not None else os.environ.get(PX4_ENV)
    if not raw:
        raise SitlUnavailable(f"{PX4_ENV} is not set (path to PX4's build folder with bin/px4 and etc/)")
    p = Path(raw).expanduser()
    binary, etc = p / "bin" / "px4", p / "etc"
    if not binary.is_file() or not os.access(binary, os.X_OK) or not etc.is_dir():
        raise SitlUnavailable(f"{PX4_ENV}={raw}: needs bin/px4 (executable) and etc/")
    return binary, etc


# ---------------------------------------------------------------------- network namespace
_libc = ctypes.CDLL(None, use_errno=True)


class NetNamespace:
    """A private network namespace with its loopback up, held open by a sleeping process.

    ``command(argv)`` wraps argv to run inside; ``call(fn)`` runs ``fn()`` on a thread that joined the
    namespace (sockets opened there stay in it). Needs CAP_SYS_ADMIN (root), as CI has.
    """

    def __init__(self) -> None:
        if shutil.which("unshare") is None or shutil.which("nsenter") is None:
            raise SitlUnavailable("unshare/nsenter (util-linux) not found")
        self._holder = subprocess.Popen(
            ["unshare", "-n", "--", "sh", "-c", "ip link set lo up && echo up && exec sleep 2147483647"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
        line = self._holder.stdout.readline().decode().strip()
        if line != "up":
            err = self._holder.stderr.read().decode().strip() if self._holder.poll() is not None else ""
            self.close()
            raise SitlUnavailable(f"cannot create a network namespace (unshare -n: {err or 'no answer'}); run as root")
        self.pid = self._holder.pid
        self.path = f"/proc/{self.pid}/ns/net"

    def command(self, argv: Sequence[str]) -> list[str]:
        return ["nsenter", f"--net={self.path}", "--", *argv]

    def call(self, fn: Callable[[], T]) -> T:
        """``fn()`` run on a helper thread inside the namespace; its result (or exception) comes back."""
        out: dict = {}

        def run() -> None:
            try:
                fd = os.open(self.path, os.O_RDONLY)
                try:
                    if _libc.setns(fd, CLONE_NEWNET) != 0:
                        raise OSError(ctypes.get_errno(), "setns failed")
                finally:
                    os.close(fd)
                out["value"] = fn()
            except BaseException as exc:  # handed back to the caller
                out["error"] = exc

        t = threading.Thread(target=run, name="netns-call", daemon=True)
        t.start()
        t.join()
        if "error" in out:
            raise out["error"]
        return out["value"]

    def close(self) -> None:
        end_process_group(self._holder)


class HostNamespace:
    """The caller's own network namespace, with NetNamespace's interface (for ``mavastsm sim --autopilot arducopter``,
    whose user connects from the same machine as usual; tests and CI use a private NetNamespace)."""

    pid = None
    path = None

    def command(self, argv: Sequence[str]) -> list[str]:
        return list(argv)

    def call(self, fn: Callable[[], T]) -> T:
        return fn()

    def close(self) -> None:
        pass


# ---------------------------------------------------------------------- the autopilots
@dataclass
class SitlInstance:
    """One running autopilot: its namespace, process, working folder and where it sends MAVLink.

    Attributes
    ----------
    kind : "arducopter" | "px4"
    netns : the namespace every peer must be started in
    bridge_url : the pymavlink URL an offboard bridge uses inside the namespace
    observer_url : a second MAVLink link for a ground station or test observer (None if the autopilot has none)
    workdir : the autopilot's working folder (state files, logs)
    log_path : its stdout/stderr
    """

    kind: str
    netns: NetNamespace
    proc: subprocess.Popen
    bridge_url: str
    observer_url: str | None
    workdir: Path
    log_path: Path
    _tmp: tempfile.TemporaryDirectory | None = None
    companions: list = field(default_factory=list)  # objects with stop(), stopped before the namespace (e.g. physics)
    started_monotonic: float = field(default_factory=time.monotonic)  # host time the autopilot was started [s]

    def alive(self) -> bool:
        return self.proc.poll() is None

    def kill(self) -> None:
        """SIGKILL the autopilot only (the namespace stays, e.g. to see the bridge's stale-ATTITUDE failsafe)."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait(5.0)

    def log_tail(self, n: int = 40) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return ""

    def stop(self) -> None:
        end_process_group(self.proc)
        for c in self.companions:
            c.stop()
        self.netns.close()
        if self._tmp is not None:
            self._tmp.cleanup()


def start_arducopter(binary: Path, parm: Path | None, *, speedup: float = 1.0, extra_defaults: Sequence[Path] = (),
                     model: str = "quad", workdir: Path | None = None, wipe: bool = True,
                     netns: NetNamespace | HostNamespace | None = None) -> SitlInstance:
    """Genuine ArduCopter SITL with wiped parameters (defaults + ``copter.parm`` + ``extra_defaults``); ``wipe=False``
    keeps what the last run in ``workdir`` stored (its eeprom.bin: parameters, signing key and timestamp).

    serial0 sends to udp 127.0.0.1:14550 (the bridge listens: ``udpin:0.0.0.0:14550``, as in the
    README); serial1 to 14551 (an observer). The simulated vehicle starts on the ground at CMAC.
    ``netns``: run it there (default: a new private NetNamespace, closed by ``stop()``).
    """
    netns = netns if netns is not None else NetNamespace()
    tmp = None
    if workdir is None:
        tmp = tempfile.TemporaryDirectory(prefix="mavastsm-arducopter-")
        workdir = Path(tmp.name)
    defaults = ",".join(str(p) for p in ([parm] if parm else []) + list(extra_defaults))
    argv = [str(binary), "--model", model, "--speedup", f"{speedup:g}", "-I0", *(["-w"] if wipe else []),
            "--home", "-35.363261,149.165230,584,353",
            "--serial0", "udpclient:127.0.0.1:14550", "--serial1", "udpclient:127.0.0.1:14551"]
    if defaults:
        argv += ["--defaults", defaults]
    log_path = workdir / "arducopter.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(netns.command(argv), cwd=workdir, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
    return SitlInstance("arducopter", netns, proc, "udpin:0.0.0.0:14550", "udpin:127.0.0.1:14551", workdir, log_path, tmp)


def solo_parm_path() -> Path:
    """The packaged ArduCopter parameter file of the 3DR Solo (configs/arducopter/solo.parm)."""
    from mavastsm.config_loading import packaged_config_dir

    return packaged_config_dir() / "arducopter" / "solo.parm"


def start_arducopter_on_solo_physics(binary: Path, parm: Path | None, physics, *, speedup: float = 1.0,
                                     netns: NetNamespace | HostNamespace | None = None,
                                     workdir: Path | None = None) -> SitlInstance:
    """Genuine ArduCopter tuned as a Solo (``copter.parm`` + ``solo.parm``) flying our Solo physics over the JSON SITL
    protocol: ``physics`` (a ``json_physics.JsonPhysics``) is served on udp 127.0.0.1:9002 inside ``netns`` (default:
    a new private namespace), then ArduCopter starts with ``--model JSON:127.0.0.1``. MAVLink as
    :func:`start_arducopter`. The physics server is the instance's companion, stopped with it; a port already in use
    raises OSError before ArduCopter starts.
    """
    from .json_physics import JsonPhysicsServer

    return _with_physics_server(JsonPhysicsServer(physics), netns, lambda ns: start_arducopter(
        binary, parm, speedup=speedup, extra_defaults=[solo_parm_path()], model="JSON:127.0.0.1", workdir=workdir, netns=ns))


def _with_physics_server(server, netns: NetNamespace | HostNamespace | None,
                         start_autopilot: Callable[[NetNamespace | HostNamespace], SitlInstance]) -> SitlInstance:
    """Open and start the physics ``server`` inside ``netns`` (None: a new private namespace), then the autopilot
    (``start_autopilot(netns)``), which connects to it; the server becomes the instance's companion, stopped with it.
    Anything failing on the way stops the server (and closes a namespace made here) before raising."""
    own = netns is None
    netns = NetNamespace() if own else netns
    try:
        netns.call(server.open)
        server.start()
        sitl = start_autopilot(netns)
    except BaseException:
        server.stop()
        if own:
            netns.close()
        raise
    sitl.companions.append(server)
    return sitl


def start_px4(binary: Path, etc: Path, *, workdir: Path | None = None, model: str = "sihsim_quadx",
              autostart: int = 10040, simulator: str = "sihsim", params: Path | None = None,
              netns: NetNamespace | HostNamespace | None = None) -> SitlInstance:
    """Genuine PX4 SITL with the SIH simulator (no Gazebo), fresh parameters in its own working folder.

    PX4's offboard link sends to udp 127.0.0.1:14540 (bridge: ``udpin:0.0.0.0:14540``), its GCS link
    to 14550 (observer). ``bin/px4-*`` client commands are symbolic links to ``px4`` that its start-up
    script finds on PATH; a copy that turned them into plain files gets them recreated in the working folder.
    ``simulator`` "" = PX4's simulator interface (simulator_mavlink) instead of SIH; ``params``: a file of PX4 shell
    ``param set`` lines, sourced as ``px4-rc.params`` after the airframe's defaults. ``netns``: as ``start_arducopter``.
    """
    netns = netns if netns is not None else NetNamespace()
    tmp = None
    if workdir is None:
        tmp = tempfile.TemporaryDirectory(prefix="mavastsm-px4-")
        workdir = Path(tmp.name)
    bindir = workdir / "bin"
    bindir.mkdir(exist_ok=True)
    for src in binary.parent.iterdir():
        if src.name.startswith("px4-") and not src.name.endswith(".sh"):
            dst = bindir / src.name
            if not dst.exists():
                dst.symlink_to(binary)
        elif src.name.endswith(".sh"):
            shutil.copy(src, bindir / src.name)
    if params is not None:
        shutil.copy(params, bindir / "px4-rc.params")  # found on PATH before etc/init.d-posix's empty one
    env = {k: v for k, v in os.environ.items() if k != "PX4_SIMULATOR"}
    env.update({"PX4_SYS_AUTOSTART": str(autostart), "PX4_SIM_MODEL": model, "PATH": f"{bindir}:{os.environ.get('PATH', '')}"})
    if simulator:
        env["PX4_SIMULATOR"] = simulator
    rootfs = workdir / "rootfs"
    rootfs.mkdir(exist_ok=True)
    argv = [str(binary), "-d", "-w", str(rootfs), str(etc)]
    log_path = workdir / "px4.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(netns.command(argv), cwd=rootfs, env=env, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
    return SitlInstance("px4", netns, proc, "udpin:0.0.0.0:14540", "udpin:127.0.0.1:14550", workdir, log_path, tmp)


def px4_solo_params_path() -> Path:
    """The packaged PX4 parameter file of the 3DR Solo (configs/px4/solo.params)."""
    from mavastsm.config_loading import packaged_config_dir

    return packaged_config_dir() / "px4" / "solo.params"


def start_px4_on_solo_physics(binary: Path, etc: Path, physics, *, speed: float = 1.0,
                              netns: NetNamespace | HostNamespace | None = None, workdir: Path | None = None,
                              params: Path | None = None) -> SitlInstance:
    """Genuine PX4 (airframe 10016 none_iris + configs/px4/solo.params) flying our Solo physics over its simulator
    interface: ``physics`` (a ``px4_hil.Px4HilPhysics``) is served on tcp 127.0.0.1:4560 inside ``netns`` (default:
    a new private namespace), which PX4 connects to; ``speed`` as ``Px4HilServer``. MAVLink as :func:`start_px4`.
    ``params``: another parameter file in solo.params's place (e.g. solo.params with a retune appended).
    The simulator server is the instance's companion, stopped with it; a port in use raises OSError before PX4 starts.
    """
    from .px4_hil import Px4HilServer

    return _with_physics_server(Px4HilServer(physics, speed=speed), netns, lambda ns: start_px4(
        binary, etc, workdir=workdir, model="none_iris", autostart=10016, simulator="",
        params=params or px4_solo_params_path(), netns=ns))


def wait_for(predicate: Callable[[], bool], timeout_s: float, what: str, instance: SitlInstance | None = None,
             poll_s: float = 0.05) -> None:
    """Poll ``predicate`` until true; TimeoutError naming ``what`` (and the autopilot's last log lines)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return
        if instance is not None and not instance.alive():
            raise RuntimeError(f"{instance.kind} exited while waiting for {what}:\n{instance.log_tail()}")
        time.sleep(poll_s)
    tail = f"\n{instance.log_tail()}" if instance is not None else ""
    raise TimeoutError(f"{what}: not within {timeout_s:g} s{tail}")
