"""[link.protocol]: a mapping from any DBC's signals to samples, and the second protocol
(two big-endian frames, no counter, 2 kHz) end to end through the virtual plant."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtsid.errors import ConfigError
from rtsid.link.acquisition import Acquisition, explain_link_state, index_from_time
from rtsid.link.config import (
    FaultConfig,
    LinkConfig,
    PlantConfig,
    ProtocolConfig,
    link_configs_from_mapping,
    load_link_configs,
)
from rtsid.link.mapping import (
    ANKLE_MAPPING,
    AnkleDecoder,
    StateDecoder,
    builtin_protocol,
    compile_protocol,
    protocol_from_config,
)
from rtsid.link.open import link_protocol, open_link
from rtsid.link.plant import VirtualPlant
from rtsid.link.protocol import (
    STATUS_PERTURBATION_ON,
    Command,
    decode_state,
    encode_state_block,
)
from rtsid.link.ring import RingBuffer

HW = Path(__file__).resolve().parents[2] / "hw"
TWOFRAME_DBC = str(HW / "protocols" / "twoframe.dbc")
TWOFRAME_TOML = HW / "configs" / "twoframe-plant.toml"
WAIT_S = 30.0  # bound of loops waiting on threads; tests never assert on time

TWOFRAME = {
    "dbc": TWOFRAME_DBC,
    "position": "JointPosition.Position",
    "torque": "JointTorque.Torque",
    "counter": "",
    "position_saturated": "JointPosition.PositionSaturated",
    "torque_saturated": "JointTorque.TorqueSaturated",
    "perturbation_on": "JointPosition.PerturbationOn",
    "discontinuity": "JointPosition.Discontinuity",
    "marker": "JointPosition.TrialMarker",
    "command": "PerturbationCommand",
    "diagnostics": "",
    "checksum": "none",
}

NARROW_DBC = """VERSION ""
NS_ :
BS_:
BU_: Robot
BO_ 256 State: 8 Robot
 SG_ Position : 0|24@1- (1E-006,0) [-8|8] "rad" Robot
 SG_ Torque : 24|20@1- (0.001,0) [-524|524] "N.m" Robot
 SG_ Counter : 44|4@1+ (1,0) [0|15] "" Robot
 SG_ Angle : 48|16@1- (0.01,0) [-300|300] "furlong" Robot
