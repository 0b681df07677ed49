"""The live service's frame I/O on a python-can bus: a fast path on the socket for the buses lde knows,
python-can's own ``recv``/``send`` for every other one.

The service takes any ``can.BusABC`` (:class:`lde.service.service.Service`); what it needs per frame is five
numbers, not a ``can.Message``. :func:`bus_io` gives it an object with

* ``recv(timeout) -> (t_ns, can_id, is_extended, dlc, word) | None``: the next frame, ``t_ns`` its
  receive time [ns] rounded to the microsecond as python-can's timestamp would be
  (:func:`lde.can.frames.seconds_to_ns`), ``word`` its data bytes as a little-endian integer (64 bits
  for a classic frame, up to 512 for CAN FD); ``can_id``
  :data:`NOT_DATA` (-1) for a remote frame or one the bus would drop, :data:`ERROR_FRAME` (-2) for an
  error frame, whose ``word`` is then its error class (python-can's ``arbitration_id``); None when
  none came within ``timeout`` [s] (0: poll);
* ``tx(msg) -> TxFrame``: a prebuilt output frame whose ``view`` (uint8, ``dlc`` bytes) is filled in
  place and sent with ``send(tx, t_s)`` (``t_s``: the send timestamp [s], as ``msg.timestamp``).

Fast paths (the same bytes on the wire, the same timestamps as python-can's; tested against it):

* python-can's ``udp_multicast`` (the host benchmark's bus): ``recvmsg`` on its socket, the msgpack
  datagram parsed at its fixed offsets (any other layout: python-can's own unpacking); outputs are
  python-can's datagram packed once, then only the timestamp and the data bytes are patched before
  each ``sendto``;
* SocketCAN: ``recvmsg`` of the ``can_frame`` and its ``SO_TIMESTAMPNS`` stamp; outputs are
  python-can's ``can_frame`` built once and written with ``send``.

Anything they do not recognise (another interface, a python-can version whose bus lacks the socket
attributes used here, a socket with a timeout set) uses the generic path.
"""

from __future__ import annotations

import select
import socket
import struct
from typing import Any

import can
import numpy as np

from lde.can.frames import seconds_to_ns

__all__ = ["ERROR_FRAME", "NOT_DATA", "BusIO", "TxFrame", "bus_io"]

#: one received frame: (t_ns, can_id (< 0: not a data frame), is_extended, dlc, word)
RxFrame = tuple[int, int, bool, int, int]
#: ``can_id`` of a remote frame or of a frame the bus would not deliver (dropped)
NOT_DATA = -1
#: ``can_id`` of an error frame (counted by the service); ``word`` carries the error class
ERROR_FRAME = -2

_TS = struct.Struct("@ll")  # struct timespec, as python-can reads SO_TIMESTAMPNS
_BE_DOUBLE = struct.Struct(">d")
_DONTWAIT = getattr(socket, "MSG_DONTWAIT", 0)


class TxFrame:
    """A prebuilt output frame: fill ``view`` (its ``dlc`` data bytes), then :meth:`BusIO.send` it.

    Attributes:
        can_id: the 11- or 29-bit id.
        is_extended: 29-bit id.
        dlc: data length [bytes].
        view: uint8 array over the frame's data bytes in the buffer that is sent.
        data, data_at: that buffer (a ``bytearray``) and the data bytes' offset in it.
    """

    __slots__ = ("can_id", "is_extended", "dlc", "view", "buf", "msg", "ts_at", "data", "data_at")

    def __init__(self, msg: can.Message, buf: bytearray | None = None, data_at: int = 0, ts_at: int = -1):
        self.can_id = int(msg.arbitration_id)
        self.is_extended = bool(msg.is_extended_id)
        self.dlc = int(msg.dlc)
        self.msg = msg
        self.buf = buf
        self.ts_at = ts_at
        #: the bytearray that holds the data bytes, and their offset in it (``view``'s memory; a
        #: slice assignment to it costs half a numpy copy into ``view``)
        self.data: bytearray = msg.data if buf is None else buf
        self.data_at = 0 if buf is None else data_at
        self.view = np.frombuffer(self.data, np.uint8, count=self.dlc, offset=self.data_at)

    def word(self) -> int:
        """The data bytes as a little-endian integer (what the recorder stores)."""
        return int.from_bytes(self.view.tobytes(), "little")


class BusIO:
    """python-can's ``recv``/``send`` (the generic path; any bus)."""

    kind = "python-can"

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus

    def recv(self, timeout: float | None) -> RxFrame | None:
        """The next frame within ``timeout`` [s] (0: poll), or None."""
        msg = self.bus.recv(timeout)
        if msg is None:
            return None
        return message_fields(msg)

    def tx(self, msg: can.Message) -> TxFrame:
        """``msg`` as a prebuilt output frame (its data is a ``bytearray`` of ``dlc`` bytes)."""
        msg.data = bytearray(msg.data)
        return TxFrame(msg)

    def send(self, tx: TxFrame, t_s: float) -> None:
        """Send ``tx`` stamped ``t_s`` [s]; raises ``can.CanError`` or ``OSError`` as the bus does."""
        msg = tx.msg
        msg.timestamp = t_s
        self.bus.send(msg)


