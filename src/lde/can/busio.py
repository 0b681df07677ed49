"""How lde uses a python-can bus: open it, name it, filter it, drain it, read and write frames.

Everything goes through python-can's public API (``can.Bus``, ``recv``, ``send``, ``set_filters``,
``fileno``, ``can.util.load_config``). This module is the one place that knows more about a
particular interface, and each such use falls back to the plain path when the interface is not
what it expects:

* python-can's ``udp_multicast``: on the socket whose descriptor ``bus.fileno()`` returns, the
  option that keeps datagrams of other groups on the same port out (:func:`own_group_only`), and a
  kernel socket filter on the datagram's CAN id (:func:`receive_only`). The filter's byte offsets
  come from python-can's own ``pack_message`` at run time; any other datagram layout gets no socket
  filter (python-can's filters then, read on as below).
* SocketCAN: python-can documents that its filters are applied in the kernel (``CAN_RAW_FILTER``);
  the service reads and writes the frames on the bus's descriptor itself, as Linux's
  ``struct can_frame`` (:class:`_SocketcanIO`: a system call per frame fewer than python-can's).

**Draining.** With filters set, python-can filters in software on most interfaces, and its
``recv(timeout=0)`` returns None at the first frame the filter rejects, with more frames still
queued. A consumer that drains with ``recv(0)`` until None then stops early every step: the
simulator took in 13-21 of several thousand ``LDE_Overlay`` frames that way. :func:`drain` and
:meth:`BusIO.recv` read on while the bus's descriptor is still readable; on a bus without one
(python-can's in-process ``virtual`` bus) :func:`receive_only` sets no filters and the consumer
ignores other ids itself.

The service needs five numbers per frame, not a ``can.Message``: :meth:`BusIO.recv` gives
``(t_ns, can_id, is_extended, dlc, word)``, ``t_ns`` the receive time [ns] rounded to the microsecond
(:func:`lde.can.frames.seconds_to_ns`), ``word`` the data bytes as a little-endian integer (64 bits
for a classic frame, up to 512 for CAN FD), ``can_id``
:data:`NOT_DATA` (-1) for a remote frame, :data:`ERROR_FRAME` (-2) for an error frame (``word``: its
error class). Output frames are built once (:class:`TxFrame`) and their data bytes refilled in place.
"""

from __future__ import annotations

import contextlib
import ctypes
import inspect
import logging
import select
import socket
import struct
import sys
import weakref
from collections.abc import Iterable, Iterator
from typing import TYPE_CHECKING, Any

import can
import numpy as np

from lde.can.frames import seconds_to_ns
from lde.errors import BusError

if TYPE_CHECKING:
    from can.typechecking import CanFilter

__all__ = [
    "ERROR_FRAME",
    "NOT_DATA",
    "BusIO",
    "TxFrame",
    "bus_io",
    "bus_label",
    "describe_bus",
    "drain",
    "frames_waiting",
    "message_fields",
    "open_bus",
    "own_group_only",
    "receive_only",
    "socketcan_fields",
]

log = logging.getLogger(__name__)

#: one received frame: (t_ns, can_id (< 0: not a data frame), is_extended, dlc, word)
RxFrame = tuple[int, int, bool, int, int]
#: ``can_id`` of a remote frame (not a data frame: ignored)
NOT_DATA = -1
#: ``can_id`` of an error frame (counted by the service); ``word`` carries the error class
ERROR_FRAME = -2
#: a drain reads on past frames the filter rejects at most this many times in one call (it ends
#: even on a bus whose descriptor stays readable); what is left waits for the next call
MAX_READ_ON = 4096


# ---------------------------------------------------------------------- opening and naming
def open_bus(**kwargs: Any) -> can.BusABC:
    """Open a python-can bus the python-can way (arguments, environment, config file).

    ``kwargs`` with value None are left out so that python-can's environment variables
    (``CAN_INTERFACE``, ``CAN_CHANNEL``, ...) and config file fill them in. A ``udp_multicast`` bus
    hears only its own group (:func:`own_group_only`).
    """
    kw = {k: v for k, v in kwargs.items() if v is not None}
    try:
        bus = can.Bus(**kw)
    except (can.CanError, OSError, ValueError, ImportError, NotImplementedError) as exc:
        raise BusError(f"cannot open CAN bus {kw or '(from python-can config)'}: {exc}") from exc
    own_group_only(bus)
    return bus


