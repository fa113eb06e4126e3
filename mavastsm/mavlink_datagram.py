"""One UDP datagram through a pymavlink parser, keeping datagram boundaries (used by the bridge's link and the sim),
and the kernel's time of its arrival.

pymavlink parses UDP as one byte stream: a datagram that ends inside a frame (a truncated or forged header)
makes the parser take the start of the *next* datagram as the rest of that frame, which swallows a genuine
ATTITUDE or HEARTBEAT. :func:`parse_datagram` parses every frame of one datagram and drops whatever is left.

:func:`enable_kernel_timestamps` and :func:`kernel_receive_ns` read when the kernel received a datagram (Linux
``SO_TIMESTAMPNS``), not when a busy reader got to it: the bridge's latency and its ``late`` counter start there,
and the bench's stub vehicle times its clients with it.
"""

from __future__ import annotations

import socket
import struct
import sys
import time

#: Linux SO_TIMESTAMPNS (not exported by Python's socket module): the kernel's receive time, CLOCK_REALTIME [ns].
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
ANCILLARY_BYTES = 64  # room for one struct timespec control message
_TIMESPEC = struct.Struct("qq")  # tv_sec, tv_nsec (64-bit Linux)


def enable_kernel_timestamps(sock) -> bool:
    """Ask the kernel to stamp every datagram ``sock`` receives; False where it cannot (not Linux, not a socket)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    except (OSError, AttributeError):
        return False
    return True


def kernel_receive_ns(ancdata) -> int | None:
    """The kernel's receive time [ns, CLOCK_REALTIME] in ``recvmsg``'s ancillary data, or None when it has none."""
    for level, kind, cdata in ancdata:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(cdata) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(cdata)
            return sec * 1_000_000_000 + nsec
    return None


def arrival_monotonic_ns(ancdata, max_age_ns: int = 1_000_000_000) -> int:
    """When the datagram of ``ancdata`` arrived, on the host's monotonic clock [ns]: the kernel's receive time moved
    over from CLOCK_REALTIME, kept within the last ``max_age_ns`` (a wall-clock step between arrival and now must not
    make it the future or the distant past); now when the kernel gave no time."""
    now = time.monotonic_ns()
    kernel = kernel_receive_ns(ancdata)
    if kernel is None:
        return now
    arrived = now - (time.time_ns() - kernel)
    return now if arrived > now else max(arrived, now - max_age_ns)

HEADER_LEN_V1 = 6  # the parser's idle state expects a MAVLink 1 header + CRC first (pymavlink's own reset value)


def discard_partial_frame(mav) -> None:
    """Reset the pymavlink ``MAVLink`` parser ``mav`` to its idle state (nothing buffered)."""
    mav.buf, mav.buf_index = bytearray(), 0
    mav.expected_length = HEADER_LEN_V1 + 2


def parse_datagram(mav, data: bytes) -> tuple[list, int]:
    """(every message parsed from ``data``, including pymavlink's BAD_DATA ones; bytes of a frame cut off by the
    datagram's end, dropped). ``MAVLink.parse_buffer`` minus its final empty ``parse_char`` call."""
    msgs = []
    msg = mav.parse_char(data)
    while msg is not None:
        msgs.append(msg)
        if mav.buf_len() == 0:
            break
        msg = mav.parse_char(b"")
    left = mav.buf_len()
    if left > 0:
        discard_partial_frame(mav)
    return msgs, left
