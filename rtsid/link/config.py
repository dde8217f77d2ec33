"""Configuration of the hardware link (``[link]``) and of the virtual plant (``[plant]``).

``[plant]`` has three sub-tables, ``[plant.faults]`` (:class:`FaultConfig`),
``[plant.stiffness_profile]`` (:class:`StiffnessConfig`) and ``[plant.torque_multisine]``
(:class:`TorqueMultisineConfig`). Build them from a parsed TOML document with
:func:`link_configs_from_mapping` (or from a file with :func:`load_link_configs`); every
unknown key, wrong type or out-of-range value is a one-line :class:`~rtsid.errors.ConfigError`
naming ``section.key``.
"""

from __future__ import annotations

import dataclasses
import types
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rtsid.config import (
    from_config_folder,
    invalid,
    load_toml,
    require_choice,
    require_range,
    section_from_mapping,
)
from rtsid.errors import ConfigError, InputDataError
from rtsid.link.protocol import ANKLE_MAPPING, PERTURBATION_KINDS

if TYPE_CHECKING:  # the plant's simulation, imported where a plant is built: a replay reads
    # this configuration without it
    from rtsid.ident.excitation import Multisine
    from rtsid.sim.reflex import ReflexParameters

__all__ = [
    "FaultConfig",
    "LinkConfig",
    "PlantConfig",
    "ProtocolConfig",
    "StiffnessConfig",
    "TorqueMultisineConfig",
    "UdpConfig",
    "link_config_from_mapping",
    "link_configs_from_mapping",
    "load_link_configs",
    "plant_config_from_mapping",
]

#: socketcand clients: rtsid's (batch reads, the default) and python-can's (frame by frame).
SOCKETCAND_CLIENTS = ("rtsid", "python-can")
#: python-can interfaces rtsid accepts, plus ``embedded`` (the in-process virtual plant).
#: ``udp_multicast`` is left out on purpose: rtsid never uses multicast.
INTERFACES = (
    "embedded",
    "virtual",
    "socketcand",
    "socketcan",
    "pcan",
    "kvaser",
    "vector",
    "ixxat",
    "slcan",
    "gs_usb",
    "nican",
    "neovi",
    "cantact",
    "canalystii",
    "systec",
    "seeedstudio",
    "usb2can",
    "serial",
    "robotell",
    "etas",
    "udp",
)
_DEFAULT_CHANNELS: dict[str, str | int] = {
    "embedded": "rtsid",
    "virtual": "rtsid",
    "pcan": "PCAN_USBBUS1",
    "kvaser": 0,
    "vector": 0,
    "ixxat": 0,
}


