"""Is there a usable SocketCAN channel here? (standard library only: the plugin asks at collection)."""

from __future__ import annotations

import socket
import sys

__all__ = ["socketcan_unavailable"]


def socketcan_unavailable(channel: str = "vcan0", hint: str = "") -> str | None:
    """None when a raw CAN socket binds to ``channel``; otherwise the reason, ending with ``hint``.

    A kernel without CAN (most containers, this project's development machines) fails at the socket;
    a kernel with CAN but no such interface fails at the bind.
    """
    tail = f"; {hint}" if hint else ""
    if not sys.platform.startswith("linux"):
        return f"needs Linux SocketCAN ({channel}); this is {sys.platform}{tail}"
    if not hasattr(socket, "AF_CAN"):
        return f"this Python has no socket.AF_CAN{tail}"
    try:
        s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError as exc:
        return f"no SocketCAN in this kernel ({exc.strerror}){tail}"
    try:
        s.bind((channel,))
    except OSError as exc:
        return f"no usable {channel} ({exc.strerror}){tail}"
    finally:
        s.close()
    return None
