"""Inbound datagrams of the simulated ArduCopter: parsed into MAVLink messages, bad input classified and counted,
each valid message handed to its handler. Nothing inbound can raise out of :meth:`DatagramReader.read`."""

from __future__ import annotations

import logging
from typing import Any, Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavastsm import signing
from mavastsm.mavlink_datagram import discard_partial_frame, parse_datagram

from .vehicle_link import VehicleLink

log = logging.getLogger("mavastsm_sim")

MAVLINK2_MIN_FRAME_BYTES = mavlink.HEADER_LEN_V2 + 2  # header + CRC of an empty, unsigned MAVLink 2 frame


class DatagramReader:
    """Parses datagrams with the link's ``MAVLink`` object and dispatches the messages by id.

    Parameters
    ----------
    link : VehicleLink
        The parser (``mav``) and the counters (``messages_in`` and the bad-input classes).
    handlers : dict of msg id -> callable(msg)
        What to do with each message id handled; valid messages of other ids are counted and ignored.
    """

    def __init__(self, link: VehicleLink, handlers: dict[int, Callable[[Any], None]]) -> None:
        self.link = link
        self.mav = link.mav
        self.counters = link.counters
        self._handlers = handlers

    def read(self, data: bytes, on_first_valid: Callable[[], None] | None = None) -> int:
        """Parse one datagram and hand every valid message in it to its handler; never raises. Returns how many
        frames were valid MAVLink; ``on_first_valid`` runs before the first valid one is acted on
        (``MavlinkVehicle.handle_datagram`` says more)."""
        mav = self.mav
        msgs = []
        try:
            if self._is_single_v2_frame(data):
                msgs.append(self._decode_single_frame(data))
            else:
                msgs, left = parse_datagram(mav, data)
                if left > 0:
                    self.link.bad("truncated_frames", f"{left} bytes left in a datagram of {len(data)}")
        except Exception as exc:  # pymavlink should not raise with robust_parsing; never let it kill us
            msgs = []
            self.link.bad("malformed_frames", f"parser raised {exc!r}")
        left = mav.buf_len()  # after a parser exception (parse_datagram drops a cut frame itself)
        if left > 0:
            self.link.bad("truncated_frames", f"{left} bytes left in a datagram of {len(data)}")
            discard_partial_frame(mav)
        valid = 0
        for msg in msgs:
            try:
                if not valid and on_first_valid is not None and self._is_valid(msg):
                    on_first_valid()
                valid += self._dispatch(msg)
            except Exception as exc:  # a handler bug must not stop the vehicle
                self.link.bad("internal_errors", f"{msg.get_type()} handler raised {exc!r}")
                log.exception("handler for %s failed", msg.get_type())
        return valid

    def _is_single_v2_frame(self, data: bytes) -> bool:
        """True when ``data`` is exactly one MAVLink 2 frame (length from its header, incompat flags 0 or
        signed) and the parser holds no partial frame: the common case of one message per datagram."""
        n = len(data)
        return (n >= MAVLINK2_MIN_FRAME_BYTES and data[0] == mavlink.PROTOCOL_MARKER_V2 and self.mav.buf_len() == 0
                and data[2] in (0, mavlink.MAVLINK_IFLAG_SIGNED)
                and n == data[1] + MAVLINK2_MIN_FRAME_BYTES + (mavlink.MAVLINK_SIGNATURE_BLOCK_LEN if data[2] else 0))

    def _decode_single_frame(self, data: bytes) -> Any:
        """What ``MAVLink.parse_char`` returns for a datagram that ``_is_single_v2_frame`` accepted, with the
        same bookkeeping, minus its byte-buffer handling: the frame goes straight to pymavlink's
        ``MAVLink.decode`` (header, CRC, signature and payload checks all stay pymavlink's). A frame it
        refuses becomes ``MAVLink_bad_data`` with pymavlink's reason, as the robust parser does."""
        mav = self.mav
        mav.total_bytes_received += len(data)
        frame = bytearray(data)
        try:
            msg = mav.decode(frame)
        except mavlink.MAVError as reason:
            msg = mavlink.MAVLink_bad_data(frame, reason.message)
            mav.total_receive_errors += 1
        mav.have_prefix_error = False
        mav.expected_length = mavlink.HEADER_LEN_V2 + 2
        mav.total_packets_received += 1
        if mav.callback is not None and mav.callback_args is not None and mav.callback_kwargs is not None:
            mav.callback(msg, *mav.callback_args, **mav.callback_kwargs)
        return msg

    @staticmethod
    def _is_valid(msg: Any) -> bool:
        return msg.get_msgId() not in (mavlink.MAVLINK_MSG_ID_BAD_DATA, mavlink.MAVLINK_MSG_ID_UNKNOWN)

    def _dispatch(self, msg: Any) -> int:
        """Act on one parsed frame; 1 when it was a valid message (handled or not), else 0 (counted as bad)."""
        mid = msg.get_msgId()
        if mid == mavlink.MAVLINK_MSG_ID_BAD_DATA:
            self._classify_bad_data(msg)
            return 0
        if mid == mavlink.MAVLINK_MSG_ID_UNKNOWN:
            self.link.bad("unknown_message_ids", f"msg id {getattr(msg, 'msgid', '?')}")
            return 0
        self.counters["messages_in"] += 1
        handler = self._handlers.get(mid)
        if handler is not None:
            handler(msg)
        return 1

    def _classify_bad_data(self, msg: Any) -> None:
        self.link.bad(signing.classify_bad_data(msg, self.mav), str(getattr(msg, "reason", "")))