@dataclass(frozen=True)
class ProtocolConfig:
    """``[link.protocol]``: which DBC the robot speaks and where each quantity is in it.

    Signals are named ``"Message.Signal"``; ``""`` leaves an optional one out. The defaults
    are the built-in ankle protocol (``rtsid/link/ankle.dbc``). The mapping is checked
    against the DBC when the config loads (:func:`rtsid.link.mapping.compile_protocol`):
    every error is one line naming the DBC, the message and the signal.

    Attributes
    ----------
    dbc : str
        Path of the DBC file, relative to the config file; ``""``: the built-in ankle DBC.
    position, torque : str
        The joint angle and torque signals; their DBC unit must convert to rad (rad, mrad,
        urad, deg) / N·m (N·m, N.m, N*m, Nm, mNm, Ncm, kNm).
    position_sign, torque_sign : float
        +1 or -1, applied after the unit conversion.
    counter : str
        The sample counter (unsigned, >= 8 bits, width from the DBC; with two messages the
        same signal name in both). ``""``: no counter, the sample index comes from the
        frames' timestamps (a jump of more than 1.5 periods is a gap).
    position_saturated, torque_saturated, perturbation_on, discontinuity : str
        Status bits (in the position or torque message).
    marker : str
        A trial-marker signal: each change (``marker_on = "change"``) or each non-zero
        value (``"nonzero"``) stamps a marker on that sample.
    marker_on : str
        ``"change"`` or ``"nonzero"``.
    command : str
        The perturbation command message (signals Enable, Kind, Amplitude, Bandwidth,
        CommandCounter); ``""``: none.
    diagnostics : str
        A diagnostics message decoded into the acquisition's ``last_diagnostics``.
    checksum : str
        ``"nibble_xor"`` (the ankle's 8-byte frame checksum) or ``"none"``.
    """

    dbc: str = ANKLE_MAPPING["dbc"]
    position: str = ANKLE_MAPPING["position"]
    position_sign: float = 1.0
    torque: str = ANKLE_MAPPING["torque"]
    torque_sign: float = 1.0
    counter: str = ANKLE_MAPPING["counter"]
    position_saturated: str = ANKLE_MAPPING["position_saturated"]
    torque_saturated: str = ANKLE_MAPPING["torque_saturated"]
    perturbation_on: str = ANKLE_MAPPING["perturbation_on"]
    discontinuity: str = ANKLE_MAPPING["discontinuity"]
    marker: str = ""
    marker_on: str = "change"
    command: str = ANKLE_MAPPING["command"]
    diagnostics: str = ANKLE_MAPPING["diagnostics"]
    checksum: str = ANKLE_MAPPING["checksum"]

    def __post_init__(self) -> None:
        require_choice("position_sign", self.position_sign, (1.0, -1.0))
        require_choice("torque_sign", self.torque_sign, (1.0, -1.0))
        require_choice("marker_on", self.marker_on, ("change", "nonzero"))
        require_choice("checksum", self.checksum, ("nibble_xor", "none"))
        if not self.is_default():
            from rtsid.link.mapping import protocol_from_config

            protocol_from_config(self)  # every mapping error now, not at the first frame

    def is_default(self) -> bool:
        """Every key at its default: the built-in ankle protocol, which compiles (tested) and
        is compiled where a link opens. Compiling it again to check it loaded the packaged
        DBC with cantools (and python-can with it: ≈ 0.37 G instructions) in every process
        that only reads a configuration, each process of ``replay DIR --jobs N`` among them."""
        return all(getattr(self, f.name) == f.default for f in dataclasses.fields(self))


@dataclass(frozen=True)
class UdpConfig:
    """``[link.udp]``: datagrams from a real-time target (``[link] interface = "udp"``).

    A datagram holds ``samples_per_datagram`` samples back to back, each packed as
    ``sample_format`` (Python :mod:`struct` codes without a byte-order character, e.g.
    ``"Iiii"``) in ``byte_order``; ``fields`` names each code in order: ``counter``
    (required, unsigned; its width gives the wrap), ``position``, ``torque`` (required),
    ``status`` (the ``STATUS_*`` bits), ``marker`` (a change stamps a trial marker) or ``_``
    (ignored). Position = value × ``position_scale`` × ``position_sign`` rad; torque
    likewise in N·m. A datagram of another length is counted ``malformed``.

    Attributes
    ----------
    bind_host : str
        Address to listen on: loopback by default; a lab opens it explicitly (e.g. the
        address of the interface facing the target).
    port : int
        UDP port (0: a free one, for tests).
    byte_order : str
        ``"little"`` or ``"big"``.
    sample_format : str
        :mod:`struct` codes of one sample.
    fields : tuple of str
        One name per code.
    samples_per_datagram : int
        Samples in each datagram.
    position_scale, torque_scale : float
        rad / N·m per unit of the field.
    position_sign, torque_sign : float
        +1 or -1.
    receive_buffer_bytes : int
        Socket receive buffer (``SO_RCVBUF``), bytes.
    embedded_plant : bool
        Run the virtual plant in this process as the sender (on loopback, to ``port``; port
        0 picks a free one): the demo and tests, ``hw/configs/udp-plant.toml``.
    """

    bind_host: str = "127.0.0.1"
    port: int = 25000
    byte_order: str = "little"
    sample_format: str = "Iiii"
    fields: tuple[str, ...] = ("counter", "position", "torque", "status")
    samples_per_datagram: int = 10
    position_scale: float = 1e-6
    torque_scale: float = 1e-3
    position_sign: float = 1.0
    torque_sign: float = 1.0
    receive_buffer_bytes: int = 1 << 20
    embedded_plant: bool = False

    def __post_init__(self) -> None:
        require_range("port", self.port, 0, 65535)
        require_choice("byte_order", self.byte_order, ("little", "big"))
        if not self.has_default_layout():
            from rtsid.link.udp import UDP_FIELDS

            for name in self.fields:
                require_choice("fields", name, UDP_FIELDS)
        require_range("samples_per_datagram", self.samples_per_datagram, 1, 1000)
        require_range("position_scale", self.position_scale, 0.0, None, low_inclusive=False)
        require_range("torque_scale", self.torque_scale, 0.0, None, low_inclusive=False)
        require_choice("position_sign", self.position_sign, (1.0, -1.0))
        require_choice("torque_sign", self.torque_sign, (1.0, -1.0))
        require_range("receive_buffer_bytes", self.receive_buffer_bytes, 4096, 1 << 28)
        if not self.bind_host:
            raise invalid("bind_host", self.bind_host, "an address such as '127.0.0.1'")
        if not self.has_default_layout():
            from rtsid.link.udp import compile_layout

            compile_layout(self)  # every layout error now, not at the first datagram

    def has_default_layout(self) -> bool:
        """The datagram's layout (``byte_order``, ``sample_format``, ``fields``) at its
        defaults: a layout that compiles (tested) and is compiled where the link opens.
        Checking it again imported the UDP link in every process that only reads a
        configuration (each process of ``replay DIR --jobs N`` among them)."""
        return all(getattr(self, k) == v for k, v in _UDP_LAYOUT_DEFAULTS.items())