def _config(kwargs: dict[str, Any]) -> dict[str, Any]:
    """The bus configuration python-can resolves from ``kwargs`` (None values: environment, config
    file), with the interface's own defaults for the channel and port where it has them."""
    kw = {k: v for k, v in kwargs.items() if v is not None}
    try:
        cfg = dict(can.util.load_config(config=kw))
    except (can.CanError, ValueError, NotImplementedError):
        cfg = dict(kw)
    if cfg.get("interface") == "udp_multicast":
        with contextlib.suppress(ImportError, TypeError, ValueError):
            from can.interfaces.udp_multicast import UdpMulticastBus

            params = inspect.signature(UdpMulticastBus.__init__).parameters
            for key in ("channel", "port"):
                if cfg.get(key) is None and key in params:
                    default = params[key].default
                    if default is not inspect.Parameter.empty:
                        cfg[key] = default
    return cfg


def bus_label(**kwargs: Any) -> str:
    """The bus as python-can names it, ``interface:channel`` (``udp_multicast:239.74.163.77``,
    ``socketcan:vcan0``), from the arguments :func:`open_bus` takes; ``udp_multicast`` adds its port
    (``udp_multicast:239.74.163.77 port 47311``): two buses hear each other when both are equal."""
    cfg = _config(kwargs)
    label = f"{cfg.get('interface', 'unknown')}:{cfg.get('channel', '')}"
    if cfg.get("interface") == "udp_multicast" and cfg.get("port") is not None:
        label += f" port {cfg['port']}"
    return label


def describe_bus(bus: can.BusABC) -> str:
    """A name for an open bus when its configuration is not at hand: python-can's ``channel_info``,
    or the interface's class name."""
    info = getattr(bus, "channel_info", "")
    return info if info and info != "unknown" else type(bus).__name__


# ---------------------------------------------------------------------- udp_multicast's socket
def _udp_multicast_bus(bus: can.BusABC) -> bool:
    try:
        from can.interfaces.udp_multicast import UdpMulticastBus
    except ImportError:  # pragma: no cover - python-can without it
        return False
    return isinstance(bus, UdpMulticastBus)


@contextlib.contextmanager
def _socket_of(bus: can.BusABC) -> Iterator[socket.socket | None]:
    """The bus's socket (a duplicate of the descriptor ``bus.fileno()`` gives: options set on it
    apply to python-can's socket), or None where there is none."""
    try:
        fd = bus.fileno()
    except (NotImplementedError, OSError, ValueError, AttributeError):
        fd = -1
    if not isinstance(fd, int) or fd < 0:
        yield None
        return
    try:
        sock = socket.socket(fileno=socket.dup(fd))
    except OSError:
        yield None
        return
    try:
        yield sock
    finally:
        sock.close()


#: Linux: a socket bound to a port receives the datagrams of every group any socket on the host has
#: joined on that port, unless this is 0 (linux/in.h, linux/in6.h; Python names them from 3.13 on)
_IP_MULTICAST_ALL = getattr(socket, "IP_MULTICAST_ALL", 49)
_IPV6_MULTICAST_ALL = getattr(socket, "IPV6_MULTICAST_ALL", 29)


def own_group_only(bus: can.BusABC) -> bool:
    """On python-can's ``udp_multicast`` bus (Linux): receive only the group the bus joined.

    By default Linux hands a socket bound to a port the datagrams of every group joined on this
    host with that port: two users of ``udp_multicast`` with different groups and python-can's
    default port would hear each other. Returns True when the option was set."""
    if not _udp_multicast_bus(bus):
        return False
    with _socket_of(bus) as sock:
        if sock is None or sock.family not in (socket.AF_INET, socket.AF_INET6):
            return False
        try:
            if sock.family == socket.AF_INET:
                sock.setsockopt(socket.IPPROTO_IP, _IP_MULTICAST_ALL, 0)
            else:
                sock.setsockopt(socket.IPPROTO_IPV6, _IPV6_MULTICAST_ALL, 0)
        except OSError:  # not Linux, or a kernel without the option
            return False
    return True


