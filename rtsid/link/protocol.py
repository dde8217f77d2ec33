"""The ankle robot's CAN protocol: the DBC, a fast state-frame decoder and the encoders.

The canonical description is the DBC ``rtsid/link/ankle.dbc`` (a byte-identical copy lives
in ``hw/ankle.dbc`` for people wiring the robot; a test keeps the two equal). Three frames,
all classic CAN, 11-bit identifiers, 8 data bytes, little-endian (Intel) signals:

========  ===================  ======  =====================================================
ID        name                 rate    content
========  ===================  ======  =====================================================
``0x100`` AnkleState           2500 Hz Position int24 · 1e-6 rad, Torque int20 · 1e-3 N·m,
                                       Counter uint12 (wraps), 4 status bits, Checksum uint4
``0x200`` PerturbationCommand  on use  Enable, Kind, Amplitude uint16 · 1e-5 rad,
                                       Bandwidth uint8 Hz, CommandCounter uint8
``0x300`` Diagnostics          10 Hz   multiplexed by Page: health (temperature, supply,
                                       fault code) and statistics (uptime, tx overflows)
========  ===================  ======  =====================================================

The state frame is decoded on the hot path by :func:`decode_state` (pure integer
arithmetic on one 64-bit word, ≈ 1 µs) instead of cantools (≈ 2 µs plus a dict); a test
checks the two agree bit for bit. Checksum: the XOR of all sixteen nibbles of the frame is
``0xA``, so any single corrupted nibble, and an all-zero frame, are rejected.
"""

from __future__ import annotations

import functools
import types
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import InputDataError

__all__ = [
    "ANKLE_MAPPING",
    "BUILTIN_DBC",
    "COMMAND_ID",
    "COUNTER_MODULO",
    "DIAGNOSTICS_ID",
    "PERTURBATION_KINDS",
    "POSITION_SCALE_RAD",
    "STATE_ID",
    "STATUS_DISCONTINUITY",
    "STATUS_PERTURBATION_ON",
    "STATUS_POSITION_SATURATED",
    "STATUS_TORQUE_SATURATED",
    "TORQUE_SCALE_NM",
    "Command",
    "database",
    "dbc_path",
    "decode_command",
    "decode_state",
    "encode_command",
    "encode_diagnostics",
    "encode_state_block",
    "fold_nibbles",
    "quantise_position",
    "quantise_torque",
]

STATE_ID = 0x100
COMMAND_ID = 0x200
DIAGNOSTICS_ID = 0x300
STATE_DLC = 8

POSITION_SCALE_RAD = 1e-6
POSITION_BITS = 24
TORQUE_SCALE_NM = 1e-3
TORQUE_BITS = 20
COUNTER_BITS = 12
COUNTER_MODULO = 1 << COUNTER_BITS
CHECKSUM_SEED = 0xA

STATUS_POSITION_SATURATED = 0x1
STATUS_TORQUE_SATURATED = 0x2
STATUS_PERTURBATION_ON = 0x4
STATUS_DISCONTINUITY = 0x8

AMPLITUDE_SCALE_RAD = 1e-5
AMPLITUDE_CODES_PER_RAD = 100_000  # dividing by it rounds 4500 to exactly 0.045
PERTURBATION_KINDS = ("off", "prbs", "filtered_noise", "multisine")

#: ``dbc = ""`` in ``[link.protocol]``: the packaged ankle DBC.
BUILTIN_DBC = ""
#: The built-in mapping (``[link.protocol]`` defaults): the ankle robot's DBC (here, not in
#: :mod:`rtsid.link.mapping`, so that reading a configuration does not compile the mapper).
ANKLE_MAPPING: Mapping[str, Any] = types.MappingProxyType(
    {
        "dbc": BUILTIN_DBC,
        "position": "AnkleState.Position",
        "position_sign": 1.0,
        "torque": "AnkleState.Torque",
        "torque_sign": 1.0,
        "counter": "AnkleState.Counter",
        "position_saturated": "AnkleState.PositionSaturated",
        "torque_saturated": "AnkleState.TorqueSaturated",
        "perturbation_on": "AnkleState.PerturbationOn",
        "discontinuity": "AnkleState.Discontinuity",
        "marker": "",
        "marker_on": "change",
        "command": "PerturbationCommand",
        "diagnostics": "Diagnostics",
        "checksum": "nibble_xor",
    }
)