#: The keys of ``[link.udp]`` that shape a datagram, at their defaults.
_UDP_LAYOUT_DEFAULTS = {
    f.name: f.default
    for f in dataclasses.fields(UdpConfig)
    if f.name in ("byte_order", "sample_format", "fields")
}


@dataclass(frozen=True)
class LinkConfig:
    """The ``[link]`` section: which bus to open and how to acquire from it.

    Attributes
    ----------
    interface : str
        ``"embedded"`` (default: an in-process virtual plant on a private ``virtual``
        channel), ``"virtual"`` (python-can's in-process bus, channel shared by name),
        ``"socketcand"`` (TCP to a socketcand server, e.g. ``rtsid plant``) or a python-can
        hardware interface (``"socketcan"``, ``"pcan"``, ``"kvaser"``, …).
    channel : str or int
        Interface channel: ``"can0"`` (socketcan, socketcand), ``"PCAN_USBBUS1"`` (pcan),
        ``0`` (kvaser), any name (virtual). Empty: that usual default for the interface.
    bitrate : int
        Bit rate, bit/s, passed to adapters that set it (pcan, kvaser, …). SocketCAN takes
        it from ``ip link``; socketcand from its host.
    host, port : str, int
        socketcand server (loopback only in rtsid's defaults; 29536 is socketcand's port).
    fs_hz : float
        The robot's state-frame rate, Hz (sample time = counter / fs_hz).
    ring_capacity_s : float
        Seconds of samples the ring buffer holds (30: the slow lane's 20 s horizon and its
        next fit, with room).
    receive_timeout_s : float
        Longest ``bus.recv`` wait; bounds how long ``stop()`` takes.
    stale_after_s : float
        No state frame for this long: the link reports ``stale`` (robot stopped).
    reconnect_after_stale_s : float
        Reopen the bus after this long without frames (0: never). Needed for socketcand
        with python-can's client, which does not report a closed connection (rtsid's
        does). Not used by ``udp``.
    backoff_min_s, backoff_max_s : float
        Reconnection back-off: first wait, doubling up to the maximum.
    rx_queue_frames : int
        Receive queue bound for ``virtual``/``embedded`` buses, frames.
    tcp_tune : bool
        socketcand: TCP_NODELAY/QUICKACK for lower latency.
    socketcand_client : str
        ``"rtsid"`` (default: rtsid's client, reading a whole TCP read at once and writing
        the built-in protocol's frames to the ring as a block) or ``"python-can"``
        (python-can's client, a ``can.Message`` per frame: the acquisition before issue 22,
        kept for comparison and as a fallback).
    options : dict
        Extra keyword arguments for ``can.Bus`` (e.g. ``{fd = true}``).
    rate_tolerance_percent : float
        The sample rate measured from the data (counter or timestamps over >= 2 s of the
        sender's clock) may differ from ``fs_hz`` by this much before the acquisition
        reports ``rate_mismatch``.
    protocol : ProtocolConfig
        ``[link.protocol]``: the DBC mapping (CAN interfaces).
    udp : UdpConfig
        ``[link.udp]``: the datagram layout (``interface = "udp"``).
    """

    interface: str = "embedded"
    channel: str | int = ""
    bitrate: int = 1_000_000
    host: str = "127.0.0.1"
    port: int = 29536
    fs_hz: float = 2500.0
    ring_capacity_s: float = 30.0
    receive_timeout_s: float = 0.05
    stale_after_s: float = 0.1
    reconnect_after_stale_s: float = 2.0
    backoff_min_s: float = 0.1
    backoff_max_s: float = 5.0
    rx_queue_frames: int = 20000
    tcp_tune: bool = True
    socketcand_client: str = "rtsid"
    options: Mapping[str, Any] = field(default_factory=dict)
    rate_tolerance_percent: float = 2.0
    protocol: ProtocolConfig = field(default_factory=ProtocolConfig)
    udp: UdpConfig = field(default_factory=UdpConfig)

    def __post_init__(self) -> None:
        require_choice("interface", self.interface, INTERFACES)
        require_choice("socketcand_client", self.socketcand_client, SOCKETCAND_CLIENTS)
        require_range("rate_tolerance_percent", self.rate_tolerance_percent, 0.0, 100.0)
        require_range("bitrate", self.bitrate, 10_000, 8_000_000)
        require_range("port", self.port, 0, 65535)
        require_range("fs_hz", self.fs_hz, 1.0, 100_000.0)
        require_range("ring_capacity_s", self.ring_capacity_s, 0.0, 3600.0, low_inclusive=False)
        require_range("receive_timeout_s", self.receive_timeout_s, 0.001, 1.0)
        require_range("stale_after_s", self.stale_after_s, 0.0, 60.0, low_inclusive=False)
        require_range("reconnect_after_stale_s", self.reconnect_after_stale_s, 0.0, 3600.0)
        require_range("backoff_min_s", self.backoff_min_s, 0.001, 60.0)
        require_range("backoff_max_s", self.backoff_max_s, self.backoff_min_s, 600.0)
        require_range("rx_queue_frames", self.rx_queue_frames, 100, 10_000_000)
        if self.interface in ("socketcand",) and self.host in ("0.0.0.0", "::", ""):
            raise invalid("host", self.host, "a host address such as '127.0.0.1'")
        if self.capacity_rows < 2 * self.fs_hz * self.receive_timeout_s + 16:
            raise invalid("ring_capacity_s", self.ring_capacity_s, "a longer ring (>= 0.1 s)")
        object.__setattr__(self, "options", types.MappingProxyType(dict(self.options)))
        if self.channel == "":
            object.__setattr__(self, "channel", _DEFAULT_CHANNELS.get(self.interface, "can0"))

    @property
    def capacity_rows(self) -> int:
        """Ring buffer capacity in rows."""
        return round(self.ring_capacity_s * self.fs_hz)


