"""Bring your own CAN protocol: a mapping from any DBC's signals to samples.

``[link.protocol]`` (:class:`~rtsid.link.config.ProtocolConfig`) names a DBC and the
``Message.Signal`` that carries each quantity; :func:`compile_protocol` checks the mapping
against the DBC once, at config load, and gives a :class:`MappedProtocol`:

* position and torque, each from its own message and signal, converted from the DBC's
  unit (rad, deg, mrad, µrad; N·m, mN·m, N·cm …) and multiplied by a ``sign``;
* a sample counter (its width from the DBC), or none: the sample index then comes from the
  frames' timestamps (``ceil((t - t_newest)·fs_hz - 0.5)`` samples after the newest, so a
  timestamp jump of more than 1.5 periods is a gap and one within half a period repeats
  the newest sample);
* optional status bits (position/torque saturated, perturbation on, discontinuity), a trial
  marker signal, a command message and a diagnostics message.

Position and torque may come in two messages: the two frames of one sample are paired by
counter (the counter signal's name must be in both messages) or, without one, by time
(within half a sample period). A frame whose partner never comes is counted
(``unpaired``) and its sample is lost, never invented.

The built-in ankle protocol (``rtsid/link/ankle.dbc``) is the default mapping; its decoder is
the fast integer one (:func:`rtsid.link.protocol.decode_state`), which a test keeps equal to
this module's cantools decoder. Every mapping error is one line naming the DBC, the message
and the signal, raised as :class:`~rtsid.errors.ConfigError` when the config loads.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from rtsid.errors import ConfigError
from rtsid.link.protocol import (
    ANKLE_MAPPING,
    BUILTIN_DBC,
    CHECKSUM_SEED,
    COUNTER_MODULO,
    PERTURBATION_KINDS,
    POSITION_SCALE_RAD,
    STATE_ID,
    STATUS_DISCONTINUITY,
    STATUS_PERTURBATION_ON,
    STATUS_POSITION_SATURATED,
    STATUS_TORQUE_SATURATED,
    TORQUE_SCALE_NM,
    Command,
    database,
    dbc_path,
    decode_command,
    decode_diagnostics,
    encode_command,
    encode_state_block,
    fold_nibbles,
    quantise_position,
    quantise_torque,
)

if TYPE_CHECKING:  # python-can (asyncio, sqlite3, …) is imported where frames are made
    import can

__all__ = [
    "ANGLE_UNITS",
    "ANKLE_MAPPING",
    "BUILTIN_DBC",
    "FRAME_COMMAND",
    "FRAME_DIAGNOSTICS",
    "FRAME_STATE",
    "MIN_COUNTER_BITS",
    "TORQUE_UNITS",
    "MappedProtocol",
    "compile_protocol",
    "frame_key",
]

#: Narrowest counter accepted: a wrap must exceed the reorder window (64) twice over.
MIN_COUNTER_BITS = 8
#: Narrowest position/torque signal accepted, bits.
MIN_VALUE_BITS = 8
_EXTENDED = 1 << 31

FRAME_STATE, FRAME_COMMAND, FRAME_DIAGNOSTICS = 0, 1, 2

#: Units accepted for position, and their factor to rad.
ANGLE_UNITS = {
    "rad": 1.0,
    "mrad": 1e-3,
    "urad": 1e-6,
    "µrad": 1e-6,
    "deg": math.pi / 180,
    "degree": math.pi / 180,
    "degrees": math.pi / 180,
    "°": math.pi / 180,
}
#: Units accepted for torque (``·``, ``*``, ``.`` and spaces removed), and their factor to N·m.
TORQUE_UNITS = {"Nm": 1.0, "mNm": 1e-3, "Ncm": 1e-2, "Nmm": 1e-3, "kNm": 1e3}

#: The status signals a mapping may name, and the status bit each sets.
STATUS_SIGNALS = {
    "position_saturated": STATUS_POSITION_SATURATED,
    "torque_saturated": STATUS_TORQUE_SATURATED,
    "perturbation_on": STATUS_PERTURBATION_ON,
    "discontinuity": STATUS_DISCONTINUITY,
}
_COMMAND_SIGNALS = ("Enable", "Kind", "Amplitude", "Bandwidth", "CommandCounter")


def frame_key(arbitration_id: int, extended: bool) -> int:
    """The lookup key of a frame: its identifier, bit 31 set for a 29-bit identifier."""
    return arbitration_id | _EXTENDED if extended else arbitration_id


def _unit_key(unit: str) -> str:
    return "".join(ch for ch in unit if ch not in " ·*.⋅")


@dataclass(frozen=True)
class _Field:
    """One mapped signal: its message, the cantools signal and the factor to SI units."""

    message: Any
    signal: Any
    factor: float  # SI units per DBC physical unit, times the sign

    @property
    def name(self) -> str:
        return str(self.signal.name)

    def raw_limits(self) -> tuple[int, int]:
        """Smallest and largest raw code of the signal."""
        bits = int(self.signal.length)
        if self.signal.is_signed:
            return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
        return 0, (1 << bits) - 1

    def quantise(self, values: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
        """Raw codes of SI ``values`` (rounded, clipped to the signal) and where clipping was."""
        physical = np.asarray(values, dtype=float) / self.factor
        raw = np.rint((physical - float(self.signal.offset)) / float(self.signal.scale))
        low, high = self.raw_limits()
        clipped = (raw < low) | (raw > high)
        return np.clip(raw, low, high).astype(np.int64), clipped

    def to_si(self, raw: NDArray[Any]) -> NDArray[np.float64]:
        """SI values of raw codes (as the decoder computes them)."""
        physical = raw * float(self.signal.scale) + float(self.signal.offset)
        return np.asarray(physical * self.factor, dtype=np.float64)


def _or_leave_out(key: str, fix: str) -> str:
    """``fix``, and for an optional key the other fix: leave it out with ``""`` (a key left
    out of the section takes the built-in ankle protocol's name, which another DBC lacks)."""
    if key in ("position", "torque"):
        return fix
    return f'{fix}, or link.protocol.{key} = "" to leave it out'


class _Resolver:
    """Looks signals up in one DBC, every failure one line naming DBC, message and signal."""

    def __init__(self, db: Any, label: str) -> None:
        self.db = db
        self.label = label

    def fail(self, what: str, fix: str) -> ConfigError:
        return ConfigError(f"[link.protocol] DBC {self.label}: {what}; {fix}")

    def message(self, name: str, key: str, signal: str = "") -> Any:
        try:
            return self.db.get_message_by_name(name)
        except KeyError:
            known = ", ".join(sorted(m.name for m in self.db.messages)[:12]) or "none"
            what = f" (for signal {signal!r})" if signal else ""
            raise self.fail(
                f"{key} names message {name!r}{what}, which the DBC does not define",
                _or_leave_out(key, f"use one of its messages ({known})"),
            ) from None

    def signal(self, ref: str, key: str, min_bits: int = 1) -> tuple[Any, Any]:
        if ref.count(".") != 1 or not all(ref.split(".")):
            raise self.fail(
                f"{key} = {ref!r} is not 'Message.Signal'", "write e.g. 'AnkleState.Position'"
            )
        msg_name, sig_name = ref.split(".")
        message = self.message(msg_name, key, sig_name)
        try:
            signal = message.get_signal_by_name(sig_name)
        except KeyError:
            known = ", ".join(s.name for s in message.signals) or "none"
            raise self.fail(
                f"message {msg_name} has no signal {sig_name!r} (for {key})",
                _or_leave_out(key, f"use one of {known}"),
            ) from None
        where = f"message {msg_name} signal {sig_name}"
        if signal.multiplexer_ids is not None or signal.is_multiplexer:
            raise self.fail(
                f"{where} (for {key}) is multiplexed",
                "map a signal that is in every frame of its message",
            )
        if int(signal.length) < min_bits:
            raise self.fail(
                f"{where} (for {key}) is {signal.length} bits wide, too narrow",
                f"map a signal of at least {min_bits} bits",
            )
        return message, signal

    def unit_factor(self, message: Any, signal: Any, key: str, units: dict[str, float]) -> float:
        unit = signal.unit or ""
        factor = units.get(unit) if key == "position" else units.get(_unit_key(unit))
        if factor is None:
            accepted = (
                "rad, mrad, urad, deg" if key == "position" else "N·m (N.m, N*m, Nm), mNm, Ncm"
            )
            raise self.fail(
                f"message {message.name} signal {signal.name} (for {key}) has unit {unit!r}, "
                f"not convertible to {'rad' if key == 'position' else 'N·m'}",
                f"give it one of {accepted} in the DBC",
            )
        return factor


def _load_dbc(path: str) -> tuple[Any, str]:
    """The cantools database of ``path`` ("" = the packaged ankle DBC) and its label."""
    import cantools

    if path == BUILTIN_DBC:
        return database(), f"{dbc_path().name} (built in)"
    try:
        return cantools.database.load_file(path, database_format="dbc", strict=True), repr(path)
    except FileNotFoundError:
        raise ConfigError(
            f"[link.protocol] DBC {path!r} does not exist; check link.protocol.dbc (a path "
            "relative to the config file)"
        ) from None
    except Exception as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConfigError(
            f"[link.protocol] DBC {path!r} cannot be read as a DBC ({reason}); fix the file or "
            "link.protocol.dbc"
        ) from None


@functools.cache
def compile_protocol(
    dbc: str = BUILTIN_DBC,
    position: str = ANKLE_MAPPING["position"],
    torque: str = ANKLE_MAPPING["torque"],
    *,
    position_sign: float = 1.0,
    torque_sign: float = 1.0,
    counter: str = ANKLE_MAPPING["counter"],
    status: tuple[tuple[str, str], ...] = (),
    marker: str = "",
    marker_on: str = "change",
    command: str = "",
    diagnostics: str = "",
    checksum: str = "none",
) -> MappedProtocol:
    """Check a mapping against its DBC and compile it (cached: one per distinct mapping).

    Parameters
    ----------
    dbc : str
        Path of the DBC ("" = the packaged ankle DBC).
    position, torque : str
        ``"Message.Signal"`` carrying the joint angle / torque.
    position_sign, torque_sign : float
        +1 or -1, applied after the unit conversion.
    counter : str
        ``"Message.Signal"`` of the sample counter ("" = none: index from timestamps).
    status : tuple of (name, "Message.Signal")
        Status signals, names from :data:`STATUS_SIGNALS`.
    marker : str
        ``"Message.Signal"`` of a trial marker ("" = none).
    marker_on : str
        ``"change"`` (a marker when the value changes) or ``"nonzero"`` (on every sample
        where it is not 0).
    command, diagnostics : str
        Message names ("" = none).
    checksum : str
        ``"nibble_xor"`` (the ankle's: the XOR of the 16 nibbles of an 8-byte frame is 0xA)
        or ``"none"``.

    Raises
    ------
    ConfigError
        One line naming the DBC, the message and the signal.
    """
    db, label = _load_dbc(dbc)
    r = _Resolver(db, label)
    pos_msg, pos_sig = r.signal(position, "position", MIN_VALUE_BITS)
    trq_msg, trq_sig = r.signal(torque, "torque", MIN_VALUE_BITS)
    pos = _Field(pos_msg, pos_sig, r.unit_factor(pos_msg, pos_sig, "position", ANGLE_UNITS))
    pos = _Field(pos_msg, pos_sig, pos.factor * position_sign)
    trq = _Field(trq_msg, trq_sig, r.unit_factor(trq_msg, trq_sig, "torque", TORQUE_UNITS))
    trq = _Field(trq_msg, trq_sig, trq.factor * torque_sign)
    data_messages = [pos_msg] if pos_msg is trq_msg else [pos_msg, trq_msg]
    counter_name, modulo = _counter(r, counter, data_messages)
    status_fields = tuple(
        (STATUS_SIGNALS[name], _in_data_message(r, ref, f"{name}", data_messages))
        for name, ref in status
    )
    marker_field = _in_data_message(r, marker, "marker", data_messages) if marker else None
    command_msg = r.message(command, "command") if command else None
    if command_msg is not None:
        _check_command(r, command_msg)
    diag_msg = r.message(diagnostics, "diagnostics") if diagnostics else None
    if checksum == "nibble_xor":
        for m in data_messages:
            if m.length != 8:
                raise r.fail(
                    f"message {m.name} is {m.length} bytes; checksum 'nibble_xor' needs 8",
                    "set link.protocol.checksum = 'none'",
                )
    return MappedProtocol(
        label=label,
        position=pos,
        torque=trq,
        data_messages=tuple(data_messages),
        counter_signal=counter_name,
        counter_modulo=modulo,
        status_fields=status_fields,
        marker=marker_field,
        marker_on=marker_on,
        command_message=command_msg,
        diagnostics_message=diag_msg,
        checksum=checksum,
        builtin=False,
    )


def _counter(r: _Resolver, ref: str, data_messages: Sequence[Any]) -> tuple[str, int]:
    """The counter's signal name and modulo (0: no counter)."""
    if not ref:
        return "", 0
    message, signal = r.signal(ref, "counter", MIN_COUNTER_BITS)
    if message not in data_messages:
        raise r.fail(
            f"counter message {message.name} carries neither position nor torque",
            "map the counter of the position or torque message",
        )
    if signal.is_signed or signal.is_float or signal.scale != 1 or signal.offset != 0:
        raise r.fail(
            f"message {message.name} signal {signal.name} (for counter) is not a plain unsigned "
            "integer (scale 1, offset 0)",
            "map an unsigned integer counter",
        )
    for other in data_messages:
        try:
            twin = other.get_signal_by_name(signal.name)
        except KeyError:
            raise r.fail(
                f"message {other.name} has no signal {signal.name!r} to pair its frames by counter",
                "add the counter to both messages, or set link.protocol.counter = '' to pair "
                "by time",
            ) from None
        if twin.length != signal.length:
            raise r.fail(
                f"message {other.name} signal {signal.name} (for counter) is {twin.length} bits, "
                f"not {signal.length} as in {message.name}",
                "give both counters the same width",
            )
    return str(signal.name), 1 << int(signal.length)


def _in_data_message(r: _Resolver, ref: str, key: str, data_messages: Sequence[Any]) -> _Field:
    message, signal = r.signal(ref, key)
    if message not in data_messages:
        raise r.fail(
            f"{key} message {message.name} carries neither position nor torque",
            "map a signal of the position or torque message",
        )
    return _Field(message, signal, 1.0)


def _check_command(r: _Resolver, message: Any) -> None:
    names = {s.name for s in message.signals}
    missing = [n for n in _COMMAND_SIGNALS if n not in names]
    if missing:
        raise r.fail(
            f"command message {message.name} has no signal {missing[0]!r} (a command needs "
            + ", ".join(_COMMAND_SIGNALS)
            + ")",
            "add it, or set link.protocol.command = ''",
        )


#: Decoded sample: (counter or timestamp s, position rad, torque N·m, status bits, marker label
#: or None).
DecodedSample = tuple[float, float, float, int, str | None]
#: :meth:`StateDecoder.decode` result for a frame waiting for its partner.
PENDING: tuple[()] = ()


class MappedProtocol:
    """A compiled protocol mapping (immutable; make a decoder per acquisition).

    Attributes
    ----------
    label : str
        The DBC as errors name it.
    counter_modulo : int
        ``2**bits`` of the counter; 0 without a counter (index from timestamps).
    frame_kinds : dict
        :func:`frame_key` → ``FRAME_STATE``, ``FRAME_COMMAND`` or ``FRAME_DIAGNOSTICS``.
    state_lengths : dict
        :func:`frame_key` of each state message → its length in bytes.
    builtin : bool
        The built-in ankle mapping (fast integer decoder and vectorised encoder).
    """

    def __init__(
        self,
        *,
        label: str,
        position: _Field,
        torque: _Field,
        data_messages: tuple[Any, ...],
        counter_signal: str,
        counter_modulo: int,
        status_fields: tuple[tuple[int, _Field], ...],
        marker: _Field | None,
        marker_on: str,
        command_message: Any,
        diagnostics_message: Any,
        checksum: str,
        builtin: bool,
    ) -> None:
        self.label = label
        self.position = position
        self.torque = torque
        self.data_messages = data_messages
        self.counter_signal = counter_signal
        self.counter_modulo = counter_modulo
        self.status_fields = status_fields
        self.marker = marker
        self.marker_on = marker_on
        self.command_message = command_message
        self.diagnostics_message = diagnostics_message
        self.checksum = checksum
        self.builtin = builtin
        self.frame_kinds: dict[int, int] = {}
        self.state_lengths: dict[int, int] = {}
        for m in data_messages:
            key = frame_key(m.frame_id, m.is_extended_frame)
            self.frame_kinds[key] = FRAME_STATE
            self.state_lengths[key] = int(m.length)
        if command_message is not None:
            key = frame_key(command_message.frame_id, command_message.is_extended_frame)
            self.frame_kinds.setdefault(key, FRAME_COMMAND)
        if diagnostics_message is not None:
            key = frame_key(diagnostics_message.frame_id, diagnostics_message.is_extended_frame)
            self.frame_kinds.setdefault(key, FRAME_DIAGNOSTICS)

    @property
    def frames_per_sample(self) -> int:
        """State frames that make one sample (1 or 2)."""
        return len(self.data_messages)

    @property
    def uses_timestamps(self) -> bool:
        """No counter: the sample index comes from the frames' timestamps."""
        return self.counter_modulo == 0

    def as_builtin(self) -> MappedProtocol:
        """This mapping flagged as the built-in ankle protocol (fast decoder and encoder)."""
        clone = MappedProtocol.__new__(MappedProtocol)
        clone.__dict__.update(self.__dict__)
        clone.builtin = True
        return clone

    def decoder(self) -> StateDecoder | AnkleDecoder:
        """A fresh decoder (it holds the pairing state of one stream)."""
        if self.builtin:
            return AnkleDecoder()
        return StateDecoder(self)

    # ------------------------------------------------------------------ commands
    def encode_command(self, command: Command) -> can.Message:
        """The command frame; ValueError when the protocol maps no command message."""
        m = self.command_message
        if m is None:
            raise ValueError("this protocol maps no command message")
        if self.builtin:
            data = encode_command(command)
        else:
            data = m.encode(
                {
                    "Enable": int(command.enable),
                    "Kind": PERTURBATION_KINDS.index(command.kind),
                    "Amplitude": command.amplitude_rad,
                    "Bandwidth": command.bandwidth_hz,
                    "CommandCounter": command.counter & 0xFF,
                },
                padding=True,
            )
        import can

        return can.Message(arbitration_id=m.frame_id, data=data, is_extended_id=m.is_extended_frame)

    def decode_command(self, msg: can.Message) -> Command | None:
        """A command frame's content; None if it is not this protocol's command or is bad."""
        m = self.command_message
        if m is None or msg.arbitration_id != m.frame_id or msg.is_error_frame:
            return None
        if self.builtin:
            return decode_command(msg.data)
        try:
            values = m.decode(bytes(msg.data), decode_choices=False)
            kind = int(values["Kind"])
            return Command(
                enable=bool(values["Enable"]),
                kind=PERTURBATION_KINDS[kind],
                amplitude_rad=round(float(values["Amplitude"]), 5),
                bandwidth_hz=float(values["Bandwidth"]),
                counter=int(values["CommandCounter"]),
            )
        except Exception:
            return None

    def decode_diagnostics(self, data: bytes | bytearray) -> dict[str, Any] | None:
        """A diagnostics frame's signals; None if it does not decode."""
        m = self.diagnostics_message
        if m is None:
            return None
        if self.builtin:
            return decode_diagnostics(data)
        try:
            return dict(m.decode(bytes(data), decode_choices=False))
        except Exception:
            return None

    # ------------------------------------------------------------------ the plant's side
    def quantise(
        self, position_rad: NDArray[np.float64], torque_nm: NDArray[np.float64]
    ) -> tuple[NDArray[np.int64], NDArray[np.bool_], NDArray[np.int64], NDArray[np.bool_]]:
        """Raw position and torque codes and where each was clipped to its signal's range."""
        if self.builtin:
            pos_raw, pos_sat = quantise_position(position_rad)
            trq_raw, trq_sat = quantise_torque(torque_nm)
            return pos_raw, pos_sat, trq_raw, trq_sat
        pos_raw, pos_sat = self.position.quantise(position_rad)
        trq_raw, trq_sat = self.torque.quantise(torque_nm)
        return pos_raw, pos_sat, trq_raw, trq_sat

    def encode_samples(
        self,
        index: NDArray[np.int64],
        position_raw: NDArray[np.int64],
        torque_raw: NDArray[np.int64],
        status: NDArray[np.int64],
        *,
        marker: NDArray[np.int64] | None = None,
        wall0_s: float = 0.0,
        fs_hz: float = 1.0,
    ) -> list[list[can.Message]]:
        """The frames of consecutive samples, one group per sample.

        ``marker``: raw values of the marker signal, if the mapping has one.

        Without a counter, each frame is stamped with its sample's time ``wall0_s +
        index / fs_hz`` (a virtual bus must be opened with ``preserve_timestamps=True``).
        """
        if self.builtin:
            payload = encode_state_block(position_raw, torque_raw, index % COUNTER_MODULO, status)
            raw = payload.tobytes()
            return [[_frame(STATE_ID, False, raw[8 * k : 8 * k + 8])] for k in range(index.size)]
        if self.checksum != "none":
            raise ConfigError(
                f"[link.protocol] DBC {self.label}: the virtual plant cannot compute checksum "
                f"{self.checksum!r} for a custom mapping; set link.protocol.checksum = 'none'"
            )
        groups: list[list[can.Message]] = []
        stamp = self.uses_timestamps
        for k in range(index.size):
            values: dict[int, dict[str, int]] = {id(m): _zeros(m) for m in self.data_messages}
            values[id(self.position.message)][self.position.name] = int(position_raw[k])
            values[id(self.torque.message)][self.torque.name] = int(torque_raw[k])
            if self.counter_signal:
                for m in self.data_messages:
                    values[id(m)][self.counter_signal] = int(index[k]) % self.counter_modulo
            for bit, f in self.status_fields:
                values[id(f.message)][f.name] = int(bool(status[k] & bit))
            if self.marker is not None and marker is not None:
                values[id(self.marker.message)][self.marker.name] = int(marker[k])
            t = wall0_s + int(index[k]) / fs_hz if stamp else 0.0
            groups.append(
                [
                    _frame(
                        m.frame_id,
                        m.is_extended_frame,
                        m.encode(values[id(m)], scaling=False, padding=True, strict=False),
                        t,
                    )
                    for m in self.data_messages
                ]
            )
        return groups

    def to_si(
        self, position_raw: NDArray[Any], torque_raw: NDArray[Any]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Position (rad) and torque (N·m) of raw codes, exactly as the decoder gives them."""
        if self.builtin:
            return (
                np.asarray(position_raw * POSITION_SCALE_RAD, dtype=np.float64),
                np.asarray(torque_raw * TORQUE_SCALE_NM, dtype=np.float64),
            )
        return self.position.to_si(position_raw), self.torque.to_si(torque_raw)


def _zeros(message: Any) -> dict[str, int]:
    return {s.name: 0 for s in message.signals}


def _frame(frame_id: int, extended: bool, data: bytes, timestamp: float = 0.0) -> can.Message:
    import can  # python-can where a frame is made: a config's check does not import it

    return can.Message(
        arbitration_id=frame_id,
        data=data,
        is_extended_id=extended,
        check=False,
        timestamp=timestamp,
    )


def _state_word(word: int) -> tuple[int, float, float, int] | None:
    """``(counter, position rad, torque N·m, status)`` of one state frame's 8 bytes as a
    little-endian integer; None for a bad checksum (:func:`decode_state`'s integer
    arithmetic, ≈ 1 µs)."""
    fold = word ^ (word >> 32)
    fold ^= fold >> 16
    fold ^= fold >> 8
    fold ^= fold >> 4
    if fold & 0xF != 0xA:
        return None
    position = word & 0xFFFFFF
    if position & 0x800000:
        position -= 0x1000000
    torque = (word >> 24) & 0xFFFFF
    if torque & 0x80000:
        torque -= 0x100000
    return (
        (word >> 44) & 0xFFF,
        position * POSITION_SCALE_RAD,
        torque * TORQUE_SCALE_NM,
        (word >> 56) & 0xF,
    )


class AnkleDecoder:
    """The built-in protocol's decoder: :func:`decode_state`'s integer arithmetic on the 8
    bytes (:func:`_state_word`), because it runs for every frame."""

    unpaired = 0

    def decode(self, key: int, data: bytes | bytearray, bus_time_s: float) -> Any:
        """``(counter, position rad, torque N·m, status, None)``; None for a bad checksum.

        The same as :func:`decode_state` (a test keeps the two, and the cantools mapping of
        the same DBC, equal).
        """
        fields = _state_word(int.from_bytes(data, "little"))
        return None if fields is None else (*fields, None)

    @staticmethod
    def decode_words(
        words: Sequence[int],
    ) -> tuple[list[int], list[float], list[float], list[int]] | None:
        """Counters, positions (rad), torques (N·m) and status bits of many state frames.

        Parameters
        ----------
        words : sequence of int
            Each frame's 8 bytes as a little-endian integer.

        Returns
        -------
        tuple of lists or None
            The same numbers as :meth:`decode` frame by frame; None if any checksum fails
            (the caller then takes the frames one by one, counting the bad ones).
        """
        counters: list[int] = []
        positions: list[float] = []
        torques: list[float] = []
        statuses: list[int] = []
        for word in words:
            fields = _state_word(word)
            if fields is None:
                return None
            counters.append(fields[0])
            positions.append(fields[1])
            torques.append(fields[2])
            statuses.append(fields[3])
        return counters, positions, torques, statuses


class StateDecoder:
    """Turns state frames of a :class:`MappedProtocol` into samples (cantools, ≈ 2–5 µs).

    Attributes
    ----------
    unpaired : int
        Frames of a two-frame sample whose partner never came (their sample is lost).
    """

    def __init__(self, protocol: MappedProtocol) -> None:
        self.p = protocol
        self.unpaired = 0
        self._by_key = {
            frame_key(m.frame_id, m.is_extended_frame): m for m in protocol.data_messages
        }
        self._two = protocol.frames_per_sample == 2
        self._pending: tuple[Any, float, dict[str, Any]] | None = None
        self._half_period_s = 0.0
        self._marker_last: float | None = None

    def set_rate(self, fs_hz: float) -> None:
        """The sample rate, for pairing two frames by time (within half a period)."""
        self._half_period_s = 0.5 / fs_hz

    def decode(self, key: int, data: bytes | bytearray, bus_time_s: float) -> Any:
        """A :data:`DecodedSample`, :data:`PENDING` (first frame of a pair) or None (bad)."""
        p = self.p
        if p.checksum == "nibble_xor" and (
            fold_nibbles(int.from_bytes(data, "little")) != CHECKSUM_SEED
        ):
            return None
        message = self._by_key[key]
        try:
            values = message.decode(bytes(data), decode_choices=False)
        except Exception:
            return None
        stamp = values[p.counter_signal] if p.counter_signal else bus_time_s
        if not self._two:
            return self._sample(stamp, values)
        pending = self._pending
        if pending is not None and pending[0] is not message and self._same(pending[1], stamp):
            self._pending = None
            return self._sample(pending[1], {**pending[2], **values})
        if pending is not None:
            self.unpaired += 1
        self._pending = (message, stamp, values)
        return PENDING

    def _same(self, a: float, b: float) -> bool:
        if self.p.counter_signal:
            return a == b
        return abs(a - b) < self._half_period_s

    def _sample(self, stamp: float, values: dict[str, Any]) -> DecodedSample:
        p = self.p
        status = 0
        for bit, f in p.status_fields:
            if values[f.name]:
                status |= bit
        marker = None
        if p.marker is not None:
            value = float(values[p.marker.name])
            changed = value != self._marker_last and self._marker_last is not None
            if (p.marker_on == "change" and changed) or (p.marker_on == "nonzero" and value):
                marker = f"{p.marker.name}={value:g}"
            self._marker_last = value
        return (
            stamp,
            float(values[p.position.name]) * p.position.factor,
            float(values[p.torque.name]) * p.torque.factor,
            status,
            marker,
        )


def protocol_from_config(cfg: Any, base_dir: str | Path | None = None) -> MappedProtocol:
    """Compile a ``[link.protocol]`` section (:class:`~rtsid.link.config.ProtocolConfig`).

    The default section (the packaged ankle DBC, its signals, signs +1, no marker) gives the
    built-in protocol with its fast decoder.
    """
    dbc = cfg.dbc
    if dbc and base_dir is not None and not Path(dbc).is_absolute():
        dbc = str(Path(base_dir) / dbc)
    status = tuple((name, getattr(cfg, name)) for name in STATUS_SIGNALS if getattr(cfg, name))
    protocol = compile_protocol(
        dbc,
        cfg.position,
        cfg.torque,
        position_sign=cfg.position_sign,
        torque_sign=cfg.torque_sign,
        counter=cfg.counter,
        status=status,
        marker=cfg.marker,
        marker_on=cfg.marker_on,
        command=cfg.command,
        diagnostics=cfg.diagnostics,
        checksum=cfg.checksum,
    )
    mapping = {f: getattr(cfg, f) for f in ANKLE_MAPPING}
    if mapping == ANKLE_MAPPING:
        return protocol.as_builtin()
    return protocol


@functools.cache
def builtin_protocol() -> MappedProtocol:
    """The built-in ankle protocol (the default ``[link.protocol]``)."""
    status = tuple((name, ANKLE_MAPPING[name]) for name in STATUS_SIGNALS)
    return compile_protocol(
        BUILTIN_DBC,
        status=status,
        command=ANKLE_MAPPING["command"],
        diagnostics=ANKLE_MAPPING["diagnostics"],
        checksum="nibble_xor",
    ).as_builtin()