# a classic BPF program (linux/filter.h) attached with SO_ATTACH_FILTER
_SO_ATTACH_FILTER = 26
_BPF_LD_B_ABS, _BPF_LD_H_ABS, _BPF_JEQ_K, _BPF_RET_K = 0x30, 0x28, 0x15, 0x06
_UDP_HEADER = 8  # what a socket filter sees on a UDP socket starts with the UDP header


def udp_datagram_layout(pack: Any = None) -> tuple[tuple[tuple[int, int], ...], int, int] | None:
    """Where python-can's ``udp_multicast`` datagram carries an 11-bit CAN id of 256..2047, from
    python-can's own ``pack_message`` (or ``pack``, same signature): the (offset, byte) pairs that
    are the same in every datagram up to the id's encoding (the timestamp's bytes left out), the
    offset of the id's two big-endian bytes, and the byte before them that says "two bytes" (another
    value there: an id outside 256..2047). None when the layout is not one with a fixed prefix and a
    two-byte id (then no socket filter is made)."""
    if pack is None:
        try:
            from can.interfaces.udp_multicast.utils import pack_message as pack
        except ImportError:
            return None

    def probe(ts: float, can_id: int) -> bytes:
        return bytes(pack(can.Message(timestamp=ts, arbitration_id=can_id, is_extended_id=False, data=b"")))

    try:
        a, b, c = probe(0.0, 0x100), probe(0.0, 0x7FF), probe(1.5, 0x100)
    except Exception:  # noqa: BLE001 - msgpack missing or a packer that fails: no layout
        return None
    if not len(a) == len(b) == len(c):
        return None
    id_diff = [i for i in range(len(a)) if a[i] != b[i]]
    if len(id_diff) != 2 or id_diff[1] != id_diff[0] + 1 or id_diff[0] < 1:
        return None
    at = id_diff[0]
    if a[at : at + 2] != b"\x01\x00" or b[at : at + 2] != b"\x07\xff":
        return None
    ts_diff = [i for i in range(len(a)) if a[i] != c[i]]
    if not ts_diff or max(ts_diff) >= at - 1 or max(ts_diff) - min(ts_diff) >= 8:
        return None
    ts_at = min(ts_diff)
    fixed = tuple((i, a[i]) for i in range(at - 1) if not ts_at <= i < ts_at + 8)
    return fixed, at, a[at - 1]


def udp_filter_program(ids: Iterable[int], layout: tuple[tuple[tuple[int, int], ...], int, int]) -> bytes:
    """A socket filter passing a datagram whose fixed bytes are not ``layout``'s (python-can then
    decodes it and the consumer filters), or whose id is one of ``ids`` (11-bit, 256..2047); the
    other datagrams are dropped in the kernel."""
    fixed, at, two_bytes = layout
    ins: list[tuple[int, int, int, int]] = []
    for off, byte in fixed:  # a byte that differs: not this layout, accept
        ins.append((_BPF_LD_B_ABS, 0, 0, _UDP_HEADER + off))
        ins.append((_BPF_JEQ_K, 0, -1, byte))  # -1: patched to "accept"
    ins.append((_BPF_LD_B_ABS, 0, 0, _UDP_HEADER + at - 1))
    ins.append((_BPF_JEQ_K, 0, -2, two_bytes))  # an id of another size: not an input, drop
    ins.append((_BPF_LD_H_ABS, 0, 0, _UDP_HEADER + at))
    for i in ids:
        ins.append((_BPF_JEQ_K, -1, 0, int(i)))
    ins.append((_BPF_RET_K, 0, 0, 0))  # drop
    ins.append((_BPF_RET_K, 0, 0, 0xFFFFFFFF))  # accept
    drop, accept = len(ins) - 2, len(ins) - 1
    out = []
    for pc, (code, jt, jf, k) in enumerate(ins):
        jt = accept - pc - 1 if jt == -1 else jt
        jf = accept - pc - 1 if jf == -1 else drop - pc - 1 if jf == -2 else jf
        out.append(struct.pack("HBBI", code, jt, jf, k))
    return b"".join(out)