@dataclass(frozen=True)
class FaultConfig:
    """``[plant.faults]``: faults the virtual plant injects (probabilities per frame).

    Attributes
    ----------
    drop_rate : float
        Frame not sent (the sample is lost; the counter moves on).
    duplicate_rate : float
        Frame sent twice.
    reorder_rate : float
        Frame swapped with the next one.
    corrupt_rate : float
        One bit of the payload flipped (the checksum rejects it).
    short_rate : float
        Frame truncated to fewer than 8 bytes.
    error_frame_rate : float
        An error frame inserted after the frame.
    unknown_id_rate : float
        A frame with an identifier the robot does not use inserted after the frame.
    silence_every_s, silence_s : float
        Every ``silence_every_s`` seconds (0: never) the plant sends nothing for
        ``silence_s`` seconds; those samples are lost.
    saturate_torque_nm : float
        Torque sensor range (0: only the encoding's range): larger torques are clipped
        and flagged ``TorqueSaturated``.
    seed : int
        Seed of the fault generator.
    """

    drop_rate: float = 0.0
    duplicate_rate: float = 0.0
    reorder_rate: float = 0.0
    corrupt_rate: float = 0.0
    short_rate: float = 0.0
    error_frame_rate: float = 0.0
    unknown_id_rate: float = 0.0
    silence_every_s: float = 0.0
    silence_s: float = 0.0
    saturate_torque_nm: float = 0.0
    seed: int = 7

    def __post_init__(self) -> None:
        for name in (
            "drop_rate",
            "duplicate_rate",
            "reorder_rate",
            "corrupt_rate",
            "short_rate",
            "error_frame_rate",
            "unknown_id_rate",
        ):
            require_range(name, getattr(self, name), 0.0, 0.5)
        require_range("silence_every_s", self.silence_every_s, 0.0)
        require_range("silence_s", self.silence_s, 0.0)
        if self.silence_every_s and self.silence_s >= self.silence_every_s:
            raise invalid("silence_s", self.silence_s, "a value below silence_every_s")
        require_range("saturate_torque_nm", self.saturate_torque_nm, 0.0)

    @property
    def any(self) -> bool:
        """Whether any fault is enabled."""
        rates = (
            self.drop_rate,
            self.duplicate_rate,
            self.reorder_rate,
            self.corrupt_rate,
            self.short_rate,
            self.error_frame_rate,
            self.unknown_id_rate,
        )
        return any(r > 0 for r in rates) or self.silence_every_s > 0