_POS_MASK = (1 << POSITION_BITS) - 1
_POS_SIGN = 1 << (POSITION_BITS - 1)
_TRQ_MASK = (1 << TORQUE_BITS) - 1
_TRQ_SIGN = 1 << (TORQUE_BITS - 1)
_TRQ_SHIFT = POSITION_BITS
_CTR_SHIFT = POSITION_BITS + TORQUE_BITS
_CTR_MASK = COUNTER_MODULO - 1
_STATUS_SHIFT = 56
_CHECKSUM_SHIFT = 60

POSITION_RAW_LIMITS = (-_POS_SIGN, _POS_SIGN - 1)
TORQUE_RAW_LIMITS = (-_TRQ_SIGN, _TRQ_SIGN - 1)


def dbc_path() -> Any:
    """The packaged DBC (a ``Traversable``; ``str()`` gives a path for editable installs)."""
    from importlib import resources  # here: it imports tempfile, and a replay reads no DBC

    return resources.files("rtsid.link").joinpath("ankle.dbc")


@functools.cache
def database() -> Any:
    """The ankle robot's DBC loaded by cantools (cached; treat it as read-only)."""
    import cantools

    return cantools.database.load_string(dbc_path().read_text(encoding="utf-8"), "dbc")


def fold_nibbles(word: int) -> int:
    """XOR of the sixteen nibbles of a 64-bit word."""
    word ^= word >> 32
    word ^= word >> 16
    word ^= word >> 8
    word ^= word >> 4
    return word & 0xF


def decode_state(data: bytes | bytearray) -> tuple[int, int, int, int] | None:
    """Decode the raw integers of one 8-byte AnkleState payload.

    Parameters
    ----------
    data : bytes
        Exactly 8 data bytes (the caller checks the length).

    Returns
    -------
    (position_raw, torque_raw, counter, status) or None
        Signed raw position (× :data:`POSITION_SCALE_RAD` gives rad), signed raw torque
        (× :data:`TORQUE_SCALE_NM` gives N·m), the 12-bit counter and the 4 status bits;
        ``None`` when the checksum does not match (a corrupt frame: never decode it).
    """
    word = int.from_bytes(data, "little")
    if fold_nibbles(word) != CHECKSUM_SEED:
        return None
    position = word & _POS_MASK
    if position & _POS_SIGN:
        position -= 1 << POSITION_BITS
    torque = (word >> _TRQ_SHIFT) & _TRQ_MASK
    if torque & _TRQ_SIGN:
        torque -= 1 << TORQUE_BITS
    return position, torque, (word >> _CTR_SHIFT) & _CTR_MASK, (word >> _STATUS_SHIFT) & 0xF


def quantise_position(
    position_rad: NDArray[np.float64],
) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Raw position codes (rounded, clipped to int24) and where clipping happened."""
    return _quantise(position_rad, POSITION_SCALE_RAD, POSITION_RAW_LIMITS)


def quantise_torque(torque_nm: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Raw torque codes (rounded, clipped to int20) and where clipping happened."""
    return _quantise(torque_nm, TORQUE_SCALE_NM, TORQUE_RAW_LIMITS)


def _quantise(
    values: NDArray[np.float64], scale: float, limits: tuple[int, int]
) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    raw = np.rint(np.asarray(values, dtype=float) / scale)
    clipped = (raw < limits[0]) | (raw > limits[1])
    return np.clip(raw, limits[0], limits[1]).astype(np.int64), clipped