def _attach_udp_filter(bus: can.BusABC, ids: list[int]) -> bool:
    layout = udp_datagram_layout()
    if layout is None or not all(256 <= i <= 0x7FF for i in ids):
        return False
    code = udp_filter_program(ids, layout)
    buf = ctypes.create_string_buffer(code, len(code))
    prog = struct.pack("HL", len(code) // 8, ctypes.addressof(buf))
    with _socket_of(bus) as sock:
        if sock is None:
            return False
        try:
            sock.setsockopt(socket.SOL_SOCKET, _SO_ATTACH_FILTER, prog)
        except OSError as exc:
            log.info("udp_multicast: no socket filter (%s); python-can filters", exc)
            return False
    return True


def _socketcan_bus(bus: can.BusABC) -> bool:
    try:
        from can.interfaces.socketcan import SocketcanBus
    except ImportError:  # pragma: no cover - python-can without it
        return False
    return isinstance(bus, SocketcanBus)


# ---------------------------------------------------------------------- filters and draining
def receive_only(bus: can.BusABC, ids: Iterable[int]) -> str:
    """Pass only the 11-bit ``ids`` up from ``bus`` where that costs the consumer nothing it needs;
    returns how. The consumer ignores any other id itself as well.

    * SocketCAN: python-can's filters, which it applies in the kernel (``CAN_RAW_FILTER``);
    * ``udp_multicast``: a kernel socket filter on the datagram's id (module docstring); it also
      drops the consumer's own sends, which the multicast loopback hands back to its socket;
    * any other bus with a file descriptor: python-can's filters (in software; :func:`drain` reads
      on past the frames they reject);
    * a bus without one (python-can's ``virtual``): none; a drain could not tell a rejected frame
      from an empty queue.
    """
    ids = sorted({int(i) for i in ids})
    filters: list[CanFilter] = [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in ids]
    if _socketcan_bus(bus):
        bus.set_filters(filters)
        return "kernel (SocketCAN filters)"
    bus.set_filters(None)
    if _udp_multicast_bus(bus) and _attach_udp_filter(bus, ids):
        return "kernel (socket filter on udp_multicast)"
    with _socket_of(bus) as sock:
        has_fd = sock is not None
    if has_fd:
        bus.set_filters(filters)
        return "python-can (software)"
    return "none (the consumer ignores other ids)"


def frames_waiting(bus: can.BusABC) -> bool:
    """True when the bus's file descriptor (``bus.fileno()``) is readable now; False when it is not
    or the bus has none."""
    try:
        fd = bus.fileno()
    except (NotImplementedError, OSError, ValueError, AttributeError):
        return False
    if not isinstance(fd, int) or fd < 0:
        return False
    try:
        return bool(select.select([fd], [], [], 0)[0])
    except (OSError, ValueError):
        return False


def _reads_on(bus: can.BusABC, kernel_filters: bool | None = None) -> bool:
    """Whether a ``recv(0)`` that returned None may have stopped at a frame python-can's software
    filter rejected (filters set, not applied in the kernel). ``kernel_filters``: whether the bus
    filters in the kernel (SocketCAN), if known."""
    if getattr(bus, "filters", None) is None:  # none set (or a bus-like object without them)
        return False
    return not (_socketcan_bus(bus) if kernel_filters is None else kernel_filters)


def drain(bus: can.BusABC, limit: int | None = None) -> Iterator[can.Message]:
    """The frames that have arrived on ``bus`` and pass its filters, without waiting; at most
    ``limit`` (None: all), the rest stay queued for the next call. Reads on past the frames
    python-can's software filter rejects (module docstring)."""
    n = 0
    read_on = MAX_READ_ON if _reads_on(bus) else 0
    while limit is None or n < limit:
        msg = bus.recv(0.0)
        if msg is None:
            if read_on > 0 and frames_waiting(bus):
                read_on -= 1
                continue
            return
        n += 1
        yield msg


# ---------------------------------------------------------------------- the service's frame I/O
class TxFrame:
    """A prebuilt output frame: fill ``view`` (its ``dlc`` data bytes), then :meth:`BusIO.send` it.

    Attributes:
        can_id: the 11- or 29-bit id.
        is_extended: 29-bit id.
        dlc: data length [bytes].
        msg: the ``can.Message`` (python-can's send; its ``data`` a ``bytearray``).
        buf: the bytes written to the socket where the I/O writes them itself (SocketCAN's
            ``struct can_frame``), else None.
        view: uint8 array over the data bytes.
        data, data_at: the ``bytearray`` that holds them and their offset in it (a slice assignment
            to it costs half a numpy copy into ``view``).
    """

    __slots__ = ("can_id", "is_extended", "dlc", "view", "msg", "buf", "data", "data_at")

    def __init__(self, msg: can.Message, buf: bytearray | None = None, data_at: int = 0) -> None:
        msg.data = bytearray(msg.data)
        self.can_id = int(msg.arbitration_id)
        self.is_extended = bool(msg.is_extended_id)
        self.dlc = int(msg.dlc)
        self.msg = msg
        self.buf = buf
        self.data: bytearray = msg.data if buf is None else buf
        self.data_at = 0 if buf is None else data_at
        self.view = np.frombuffer(self.data, np.uint8, count=self.dlc, offset=self.data_at)

    def word(self) -> int:
        """The data bytes as a little-endian integer (what the recorder stores)."""
        return int.from_bytes(self.view.tobytes(), "little")


class BusIO:
    """The service's frame I/O on a python-can bus: ``recv`` and ``send`` of python-can."""

    kind = "python-can"

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self._kernel_filters = _socketcan_bus(bus)

    def recv(self, timeout: float | None) -> RxFrame | None:
        """The next frame within ``timeout`` [s] (0: poll; reads on past frames python-can's software
        filter rejects, :func:`drain`), or None. Raises ``can.CanError``/``OSError`` as the bus does."""
        bus = self.bus
        msg = bus.recv(timeout)
        if msg is None and timeout == 0 and _reads_on(bus, self._kernel_filters):
            for _ in range(MAX_READ_ON):
                if not frames_waiting(bus):
                    break
                msg = bus.recv(0.0)
                if msg is not None:
                    break
        if msg is None:
            return None
        return message_fields(msg)

    def tx(self, msg: can.Message) -> TxFrame:
        """``msg`` as a prebuilt output frame (its data becomes a ``bytearray`` of ``dlc`` bytes)."""
        return TxFrame(msg)

    def send(self, tx: TxFrame, t_s: float) -> None:
        """Send ``tx`` stamped ``t_s`` [s]; raises ``can.CanError`` or ``OSError`` as the bus does."""
        msg = tx.msg
        msg.timestamp = t_s
        self.bus.send(msg)

    def close(self) -> None:
        """Let go of what this I/O holds beyond the bus (the bus belongs to the caller)."""


def message_fields(msg: can.Message) -> RxFrame:
    """A received ``can.Message`` as the service's five numbers (can_id < 0: not a data frame)."""
    if msg.is_error_frame:
        return (seconds_to_ns(msg.timestamp), ERROR_FRAME, False, 0, msg.arbitration_id)
    if msg.is_remote_frame:
        return (0, NOT_DATA, False, 0, 0)
    data = msg.data
    word = int.from_bytes(data, "little")
    return (seconds_to_ns(msg.timestamp), msg.arbitration_id, msg.is_extended_id, msg.dlc, word)


class _SocketcanIO(BusIO):
    """SocketCAN on the bus's own socket: the descriptor python-can documents (``bus.fileno()``) and
    Linux's ``struct can_frame`` / ``canfd_frame`` (linux/can.h, a kernel ABI), python-can's filters
    (in the kernel) left as they are. One ``recvmsg`` per frame received and one ``send`` per frame
    sent, where python-can's ``recv`` and ``send`` add a ``select`` to each: in user-mode Linux, where
    a system call costs 30-70 us, a step's drain and four sends cost about 2.5 times as much through
    python-can (``bench/bench_bus_io.py --socketcan vcan0``). The same frames and kernel timestamps
    as python-can's (tests/uml/test_vcan_busio.py)."""

    kind = "socketcan (descriptor)"

    def __init__(self, bus: can.BusABC, sock: socket.socket) -> None:
        super().__init__(bus)
        self.sock = sock
        self._closer = weakref.finalize(self, sock.close)
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)  # python-can sets it too: the same
        self._ancsize = socket.CMSG_SPACE(_TIMESPEC.size)
        self._rlist = [sock]

    def recv(self, timeout: float | None) -> RxFrame | None:
        sock = self.sock
        if timeout is None or timeout > 0:
            try:
                if not select.select(self._rlist, [], [], timeout)[0]:
                    return None
            except OSError as exc:
                raise can.CanOperationError(f"failed to wait for the socket: {exc}") from exc
        try:
            cf, anc, _, _ = sock.recvmsg(_CANFD_MTU, self._ancsize, _DONTWAIT)
        except BlockingIOError:
            return None
        except OSError as exc:
            raise can.CanOperationError(f"Error receiving: {exc.strerror}", exc.errno) from exc
        for level, kind, data in anc:
            if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS:
                sec, nsec = _TIMESPEC.unpack_from(data)
                return socketcan_fields(cf, sec + nsec * 1e-9)
        raise can.CanOperationError("no receive timestamp on the socket")

    def tx(self, msg: can.Message) -> TxFrame:
        if msg.is_fd or msg.dlc > 8:
            return TxFrame(msg)  # CAN FD: python-can's send
        can_id = msg.arbitration_id | (_CAN_EFF_FLAG if msg.is_extended_id else 0)
        buf = bytearray(_CAN_FRAME.pack(can_id, msg.dlc, bytes(msg.data).ljust(8, b"\0")))
        return TxFrame(msg, buf, data_at=8)

    def send(self, tx: TxFrame, t_s: float) -> None:
        buf = tx.buf
        if buf is None:
            return super().send(tx, t_s)
        tx.msg.timestamp = t_s
        try:
            sent = self.sock.send(buf)
        except OSError as exc:
            raise can.CanOperationError(f"Failed to transmit: {exc.strerror}", exc.errno) from exc
        if sent < len(buf):
            raise can.CanOperationError("frame sent in part")

    def close(self) -> None:
        self._closer()