@dataclass(frozen=True)
class StiffnessConfig:
    """``[plant.stiffness]``: the joint's stiffness over time, N·m/rad.

    ``kind`` as in :class:`rtsid.sim.StiffnessProfile`: ``"constant"`` uses
    ``[plant] stiffness``; ``"linear"``/``"hyperbolic"`` go from ``k0`` at ``t0_s`` to
    ``k1`` at ``t1_s``; ``"raised_cosine"`` one cycle ``k0 → k1 → k0`` over ``t0_s..t1_s``;
    ``"sinusoidal"`` is ``k0 + amplitude·sin(2π·freq_hz·t)``. With ``period_s > 0`` the
    profile repeats every ``period_s`` seconds.
    """

    kind: str = "constant"
    k0: float = 150.0
    k1: float = 150.0
    t0_s: float = 0.0
    t1_s: float = 1.0
    amplitude: float = 0.0
    freq_hz: float = 1.0
    period_s: float = 0.0

    def __post_init__(self) -> None:
        require_choice(
            "kind", self.kind, ("constant", "linear", "hyperbolic", "sinusoidal", "raised_cosine")
        )
        if self.kind in ("linear", "hyperbolic", "raised_cosine") and self.t1_s <= self.t0_s:
            raise invalid("t1_s", self.t1_s, f"a time after t0_s = {self.t0_s}")
        if self.kind == "hyperbolic" and min(self.k0, self.k1) <= 0:
            raise invalid("k0", self.k0, "k0 > 0 and k1 > 0 for a hyperbolic profile")
        require_range("period_s", self.period_s, 0.0)


@dataclass(frozen=True)
class ReflexConfig:
    """``[plant.reflex]``: a stretch reflex added to the simulated ankle's torque (off by
    default): ``gain·h ∗ max(θ̇(t − delay_s), 0)`` with ``h`` a second-order low-pass of unit
    static gain (:class:`rtsid.sim.reflex.ReflexParameters`). Only ``mode = "sim"`` uses it.
    """

    enabled: bool = False
    gain: float = 10.0
    delay_s: float = 0.04
    corner_hz: float = 3.0
    damping_ratio: float = 0.7

    def __post_init__(self) -> None:
        require_range("gain", self.gain, 0.0)
        require_range("delay_s", self.delay_s, 0.0, 0.5)
        require_range("corner_hz", self.corner_hz, 0.0, 100.0, low_inclusive=False)
        require_range("damping_ratio", self.damping_ratio, 0.0, 10.0, low_inclusive=False)

    def parameters(self) -> ReflexParameters | None:
        """The simulated reflex, or None when disabled."""
        if not self.enabled:
            return None
        from rtsid.sim.reflex import ReflexParameters

        return ReflexParameters(self.gain, self.delay_s, self.corner_hz, self.damping_ratio)