def message_fields(msg: can.Message) -> RxFrame:
    """A received ``can.Message`` as the service's five numbers (can_id < 0: not a data frame)."""
    if msg.is_error_frame:
        return (seconds_to_ns(msg.timestamp), ERROR_FRAME, False, 0, msg.arbitration_id)
    if msg.is_remote_frame:
        return (0, NOT_DATA, False, 0, 0)
    word = int.from_bytes(msg.data, "little")
    return (seconds_to_ns(msg.timestamp), msg.arbitration_id, msg.is_extended_id, msg.dlc, word)


class _SocketIO(BusIO):
    """Common to the socket fast paths: non-blocking ``recvmsg``, ``select`` to wait."""

    def __init__(self, bus: can.BusABC, sock: socket.socket, bufsize: int, ancsize: int) -> None:
        super().__init__(bus)
        self.sock = sock
        self._bufsize = bufsize
        self._ancsize = ancsize
        self._rlist = [sock]

    def recv(self, timeout: float | None) -> RxFrame | None:
        sock = self.sock
        if sock.gettimeout() is not None:  # someone set a socket timeout: DONTWAIT would wait
            return super().recv(timeout)
        if timeout is None or timeout > 0:
            try:
                ready = select.select(self._rlist, [], [], timeout)[0]
            except OSError as exc:
                raise can.CanOperationError(f"failed to wait for the socket: {exc}") from exc
            if not ready:
                return None
        try:
            data, anc, flags, _ = sock.recvmsg(self._bufsize, self._ancsize, _DONTWAIT)
        except BlockingIOError:
            return None
        except OSError as exc:
            raise can.CanOperationError(f"failed to receive: {exc}") from exc
        if len(anc) != 1:
            raise can.CanOperationError("no receive timestamp on the socket")
        sec, nsec = _TS.unpack_from(anc[0][2])
        return self._parse(data, sec + nsec * 1e-9)

    def _parse(self, data: bytes, ts: float) -> RxFrame:  # pragma: no cover - overridden
        raise NotImplementedError


# python-can's udp_multicast datagram (can.interfaces.udp_multicast.utils.pack_message): a msgpack map
# of 11 keys; for a classic data frame with an id of 256..65535 and no channel every field but the
# timestamp, the id, the dlc and the data sits at a fixed offset
def _udp_layout() -> tuple[bytes, bytes, bytes, bytes]:
    from can.interfaces.udp_multicast.utils import pack_message

    d = pack_message(can.Message(timestamp=0.0, arbitration_id=0x100, is_extended_id=False, data=b""))
    if not (d[11] == 0xCB and d[35] == 0xCD and d[100] == 0 and d[106] == 0xC4 and d[107] == 0):
        raise ValueError("unexpected udp_multicast datagram layout")
    return bytes(d[0:12]), bytes(d[20:36]), bytes(d[38:100]), bytes(d[101:107]) + bytes(d[108:])


class _UdpMulticastIO(_SocketIO):
    """python-can's ``udp_multicast`` bus, on its socket."""

    kind = "udp_multicast (socket)"

    def __init__(self, bus: can.BusABC, mc: Any) -> None:
        super().__init__(bus, mc._socket, int(mc.max_buffer), int(mc.received_ancillary_buffer_size))
        self._dest = mc._send_destination
        self._head, self._arb, self._mid, self._tail = _udp_layout()
        self._fd_bus = getattr(bus, "_can_protocol", None) is can.CanProtocol.CAN_FD
        self._tail_key = self._tail[:6]
        self._tail_end = self._tail[6:]

    def _parse(self, d: bytes, ts: float) -> RxFrame:
        n = len(d) - 157
        if (
            0 <= n <= 8
            and d[107] == n
            and d[100] == n
            and d[0:12] == self._head
            and d[20:36] == self._arb
            and d[38:100] == self._mid
            and d[101:107] == self._tail_key
            and d[108 + n :] == self._tail_end
        ):
            word = int.from_bytes(d[108 : 108 + n], "little")
            return (seconds_to_ns(ts), (d[36] << 8) | d[37], False, n, word)
        # any other layout (extended id, a channel name, FD, an error frame): python-can's unpacking
        from can.interfaces.udp_multicast.utils import unpack_message

        try:
            msg = unpack_message(d, replace={"timestamp": ts}, check=True)
        except Exception as exc:  # python-can raises the same for a datagram it cannot unpack
            raise can.CanOperationError("could not unpack received message") from exc
        if msg.is_fd and not self._fd_bus:  # python-can drops FD frames on a classic bus
            return (0, NOT_DATA, False, 0, 0)
        return message_fields(msg)

    def tx(self, msg: can.Message) -> TxFrame:
        from can.interfaces.udp_multicast.utils import pack_message

        msg.data = bytearray(msg.data)
        buf = bytearray(pack_message(msg))
        n = len(msg.data)
        if not (n <= 8 and buf[11] == 0xCB and buf[106] == 0xC4 and buf[107] == n):
            return TxFrame(msg)  # an unexpected layout: sent by python-can
        return TxFrame(msg, buf, data_at=108, ts_at=12)

    def send(self, tx: TxFrame, t_s: float) -> None:
        buf = tx.buf
        if buf is None:
            return super().send(tx, t_s)
        _BE_DOUBLE.pack_into(buf, tx.ts_at, t_s)
        if self.sock.sendto(buf, self._dest) < len(buf):
            raise can.CanOperationError("datagram sent in part")


