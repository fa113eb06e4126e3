"""One UDP datagram through a pymavlink parser, keeping datagram boundaries (used by the bridge's link and the sim).

pymavlink parses UDP as one byte stream: a datagram that ends inside a frame (a truncated or forged header)
makes the parser take the start of the *next* datagram as the rest of that frame, which swallows a genuine
ATTITUDE or HEARTBEAT. :func:`parse_datagram` parses every frame of one datagram and drops whatever is left.
"""

from __future__ import annotations

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
