"""CAN error frames (SocketCAN's linux/can/error.h) -> what happened: bus-off, error passive, overflows, ...

python-can hands an error frame over as a Message with is_error_frame set and the error class bits in
arbitration_id (CAN_ERR_FLAG removed); the controller's details are in data[1], the protocol's in data[2..3].
Pure; used by the live view, and meant for the pipeline's diagnostics.
"""

from __future__ import annotations

from slipdaq.records import CanFrame

CAN_ERR_TX_TIMEOUT = 0x001
CAN_ERR_LOSTARB = 0x002
CAN_ERR_CRTL = 0x004
CAN_ERR_PROT = 0x008
CAN_ERR_TRX = 0x010
CAN_ERR_ACK = 0x020
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080
CAN_ERR_RESTARTED = 0x100
CAN_ERR_CNT = 0x200

_CLASSES = (
    (CAN_ERR_BUSOFF, "bus_off"), (CAN_ERR_RESTARTED, "restarted"), (CAN_ERR_CRTL, "controller"),
    (CAN_ERR_PROT, "protocol"), (CAN_ERR_BUSERROR, "bus_error"), (CAN_ERR_ACK, "no_ack"),
    (CAN_ERR_TX_TIMEOUT, "tx_timeout"), (CAN_ERR_LOSTARB, "lost_arbitration"), (CAN_ERR_TRX, "transceiver"),
)
# data[1] when CAN_ERR_CRTL is set
_CRTL = (
    (0x01, "rx_overflow"), (0x02, "tx_overflow"), (0x04, "rx_warning"), (0x08, "tx_warning"),
    (0x10, "rx_passive"), (0x20, "tx_passive"), (0x40, "active"),
)


def error_classes(frame: CanFrame) -> tuple[str, ...]:
    """The error frame's classes ('bus_off', 'restarted', 'controller', ...) and controller details
    ('rx_overflow', 'tx_passive', ...); () for a data frame. An error frame with no known bit is ('unknown',)."""
    if not frame.is_error_frame:
        return ()
    out = [name for bit, name in _CLASSES if frame.arbitration_id & bit]
    if frame.arbitration_id & CAN_ERR_CRTL and len(frame.data) > 1:
        out += [name for bit, name in _CRTL if frame.data[1] & bit]
    return tuple(out) or ("unknown",)