@dataclass(frozen=True)
class TorqueMultisineConfig:
    """``[plant.torque_multisine]``: a periodic random-phase multisine torque experiment.

    With ``[plant] mode = "torque_multisine"`` the virtual plant applies this torque to the
    joint (admittance: ``I·φ̈ = τ − B·φ̇ − K(t)·φ``). A recording made on a real rig running
    such an experiment declares it here the same way, so that ``rtsid tv REC.mcap`` finds
    the excited bins and the periods (the ``[plant]`` section is otherwise unused then).
    The signal is :func:`rtsid.ident.excitation.multisine` with these arguments.

    Attributes
    ----------
    period_s : float
        Period, s (a whole number of samples at ``[plant] fs_hz``); 0: no multisine declared.
    f_max_hz : float
        Highest excited frequency, Hz.
    f_min_hz : float
        Lowest excited frequency, Hz (0: from the first excited bin).
    every : int
        Excite every ``every``-th bin of the ``1/period_s`` grid (lines ``every/period_s``
        Hz apart; the bins between carry the time variation).
    rms_nm : float
        RMS torque, N·m.
    seed : int
        Seed of the random phases.
    start_index : int
        Sample index at which the first period starts (the plant starts it at 0, its first
        sample). Samples before it are not part of the experiment.
    """

    period_s: float = 0.0
    f_max_hz: float = 20.0
    f_min_hz: float = 0.0
    every: int = 1
    rms_nm: float = 1.0
    seed: int = 1
    start_index: int = 0

    def __post_init__(self) -> None:
        require_range("period_s", self.period_s, 0.0, 600.0)
        require_range("f_max_hz", self.f_max_hz, 0.0, None, low_inclusive=False)
        require_range("f_min_hz", self.f_min_hz, 0.0, self.f_max_hz)
        require_range("every", self.every, 1, 1_000_000)
        require_range("rms_nm", self.rms_nm, 0.0, None, low_inclusive=False)
        require_range("start_index", self.start_index, 0)

    @property
    def declared(self) -> bool:
        """Whether a multisine is declared (``period_s > 0``)."""
        return self.period_s > 0

    def multisine(self, fs_hz: float) -> Multisine:
        """The declared signal at ``fs_hz`` (excited bins, period samples, phases, amplitudes).

        Raises
        ------
        ConfigError
            No multisine declared, or parameters :func:`multisine` refuses (named).
        """
        if not self.declared:
            raise invalid(
                "plant.torque_multisine.period_s", self.period_s, "a period > 0 s (none declared)"
            )
        from rtsid.ident.excitation import multisine

        try:
            return multisine(
                fs_hz,
                self.period_s,
                self.f_max_hz,
                every=self.every,
                f_min_hz=self.f_min_hz or None,
                rms=self.rms_nm,
                seed=self.seed,
            )
        except InputDataError as exc:
            raise ConfigError(f"[plant.torque_multisine]: {exc}") from None