# linux/can.h: struct can_frame {canid_t can_id; __u8 len; __u8 pad, res0, len8_dlc; __u8 data[8]}
_CAN_FRAME = struct.Struct("=IB3x8s")
_CANFD_MTU = 72  # sizeof(struct canfd_frame): classic frames come as 16 bytes
_CAN_EFF_FLAG, _CAN_RTR_FLAG, _CAN_ERR_FLAG = 0x80000000, 0x40000000, 0x20000000
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_TIMESPEC = struct.Struct("@ll")
_DONTWAIT = getattr(socket, "MSG_DONTWAIT", 0)


def socketcan_fields(cf: bytes, ts: float) -> RxFrame:
    """A ``struct can_frame`` / ``canfd_frame`` received at ``ts`` [s] as the service's five numbers,
    read as python-can reads them (a classic frame's ``len8_dlc`` included)."""
    can_id = int.from_bytes(cf[0:4], sys.byteorder)
    if can_id & _CAN_ERR_FLAG:
        return (seconds_to_ns(ts), ERROR_FRAME, False, 0, can_id & 0x1FFFFFFF)
    if can_id & _CAN_RTR_FLAG:
        return (0, NOT_DATA, False, 0, 0)
    ext = bool(can_id & _CAN_EFF_FLAG)
    dlc = cf[4]
    if len(cf) != _CANFD_MTU and dlc == 8 and 8 < cf[7] <= 15:
        dlc = cf[7]
    word = int.from_bytes(cf[8 : 8 + dlc], "little")
    return (seconds_to_ns(ts), can_id & (0x1FFFFFFF if ext else 0x7FF), ext, dlc, word)


def bus_io(bus: can.BusABC) -> BusIO:
    """The service's frame I/O for ``bus``: on SocketCAN bound to one interface, its own socket
    (:class:`_SocketcanIO`); on any other bus, python-can's ``recv``/``send``."""
    if _socketcan_bus(bus) and hasattr(socket, "AF_CAN"):
        try:
            fd = bus.fileno()
            sock = socket.socket(fileno=socket.dup(fd))
        except (NotImplementedError, OSError, ValueError):
            return BusIO(bus)
        try:
            bound = sock.getsockname()
            if sock.family == socket.AF_CAN and sock.type == socket.SOCK_RAW and bound and bound[0]:
                return _SocketcanIO(bus, sock)
        except OSError:
            pass
        sock.close()
    return BusIO(bus)