"""


def one_line_naming(exc: pytest.ExceptionInfo[ConfigError], *names: str) -> None:
    text = str(exc.value)
    assert "\n" not in text
    for name in names:
        assert name in text, (name, text)


@pytest.mark.parametrize(
    ("overrides", "names"),
    [
        ({"position": "AnkleStat.Position"}, ("ankle.dbc", "AnkleStat", "Position")),
        ({"torque": "AnkleState.Torq"}, ("ankle.dbc", "AnkleState", "Torq")),
        ({"position": "Diagnostics.Uptime"}, ("ankle.dbc", "Diagnostics", "Uptime", "multiplex")),
        ({"torque": "AnkleState.Counter"}, ("ankle.dbc", "AnkleState", "Counter", "unit")),
        (
            {"position": "AnkleState.PositionSaturated"},
            ("AnkleState", "PositionSaturated", "narrow"),
        ),
        ({"position": "Position"}, ("ankle.dbc", "Message.Signal")),
        ({"command": "Nothing"}, ("ankle.dbc", "Nothing")),
    ],
)
def test_a_bad_mapping_of_the_builtin_dbc_is_one_line_naming_dbc_message_and_signal(
    overrides, names
):
    with pytest.raises(ConfigError) as exc:
        link_configs_from_mapping({"link": {"protocol": overrides}})
    one_line_naming(exc, *names)


def test_an_optional_key_left_out_of_another_dbcs_mapping_says_how_to_leave_it_out():
    """A key left out takes the ankle DBC's name; the fix names the key and its "" (found
    by a new user following docs/getting-started.md with the two-frame DBC)."""
    mapping = {k: v for k, v in TWOFRAME.items() if k != "position_saturated"}
    with pytest.raises(ConfigError) as exc:
        ProtocolConfig(**mapping)
    one_line_naming(exc, "twoframe.dbc", "AnkleState", 'link.protocol.position_saturated = ""')
    with pytest.raises(ConfigError) as exc:
        ProtocolConfig(**{**TWOFRAME, "marker": "JointPosition.Trial"})
    one_line_naming(exc, "JointPosition", "'Trial'", 'link.protocol.marker = "" to leave it out')
    with pytest.raises(ConfigError) as exc:  # a required key has no such way out
        ProtocolConfig(**{**TWOFRAME, "torque": "JointTorque.Torq"})
    one_line_naming(exc, "JointTorque", "'Torq'", "use one of Torque, TorqueSaturated")
    assert "leave it out" not in str(exc.value)


def test_a_counter_too_narrow_and_a_unit_rad_cannot_hold_are_named(tmp_path):
    dbc = tmp_path / "narrow.dbc"
    dbc.write_text(NARROW_DBC)
    base = {"dbc": "narrow.dbc", "position": "State.Position", "torque": "State.Torque"}
    bare = {"position_saturated": "", "torque_saturated": "", "perturbation_on": ""}
    bare |= {"discontinuity": "", "command": "", "diagnostics": ""}
    document = {"link": {"protocol": {**base, **bare, "counter": "State.Counter"}}}
    with pytest.raises(ConfigError) as exc:
        link_configs_from_mapping(document, tmp_path)
    one_line_naming(exc, "narrow.dbc", "State", "Counter", "4 bits", "too narrow")
    document["link"]["protocol"] |= {"counter": "", "position": "State.Angle"}
    with pytest.raises(ConfigError) as exc:
        link_configs_from_mapping(document, tmp_path)
    one_line_naming(exc, "narrow.dbc", "State", "Angle", "furlong")
    document["link"]["protocol"]["position"] = "State.Position"
    link, _ = link_configs_from_mapping(document, tmp_path)  # now a valid mapping
    assert protocol_from_config(link.protocol).uses_timestamps


def test_pairing_two_frames_by_counter_needs_the_counter_in_both_messages():
    with pytest.raises(ConfigError) as exc:
        ProtocolConfig(**{**TWOFRAME, "counter": "JointPosition.TrialMarker"})
    one_line_naming(exc, "twoframe.dbc", "JointTorque", "TrialMarker")


def test_a_missing_dbc_and_a_checksum_the_frames_cannot_carry_are_config_errors(tmp_path):
    with pytest.raises(ConfigError) as exc:
        link_configs_from_mapping({"link": {"protocol": {"dbc": "none.dbc"}}}, tmp_path)
    one_line_naming(exc, "none.dbc", "link.protocol.dbc")
    with pytest.raises(ConfigError) as exc:
        ProtocolConfig(**{**TWOFRAME, "checksum": "nibble_xor"})
    one_line_naming(exc, "twoframe.dbc", "JointPosition", "6 bytes")


def test_the_default_mapping_is_the_builtin_protocol_with_its_fast_decoder():
    protocol = protocol_from_config(ProtocolConfig())
    assert protocol.builtin and isinstance(protocol.decoder(), AnkleDecoder)
    assert protocol.counter_modulo == 4096 and protocol.frames_per_sample == 1
    assert {k: getattr(ProtocolConfig(), k) for k in ANKLE_MAPPING} == ANKLE_MAPPING
    flipped = protocol_from_config(ProtocolConfig(torque_sign=-1.0))
    assert not flipped.builtin and isinstance(flipped.decoder(), StateDecoder)


def _generic_ankle() -> StateDecoder:
    """The built-in mapping decoded by cantools (the same mapping, not flagged built in)."""
    status = tuple(
        (name, ANKLE_MAPPING[name])
        for name in ("position_saturated", "torque_saturated", "perturbation_on", "discontinuity")
    )
    protocol = compile_protocol(
        "", status=status, command="PerturbationCommand", checksum="nibble_xor"
    )
    assert not protocol.builtin
    return StateDecoder(protocol)


@settings(max_examples=300, deadline=None)
@given(
    st.integers(-(1 << 23), (1 << 23) - 1),
    st.integers(-(1 << 19), (1 << 19) - 1),
    st.integers(0, 4095),
    st.integers(0, 15),
    st.binary(min_size=8, max_size=8),
)
def test_the_fast_builtin_decoder_equals_the_cantools_mapping(pos, trq, ctr, status, noise):
    fast, generic = AnkleDecoder(), _generic_ankle()
    payload = encode_state_block(
        np.array([pos]), np.array([trq]), np.array([ctr]), np.array([status])
    )[0].tobytes()
    assert fast.decode(0x100, payload, 1.0) == generic.decode(0x100, payload, 1.0)
    assert fast.decode(0x100, noise, 1.0) == generic.decode(0x100, noise, 1.0)  # checksum too
    for data in (payload, noise):  # the inlined arithmetic is decode_state's
        raw = decode_state(data)
        decoded = fast.decode(0x100, data, 1.0)
        assert (decoded is None) == (raw is None)
        if raw is not None:
            assert decoded == (raw[2], raw[0] * 1e-6, raw[1] * 1e-3, raw[3], None)


def run_twoframe(
    channel: str,
    cfg: PlantConfig,
    *,
    fs_hz: float = 2000.0,
    record: int = 0,
    link: LinkConfig | None = None,
) -> tuple[Acquisition, VirtualPlant, RingBuffer]:
    """Stream ``cfg.max_samples`` of the second protocol (or of ``link``'s mapping of it)
    through a virtual bus."""
    link = link or load_link_configs(TWOFRAME_TOML)[0]
    wire = link_protocol(link)
    ring = RingBuffer(50_000)
    acq = Acquisition(
        lambda: can.Bus(interface="virtual", channel=channel, rx_queue_size=60_000),
        ring,
        fs_hz=fs_hz,
        protocol=wire,
    )
    plant_bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    try:
        with acq, VirtualPlant(cfg, plant_bus, wire=wire, record_samples=record) as plant:
            assert plant.done.wait(WAIT_S) and plant.error is None
            sent = plant.counters().frames_sent
            deadline = time.monotonic() + WAIT_S
            while acq.counters().frames < sent and time.monotonic() < deadline:
                time.sleep(0.01)
    finally:
        plant_bus.shutdown()
    return acq, plant, ring


def twoframe_plant(**kwargs: object) -> PlantConfig:
    _, plant = load_link_configs(TWOFRAME_TOML)
    fast = {"realtime": False, "max_samples": 12_000, "block_s": 0.1, "marker_every_s": 1.0}
    return dataclasses.replace(plant, **{**fast, **kwargs})  # type: ignore[arg-type]


def test_the_second_protocol_arrives_exactly_with_its_markers(channel):
    cfg = twoframe_plant()
    acq, plant, ring = run_twoframe(channel, cfg, record=cfg.max_samples)
    c = acq.counters()
    assert c.samples == cfg.max_samples and c.lost_samples == c.unpaired == c.malformed == 0
    snap = ring.read_since(0, cfg.max_samples)
    assert snap.sample_index.tolist() == list(range(cfg.max_samples)) and snap.valid.all()
    position, torque = plant.recorded()
    assert np.array_equal(snap.position_rad, position)  # deg and mN·m converted exactly
    assert np.array_equal(snap.torque_nm, torque)
    assert np.std(position) > 0.005 and np.std(torque) > 0.5
    assert np.all(snap.status & STATUS_PERTURBATION_ON)
    markers = acq.drain_markers()
    assert [(m.sample_index, m.label) for m in markers] == [
        (k * 2000, f"TrialMarker={k}") for k in range(1, 6)
    ]
    assert c.measured_rate_hz == pytest.approx(2000.0) and not c.rate_mismatch


def test_the_second_protocol_counts_injected_faults_exactly_and_invents_nothing(channel):
    faults = FaultConfig(drop_rate=0.01, duplicate_rate=0.01, reorder_rate=0.01, seed=5)
    acq, plant, ring = run_twoframe(channel, twoframe_plant(faults=faults))
    c, p = acq.counters(), plant.counters()
    snap = ring.read_since(0, 50_000)
    first, last = int(snap.sample_index[0]), int(snap.sample_index[-1])
    expected_lost = [k for k in plant.lost_indices().tolist() if first < k < last]
    assert snap.sample_index[~snap.valid].tolist() == expected_lost
    assert c.lost_samples == len(expected_lost) and p.dropped - 2 <= len(expected_lost) <= p.dropped
    assert c.duplicates == p.duplicated > 50
    assert p.reordered > 50 and c.out_of_order == 0  # reordered pairs fill their hole
    assert c.samples + c.lost_samples == last - first + 1
    assert c.unpaired == c.malformed == 0


def test_a_short_frame_loses_its_sample_and_leaves_its_partner_unpaired(channel):
    faults = FaultConfig(short_rate=0.01, seed=2)
    acq, plant, ring = run_twoframe(channel, twoframe_plant(faults=faults))
    c, p = acq.counters(), plant.counters()
    assert c.malformed == p.shortened == c.unpaired > 50
    snap = ring.read_since(0, 50_000)
    assert snap.sample_index[~snap.valid].tolist() == plant.lost_indices().tolist()


def test_a_sender_at_another_rate_than_fs_hz_is_reported(channel):
    acq, _, _ = run_twoframe(channel, twoframe_plant(max_samples=10_000), fs_hz=2500.0)
    c = acq.counters()
    assert c.rate_mismatch and c.measured_rate_hz == pytest.approx(2000.0)
    assert "2000.0 samples/s" in c.last_error and "link.fs_hz" in c.last_error
    said = explain_link_state({**dataclasses.asdict(c), "link_state": "streaming"}, "the plant")
    assert said is not None and "2000.0 samples/s" in said and "link.fs_hz" in said


def test_timestamp_index_rule_gap_after_more_than_one_and_a_half_periods():
    fs = 2000.0
    assert index_from_time(10.0 + 1.0 / fs, 7, 10.0, fs) == 8
    assert index_from_time(10.0 + 1.49 / fs, 7, 10.0, fs) == 8  # jitter: still the next
    assert index_from_time(10.0 + 1.51 / fs, 7, 10.0, fs) == 9  # one lost
    assert index_from_time(10.0 + 0.49 / fs, 7, 10.0, fs) == 7  # the newest again
    assert index_from_time(10.0 - 1.0 / fs, 7, 10.0, fs) == 6  # late


def test_a_timestamp_only_gap_writes_invalid_rows_and_nothing_interpolated(channel):
    """Frames sent by hand: times 0..99 periods, then a jump of 5 periods (4 lost)."""
    wire = link_protocol(load_link_configs(TWOFRAME_TOML)[0])
    fs = 2000.0
    k = np.r_[np.arange(100), np.arange(104, 150)]
    groups = wire.encode_samples(
        k, 1000 * k, -1000 * k, np.zeros(k.size, dtype=np.int64), wall0_s=5000.0, fs_hz=fs
    )
    ring = RingBuffer(1000)
    with (
        can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as tx,
        Acquisition(
            lambda: can.Bus(interface="virtual", channel=channel), ring, fs_hz=fs, protocol=wire
        ) as acq,
    ):
        for group in groups:
            for frame in group:
                tx.send(frame)
        deadline = time.monotonic() + WAIT_S
        while acq.counters().frames < 2 * k.size and time.monotonic() < deadline:
            time.sleep(0.005)
        for frame in groups[10]:  # a pair sent again: the same time, a duplicate
            tx.send(frame)
        while acq.counters().duplicates < 1 and time.monotonic() < deadline:
            time.sleep(0.005)
    c = acq.counters()
    assert c.gaps == 1 and c.lost_samples == 4 and c.samples == k.size and c.duplicates == 1
    snap = ring.read_since(0, 1000)
    assert snap.sample_index[~snap.valid].tolist() == [100, 101, 102, 103]
    assert np.array_equal(snap.sample_index[snap.valid], k)
    expected = wire.to_si(1000 * k, -1000 * k)
    assert np.array_equal(snap.position_rad[snap.valid], expected[0])


def test_a_command_through_the_second_protocol_reaches_the_plant(channel):
    link, _ = load_link_configs(TWOFRAME_TOML)
    wire = link_protocol(link)
    cfg = twoframe_plant(max_samples=0, block_s=0.05)
    ring = RingBuffer(20_000)
    plant_bus = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    try:
        with Acquisition(
            lambda: can.Bus(interface="virtual", channel=channel, rx_queue_size=10_000),
            ring,
            fs_hz=2000.0,
            protocol=wire,
        ) as acq:
            with VirtualPlant(cfg, plant_bus, wire=wire) as plant:
                deadline = time.monotonic() + WAIT_S
                while ring.newest_index < 1000 and time.monotonic() < deadline:
                    time.sleep(0.005)
                acq.send_command(Command(enable=False, kind="off", amplitude_rad=0.0))
                while plant.counters().commands < 1 and time.monotonic() < deadline:
                    time.sleep(0.005)
    finally:
        plant_bus.shutdown()
    assert plant.counters().commands == 1


def test_windows_of_the_second_protocol_identify_the_true_joint(channel):
    import rtsid

    _, plant, ring = run_twoframe(channel, twoframe_plant(marker_every_s=0.0))
    truth = plant.truth
    assert truth is not None
    estimates = []
    for end in (4000, 8000, 11_999):
        snap = ring.read_since(end - 599, 600)  # 300 ms at 2 kHz
        assert snap.valid.all() and len(snap) == 600
        est = rtsid.estimate_window(snap.position_rad, snap.torque_nm, 2000.0)
        estimates.append((est.I, est.B, est.K))
    inertia, damping, stiffness = np.median(np.array(estimates), axis=0)
    assert stiffness == pytest.approx(float(truth.stiffness_at(0.0)), rel=0.05)
    assert damping == pytest.approx(truth.damping, rel=0.10)
    assert inertia == pytest.approx(truth.inertia + truth.robot_inertia, rel=0.20)


def test_the_shipped_configs_compile_their_protocols():
    link, plant = load_link_configs(TWOFRAME_TOML)
    wire = link_protocol(link)
    assert wire.uses_timestamps and wire.frames_per_sample == 2 and not wire.builtin
    assert plant.fs_hz == link.fs_hz == 2000.0
    assert builtin_protocol().builtin


def test_the_packaged_twoframe_dbc_is_the_one_in_hw():
    from importlib import resources

    packaged = resources.files("rtsid.link").joinpath("twoframe.dbc").read_bytes()
    assert (HW / "protocols" / "twoframe.dbc").read_bytes() == packaged


COUNTED_DBC = """VERSION ""
NS_ :
BS_:
BU_: Robot
BO_ 400 Pos: 8 Robot
 SG_ Seq : 7|16@0+ (1,0) [0|65535] "" Robot
 SG_ Angle : 23|32@0- (1E-006,0) [-2147|2147] "mrad" Robot
BO_ 401 Trq: 8 Robot
 SG_ Seq : 7|16@0+ (1,0) [0|65535] "" Robot
 SG_ Torque : 23|32@0- (0.001,0) [-2147483|2147483] "N*m" Robot
"""


def test_two_frames_paired_by_a_counter_count_injected_faults_exactly(channel, tmp_path):
    """Position and torque in two big-endian messages, each with the 16-bit counter."""
    (tmp_path / "counted.dbc").write_text(COUNTED_DBC)
    mapping = {
        "dbc": "counted.dbc",
        "position": "Pos.Angle",
        "torque": "Trq.Torque",
        "torque_sign": -1.0,
        "counter": "Pos.Seq",
        "position_saturated": "",
        "torque_saturated": "",
        "perturbation_on": "",
        "discontinuity": "",
        "command": "",
        "diagnostics": "",
        "checksum": "none",
    }
    document = {"link": {"fs_hz": 2000.0, "protocol": mapping}, "plant": {"fs_hz": 2000.0}}
    link, _ = link_configs_from_mapping(document, tmp_path)
    wire = link_protocol(link)
    assert wire.counter_modulo == 1 << 16 and wire.frames_per_sample == 2
    faults = FaultConfig(drop_rate=0.01, duplicate_rate=0.01, reorder_rate=0.01, seed=9)
    cfg = twoframe_plant(faults=faults, marker_every_s=0.0)
    acq, plant, ring = run_twoframe(channel, cfg, record=12_000, link=link)
    c, p = acq.counters(), plant.counters()
    snap = ring.read_since(0, 50_000)
    first, last = int(snap.sample_index[0]), int(snap.sample_index[-1])
    expected_lost = [k for k in plant.lost_indices().tolist() if first < k < last]
    assert snap.sample_index[~snap.valid].tolist() == expected_lost and len(expected_lost) > 50
    assert c.lost_samples == len(expected_lost) and c.duplicates == p.duplicated > 50
    assert c.out_of_order == c.unpaired == c.malformed == 0
    position, torque = plant.recorded()
    rows = snap.sample_index[snap.valid]
    assert np.array_equal(snap.position_rad[snap.valid], position[rows])  # mrad -> rad
    assert np.array_equal(snap.torque_nm[snap.valid], torque[rows])  # sign -1 both ways
    assert np.std(position) > 0.005 and np.std(torque) > 0.5
    raw = wire.torque.quantise(torque[:100])[0]  # on the wire the torque is inverted
    assert np.all(np.sign(raw) == -np.sign(np.rint(torque[:100] / 1e-3)))


def test_rtsid_plant_speaks_the_second_protocol_over_socketcand():
    """`rtsid plant --config twoframe-plant.toml`: the frames keep the plant's time stamps."""
    import selectors
    import signal
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "rtsid.cli", "plant", "--port", "0", "--config"]
    proc = subprocess.Popen(
        [*cmd, str(TWOFRAME_TOML)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        with selectors.DefaultSelector() as sel:
            sel.register(proc.stdout, selectors.EVENT_READ)
            banner = proc.stdout.readline() if sel.select(30.0) else ""  # type: ignore[union-attr]
        assert "127.0.0.1:" in banner and "2000 Hz" in banner, banner
        port = int(banner.split("127.0.0.1:")[1].split()[0])
        link, _ = load_link_configs(TWOFRAME_TOML)
        link = dataclasses.replace(link, interface="socketcand", port=port, channel="can0")
        with open_link(link) as handle:
            ring = handle.make_ring()
            with handle.make_acquisition(ring) as acq:
                deadline = time.monotonic() + WAIT_S
                while acq.counters().samples < 4000 and time.monotonic() < deadline:
                    time.sleep(0.01)
                acq.send_command(Command(enable=False))
                while (
                    ring.latest(10).status[-1] & STATUS_PERTURBATION_ON
                    and time.monotonic() < deadline
                ):
                    time.sleep(0.01)
                assert not ring.latest(10).status[-1] & STATUS_PERTURBATION_ON
                c = acq.counters()
        assert c.samples >= 4000 and c.lost_samples == c.unpaired == c.malformed == 0
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=20)
        assert proc.returncode == 0
        report = json.loads(out.strip().splitlines()[-1])
        assert report["plant"]["commands"] == 1  # encoded and decoded by cantools
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)


@pytest.mark.parametrize(
    ("link", "pattern"),
    [
        ({"protocol": {"postion": "AnkleState.Position"}}, "unknown config key link.protocol"),
        ({"protocol": 5}, "link.protocol"),
        ({"protocol": {"torque_sign": 2.0}}, "link.protocol.torque_sign"),
        ({"protocol": {"marker_on": "rising"}}, "link.protocol.marker_on"),
        ({"rate_tolerance_percent": -1.0}, "link.rate_tolerance_percent"),
    ],
)
def test_protocol_keys_are_checked_like_every_section(link, pattern):
    with pytest.raises(ConfigError) as exc:
        link_configs_from_mapping({"link": link})
    assert pattern in str(exc.value) and "\n" not in str(exc.value)