class _SocketcanIO(_SocketIO):
    """python-can's SocketCAN bus (CAN_RAW), on its socket."""

    kind = "socketcan (socket)"
    _EFF, _RTR, _ERR = 0x80000000, 0x40000000, 0x20000000

    def __init__(self, bus: can.BusABC, sock: socket.socket, ancsize: int) -> None:
        super().__init__(bus, sock, 72, ancsize)  # CANFD_MTU: classic and FD frames

    def _parse(self, cf: bytes, ts: float) -> RxFrame:
        return socketcan_fields(cf, ts)

    def tx(self, msg: can.Message) -> TxFrame:
        from can.interfaces.socketcan.socketcan import build_can_frame

        msg.data = bytearray(msg.data)
        buf = bytearray(build_can_frame(msg))
        return TxFrame(msg, buf, data_at=8)

    def send(self, tx: TxFrame, t_s: float) -> None:
        buf = tx.buf
        if buf is None:
            return super().send(tx, t_s)
        tx.msg.timestamp = t_s
        try:
            sent = self.sock.send(buf)
        except OSError as exc:
            raise can.CanOperationError(f"failed to transmit: {exc.strerror}", exc.errno) from exc
        if sent < len(buf):
            raise can.CanOperationError("frame sent in part")


def socketcan_fields(cf: bytes, ts: float) -> RxFrame:
    """A ``struct can_frame``/``canfd_frame`` received at ``ts`` [s] as the service's five numbers
    (python-can's ``dissect_can_frame`` and ``capture_message``, without the ``can.Message``)."""
    can_id = int.from_bytes(cf[0:4], "little" if _LITTLE else "big")
    if can_id & _SocketcanIO._ERR:
        return (seconds_to_ns(ts), ERROR_FRAME, False, 0, can_id & 0x1FFFFFFF)
    if can_id & _SocketcanIO._RTR:
        return (0, NOT_DATA, False, 0, 0)
    ext = bool(can_id & _SocketcanIO._EFF)
    dlc = cf[4]
    if len(cf) != 72 and dlc == 8 and 8 < cf[7] <= 15:  # a classic frame's len8_dlc, as python-can reads it
        dlc = cf[7]
    word = int.from_bytes(cf[8 : 8 + dlc], "little")
    return (seconds_to_ns(ts), can_id & (0x1FFFFFFF if ext else 0x7FF), ext, dlc, word)


_LITTLE = struct.pack("=I", 1)[0] == 1


def bus_io(bus: can.BusABC, fast: bool = True) -> BusIO:
    """The frame I/O for ``bus``: its socket fast path where lde knows the bus type (``fast``), else
    python-can's ``recv``/``send``."""
    if not fast:
        return BusIO(bus)
    try:
        from can.interfaces.udp_multicast import UdpMulticastBus
    except ImportError:  # pragma: no cover - python-can without it
        UdpMulticastBus = None  # type: ignore[assignment,misc]  # noqa: N806
    if UdpMulticastBus is not None and isinstance(bus, UdpMulticastBus):
        mc = getattr(bus, "_multicast", None)
        if (
            isinstance(getattr(mc, "_socket", None), socket.socket)
            and getattr(mc, "timestamp_nanosecond", False)
            and hasattr(mc, "_send_destination")
        ):
            try:
                return _UdpMulticastIO(bus, mc)
            except (ValueError, IndexError, AttributeError):  # another python-can's layout
                pass
    if type(bus).__name__ == "SocketcanBus":
        from can.interfaces.socketcan import socketcan as sc

        sock = getattr(bus, "socket", None)
        anc = getattr(sc, "RECEIVED_ANCILLARY_BUFFER_SIZE", None)
        if isinstance(sock, socket.socket) and isinstance(anc, int) and getattr(bus, "channel", "") != "":
            return _SocketcanIO(bus, sock, anc)
    return BusIO(bus)