def encode_state_block(
    position_raw: NDArray[np.int64],
    torque_raw: NDArray[np.int64],
    counter: NDArray[np.int64],
    status: NDArray[np.int64],
) -> NDArray[np.uint8]:
    """Payloads of many AnkleState frames at once (vectorised, checksum included).

    Parameters
    ----------
    position_raw, torque_raw : numpy.ndarray of int, shape (n,)
        Raw codes within int24 / int20 (see :func:`quantise_position`).
    counter : numpy.ndarray of int, shape (n,)
        Sample counters (taken modulo 4096).
    status : numpy.ndarray of int, shape (n,)
        Status bits (``STATUS_*``), 0..15.

    Returns
    -------
    numpy.ndarray of uint8, shape (n, 8)
        Row ``k`` is the data field of frame ``k``.
    """
    word = (np.asarray(position_raw, dtype=np.int64) & _POS_MASK).astype(np.uint64)
    word |= (np.asarray(torque_raw, dtype=np.int64) & _TRQ_MASK).astype(np.uint64) << np.uint64(
        _TRQ_SHIFT
    )
    word |= (np.asarray(counter, dtype=np.int64) & _CTR_MASK).astype(np.uint64) << np.uint64(
        _CTR_SHIFT
    )
    word |= (np.asarray(status, dtype=np.int64) & 0xF).astype(np.uint64) << np.uint64(_STATUS_SHIFT)
    fold = word ^ (word >> np.uint64(32))
    for shift in (16, 8, 4):
        fold ^= fold >> np.uint64(shift)
    checksum = (fold & np.uint64(0xF)) ^ np.uint64(CHECKSUM_SEED)
    word |= checksum << np.uint64(_CHECKSUM_SHIFT)
    return word.astype("<u8").view(np.uint8).reshape(-1, 8)


@dataclass(frozen=True)
class Command:
    """Perturbation command/enable sent by the daemon (frame ``0x200``).

    Attributes
    ----------
    enable : bool
        Apply the perturbation (False: the robot holds its zero position).
    kind : str
        One of :data:`PERTURBATION_KINDS`.
    amplitude_rad : float
        Peak amplitude, rad, 0..0.65535 (resolution 1e-5 rad).
    bandwidth_hz : float
        Bandwidth, Hz, 0..255 (resolution 1 Hz).
    counter : int
        Rolling command counter 0..255 (lets the robot ignore a repeated frame).
    """

    enable: bool = True
    kind: str = "prbs"
    amplitude_rad: float = 0.03
    bandwidth_hz: float = 40.0
    counter: int = 0

    def __post_init__(self) -> None:
        if self.kind not in PERTURBATION_KINDS:
            raise InputDataError(
                f"perturbation kind {self.kind!r} is not one of {PERTURBATION_KINDS}"
            )
        if not 0 <= self.amplitude_rad <= 0xFFFF * AMPLITUDE_SCALE_RAD:
            raise InputDataError(
                f"command amplitude {self.amplitude_rad} rad is outside 0..0.65535 rad"
            )
        if not 0 <= self.bandwidth_hz <= 255:
            raise InputDataError(f"command bandwidth {self.bandwidth_hz} Hz is outside 0..255 Hz")


def encode_command(command: Command) -> bytes:
    """The 8 data bytes of a PerturbationCommand frame."""
    amplitude = round(command.amplitude_rad / AMPLITUDE_SCALE_RAD)
    first = int(command.enable) | (PERTURBATION_KINDS.index(command.kind) << 1)
    return bytes(
        [
            first,
            amplitude & 0xFF,
            amplitude >> 8,
            round(command.bandwidth_hz),
            command.counter & 0xFF,
            0,
            0,
            0,
        ]
    )


def decode_command(data: bytes | bytearray) -> Command | None:
    """Decode a PerturbationCommand payload; ``None`` if it is short or names no known kind."""
    if len(data) < 5:
        return None
    kind = (data[0] >> 1) & 0x7
    if kind >= len(PERTURBATION_KINDS):
        return None
    return Command(
        enable=bool(data[0] & 1),
        kind=PERTURBATION_KINDS[kind],
        amplitude_rad=(data[1] | (data[2] << 8)) / AMPLITUDE_CODES_PER_RAD,
        bandwidth_hz=float(data[3]),
        counter=data[4],
    )


def encode_diagnostics(page: int, **signals: float) -> bytes:
    """A Diagnostics payload for ``page`` 0 (health) or 1 (statistics), encoded by cantools."""
    message = database().get_message_by_frame_id(DIAGNOSTICS_ID)
    return bytes(message.encode({"Page": page, **signals}, strict=True))


def decode_diagnostics(data: bytes | bytearray) -> dict[str, Any] | None:
    """Decode a Diagnostics payload with cantools; ``None`` if it does not decode."""
    message = database().get_message_by_frame_id(DIAGNOSTICS_ID)
    try:
        return dict(message.decode(bytes(data), decode_choices=False))
    except Exception:
        return None