@dataclass(frozen=True)
class PlantConfig:
    """The ``[plant]`` section: the simulated (or replayed) ankle robot.

    Attributes
    ----------
    mode : str
        ``"sim"`` (simulated joint under a position perturbation), ``"player"`` (stream
        ``player_file``) or ``"torque_multisine"`` (the joint driven by the multisine
        torque of ``[plant.torque_multisine]``; perturbation keys and commands are ignored).
    fs_hz : float
        State frames per second (the robot's sample rate).
    realtime : bool
        Pace frames against absolute monotonic deadlines (False: as fast as possible).
    frames_per_tick : int
        Frames sent per pacing tick (4 at 2500 Hz: a tick every 1.6 ms).
    block_s : float
        Length of each generated block of samples, s.
    perturbation : str
        ``"prbs"``, ``"filtered_noise"``, ``"multisine"`` or ``"off"``.
    amplitude_rad : float
        Peak perturbation command, rad.
    bandwidth_hz : float
        PRBS switching rate / 2, noise cut-off, multisine top frequency, Hz.
    multisine_period_s : float
        Multisine period, s (a whole number of samples).
    servo_bandwidth_hz : float
        Position servo bandwidth (critically damped), Hz: smooths the command.
    inertia, damping, stiffness : float
        The ankle's I (kg·m²), B (N·m·s/rad) and constant K (N·m/rad).
    robot_inertia : float
        Footplate/motor inertia between the torque sensor and the foot, kg·m² (its
        ``I_robot·θ̈`` adds to the measured torque; 0: none).
    noise_percent : float
        Torque noise std as % of the clean torque's std.
    position_noise_rad : float
        Encoder noise std, rad.
    seed : int
        Seed of the perturbation and noise.
    player_file : str
        ``.npz`` with ``position_rad``, ``torque_nm``, ``fs_hz`` (player mode).
    player_torque_sign : float
        Multiply the file's torque by this (-1 for a recording with inverted torque).
    player_loop : bool
        Start again at the end of the file (the first sample is flagged Discontinuity).
    diagnostics_hz : float
        Rate of the Diagnostics frame (0: none).
    max_samples : int
        Stop producing after this many samples (0: run until stopped).
    marker_every_s : float
        Step the protocol's trial-marker signal (``[link.protocol] marker``, or a UDP
        ``marker`` field) by one every this many seconds, from 0 (0: never; it stays 0).
    faults : FaultConfig
    stiffness_profile : StiffnessConfig
    torque_multisine : TorqueMultisineConfig
    reflex : ReflexConfig
    """

    mode: str = "sim"
    fs_hz: float = 2500.0
    realtime: bool = True
    frames_per_tick: int = 4
    block_s: float = 0.2
    perturbation: str = "prbs"
    amplitude_rad: float = 0.03
    bandwidth_hz: float = 40.0
    multisine_period_s: float = 1.0
    servo_bandwidth_hz: float = 60.0
    inertia: float = 0.015
    damping: float = 0.8
    stiffness: float = 150.0
    robot_inertia: float = 0.0
    noise_percent: float = 3.0
    position_noise_rad: float = 0.0
    seed: int = 1
    player_file: str = ""
    player_torque_sign: float = 1.0
    player_loop: bool = True
    diagnostics_hz: float = 10.0
    max_samples: int = 0
    marker_every_s: float = 0.0
    faults: FaultConfig = field(default_factory=FaultConfig)
    stiffness_profile: StiffnessConfig = field(default_factory=StiffnessConfig)
    torque_multisine: TorqueMultisineConfig = field(default_factory=TorqueMultisineConfig)
    reflex: ReflexConfig = field(default_factory=ReflexConfig)

    def __post_init__(self) -> None:
        require_choice("mode", self.mode, ("sim", "player", "torque_multisine"))
        require_range("fs_hz", self.fs_hz, 1.0, 200_000.0)
        require_range("frames_per_tick", self.frames_per_tick, 1, 10_000)
        require_range("block_s", self.block_s, 0.01, 10.0)
        if self.block_samples < 16:
            raise invalid("block_s", self.block_s, "a block of at least 16 samples")
        require_choice("perturbation", self.perturbation, PERTURBATION_KINDS)
        require_range("amplitude_rad", self.amplitude_rad, 0.0, 0.65)
        require_range("bandwidth_hz", self.bandwidth_hz, 0.0, self.fs_hz / 2, low_inclusive=False)
        require_range(
            "servo_bandwidth_hz", self.servo_bandwidth_hz, 0.0, self.fs_hz / 2, low_inclusive=False
        )
        require_range(
            "multisine_period_s", self.multisine_period_s, 0.0, 600.0, low_inclusive=False
        )
        for name in (
            "inertia",
            "damping",
            "robot_inertia",
            "noise_percent",
            "position_noise_rad",
            "diagnostics_hz",
        ):
            require_range(name, getattr(self, name), 0.0)
        require_range("max_samples", self.max_samples, 0)
        require_range("marker_every_s", self.marker_every_s, 0.0)
        require_choice("player_torque_sign", self.player_torque_sign, (1.0, -1.0))
        if self.mode == "torque_multisine":
            self._check_torque_multisine()
        if self.mode == "player" and not self.player_file:
            raise invalid(
                "player_file", self.player_file, "the path of an .npz file in player mode"
            )

    def _check_torque_multisine(self) -> None:
        ms = self.torque_multisine
        if not ms.declared:
            raise invalid(
                "torque_multisine.period_s",
                ms.period_s,
                "a period > 0 s in mode 'torque_multisine'",
            )
        n = ms.period_s * self.fs_hz
        if abs(n - round(n)) > 1e-6 * n:
            raise invalid(
                "torque_multisine.period_s",
                ms.period_s,
                f"a whole number of samples at fs_hz = {self.fs_hz}",
            )
        if ms.f_max_hz >= self.fs_hz / 2:
            raise invalid("torque_multisine.f_max_hz", ms.f_max_hz, f"below {self.fs_hz / 2} Hz")
        if self.inertia + self.robot_inertia <= 0:
            raise invalid("inertia", self.inertia, "inertia + robot_inertia > 0 (an admittance)")

    @property
    def block_samples(self) -> int:
        """Samples per generated block."""
        return round(self.block_s * self.fs_hz)


def plant_config_from_mapping(
    mapping: Mapping[str, Any] | None, base_dir: str | Path | None = None
) -> PlantConfig:
    """Build :class:`PlantConfig` from a ``[plant]`` table (with its sub-tables).

    A relative ``player_file`` is taken relative to ``base_dir`` (the config file's folder)
    when given.
    """
    values = dict(mapping or {})
    if "player_file" in values:
        values["player_file"] = from_config_folder(values["player_file"], base_dir)
    subs: dict[str, Any] = {}
    for key, cls, attr in (
        ("faults", FaultConfig, "faults"),
        ("stiffness_profile", StiffnessConfig, "stiffness_profile"),
        ("torque_multisine", TorqueMultisineConfig, "torque_multisine"),
        ("reflex", ReflexConfig, "reflex"),
    ):
        table = values.pop(key, None)
        if table is not None and not isinstance(table, Mapping):
            raise invalid(f"plant.{key}", table, f"a table [plant.{key}]")
        subs[attr] = section_from_mapping(cls, table, f"plant.{key}")
    return section_from_mapping(PlantConfig, {**values, **subs}, "plant")


def link_config_from_mapping(
    mapping: Mapping[str, Any] | None, base_dir: str | Path | None = None
) -> LinkConfig:
    """Build :class:`LinkConfig` from a ``[link]`` table with ``[link.protocol]`` and
    ``[link.udp]``; a relative ``protocol.dbc`` is taken relative to ``base_dir``."""
    if mapping is not None and not isinstance(mapping, Mapping):
        raise ConfigError("config key 'link' must be a table [link]")
    values = dict(mapping or {})
    subs: dict[str, Any] = {}
    for key, cls in (("protocol", ProtocolConfig), ("udp", UdpConfig)):
        table = values.pop(key, None)
        if table is not None and not isinstance(table, Mapping):
            raise invalid(f"link.{key}", table, f"a table [link.{key}]")
        table = dict(table or {})
        if key == "protocol" and "dbc" in table:
            table["dbc"] = from_config_folder(table["dbc"], base_dir)
        subs[key] = section_from_mapping(cls, table, f"link.{key}")
    return section_from_mapping(LinkConfig, {**values, **subs}, "link")


def link_configs_from_mapping(
    document: Mapping[str, Any], base_dir: str | Path | None = None
) -> tuple[LinkConfig, PlantConfig]:
    """``[link]`` and ``[plant]`` of a parsed TOML document (other sections are ignored).

    ``base_dir``: folder that relative paths (``plant.player_file``) are relative to.
    """
    link = link_config_from_mapping(document.get("link"), base_dir)
    plant = plant_config_from_mapping(document.get("plant"), base_dir)
    embedded = link.interface == "embedded" or (link.interface == "udp" and link.udp.embedded_plant)
    if embedded and link.fs_hz != plant.fs_hz:
        raise invalid("plant.fs_hz", plant.fs_hz, f"link.fs_hz = {link.fs_hz} (the same rate)")
    return link, plant


def load_link_configs(path: str | Path) -> tuple[LinkConfig, PlantConfig]:
    """Read ``[link]`` and ``[plant]`` from a TOML file."""
    return link_configs_from_mapping(load_toml(path), Path(path).resolve().parent)
