"""The UDP source: the plant's datagrams on 127.0.0.1 into the one acquisition path."""

from __future__ import annotations

import dataclasses
import socket
import struct
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtsid.errors import ConfigError, LinkError
from rtsid.link.acquisition import Acquisition
from rtsid.link.config import FaultConfig, UdpConfig, link_configs_from_mapping, load_link_configs
from rtsid.link.open import open_link
from rtsid.link.protocol import Command
from rtsid.link.ring import RingBuffer
from rtsid.link.udp import UdpReceiver, UdpSender, compile_layout

UDP_TOML = Path(__file__).resolve().parents[2] / "hw" / "configs" / "udp-plant.toml"
WAIT_S = 30.0  # bound of loops waiting on threads; tests never assert on time


def wait_for(predicate, timeout=WAIT_S):
    deadline = time.monotonic() + timeout
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.005)
    return predicate()


def udp_link(**plant_overrides):
    """The shipped UDP config on a free loopback port, the plant bounded."""
    link, plant = load_link_configs(UDP_TOML)
    link = dataclasses.replace(link, udp=dataclasses.replace(link.udp, port=0))
    bounded = {"max_samples": 10_000, "marker_every_s": 1.0, **plant_overrides}
    return link, dataclasses.replace(plant, **bounded)


def stream(link, plant_cfg):
    """Run the embedded UDP plant into the acquisition; return the stopped parts."""
    with open_link(link, plant_cfg, start_plant=False) as handle:
        ring = handle.make_ring()
        with handle.make_acquisition(ring) as acq:
            assert handle.plant is not None
            handle.plant.start()
            assert handle.plant.done.wait(WAIT_S) and handle.plant.error is None
            sent = handle.plant.counters().frames_sent
            wait_for(lambda: acq.counters().frames >= sent)
        return acq, handle.plant, ring


def test_udp_datagrams_arrive_exactly_with_markers():
    link, plant_cfg = udp_link()
    acq, plant, ring = stream(link, plant_cfg)
    c, p = acq.counters(), plant.counters()
    assert p.frames_sent == 1000 and c.frames == 1000
    assert c.samples == 10_000 and c.lost_samples == c.malformed == c.duplicates == 0
    snap = ring.read_since(0, 10_000)
    assert snap.sample_index.tolist() == list(range(10_000)) and snap.valid.all()
    assert [(m.sample_index, m.label) for m in acq.drain_markers()] == [
        (2500, "marker=1"),
        (5000, "marker=2"),
        (7500, "marker=3"),
    ]
    assert np.std(snap.position_rad) > 0.005 and np.std(snap.torque_nm) > 0.5


def test_lost_duplicated_and_reordered_datagrams_are_counted_exactly():
    # 1000 datagrams at 2 % of each fault: about as many faults as 2000 at 1 % (seed 11: 18
    # datagrams dropped, 11 duplicated, 18 reordered against 10, 20, 18) in half the real time
    faults = FaultConfig(drop_rate=0.02, duplicate_rate=0.02, reorder_rate=0.02, seed=11)
    link, plant_cfg = udp_link(faults=faults, max_samples=10_000)
    acq, plant, ring = stream(link, plant_cfg)
    c, p = acq.counters(), plant.counters()
    snap = ring.read_since(0, 50_000)
    first, last = int(snap.sample_index[0]), int(snap.sample_index[-1])
    expected_lost = [k for k in plant.lost_indices().tolist() if first < k < last]
    assert snap.sample_index[~snap.valid].tolist() == expected_lost
    assert c.lost_samples == len(expected_lost) and p.dropped - 20 <= c.lost_samples <= p.dropped
    assert p.dropped > 0 and p.dropped % 10 == 0  # whole datagrams
    assert c.duplicates == p.duplicated > 0
    assert p.reordered > 0 and c.out_of_order == 0  # a late datagram fills its hole
    assert c.samples + c.lost_samples == last - first + 1 and c.malformed == 0


def test_a_udp_window_identifies_the_true_joint():
    import rtsid

    link, plant_cfg = udp_link(marker_every_s=0.0)
    _, plant, ring = stream(link, plant_cfg)
    truth = plant.truth
    assert truth is not None
    estimates = []
    for end in (4000, 7000, 9999):
        snap = ring.read_since(end - 749, 750)
        assert snap.valid.all() and len(snap) == 750
        est = rtsid.estimate_window(snap.position_rad, snap.torque_nm, 2500.0)
        estimates.append((est.I, est.B, est.K))
    inertia, damping, stiffness = np.median(np.array(estimates), axis=0)
    assert stiffness == pytest.approx(float(truth.stiffness_at(0.0)), rel=0.05)
    assert damping == pytest.approx(truth.damping, rel=0.10)
    assert inertia == pytest.approx(truth.inertia + truth.robot_inertia, rel=0.20)


def test_bad_datagrams_are_counted_as_malformed_and_the_stream_goes_on():
    layout = compile_layout(UdpConfig(samples_per_datagram=2))
    receiver = UdpReceiver("127.0.0.1", 0, layout.datagram_bytes)
    sender = UdpSender("127.0.0.1", receiver.port)
    ring = RingBuffer(1000)
    try:
        with Acquisition(receiver, ring, protocol=layout) as acq:
            good = [struct.pack("<IiiiIiii", 2 * k, 1, 2, 0, 2 * k + 1, 3, 4, 0) for k in range(23)]
            sender.send_frames([good[0], good[1], b"", b"\x00" * 7, good[2] + b"x"])
            sender.send_frames(good[3:])  # enough after the hole to confirm it (16 samples)
            assert wait_for(lambda: acq.counters().frames == 25)
            with pytest.raises(LinkError, match="no perturbation command"):
                acq.send_command(Command())
    finally:
        sender.close()
        receiver.shutdown()
    c = acq.counters()
    assert c.malformed == 3 and c.samples == 44 and c.lost_samples == 2  # datagram 2 was bad
    assert ring.read_since(0, 100).position_rad[:2].tolist() == [1e-6, 3e-6]


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=200), st.sampled_from(["little", "big"]))
def test_the_datagram_decoder_never_raises(data, order):
    cfg = UdpConfig(
        byte_order=order,
        sample_format="Hfdbi",
        fields=("counter", "position", "torque", "status", "marker"),
        samples_per_datagram=3,
    )
    decoder = compile_layout(cfg).decoder()
    out = decoder.decode(data)
    if len(data) != compile_layout(cfg).datagram_bytes:
        assert out is None
    else:
        assert out is None or len(out) == 3


@pytest.mark.parametrize(
    ("udp", "pattern"),
    [
        ({"sample_format": "Iii"}, "3 codes but fields names 4"),
        ({"sample_format": "Iiis"}, "code 's' is not accepted"),
        ({"fields": ["position", "torque", "status", "_"]}, "no 'counter'"),
        ({"sample_format": "iiii"}, "counter's code 'i' is not an unsigned"),
        ({"fields": ["counter", "position", "torque", "torque"]}, "names a field twice"),
        ({"fields": ["counter", "position", "torque", "speed"]}, "link.udp.fields"),
        ({"byte_order": "middle"}, "link.udp.byte_order"),
        ({"samples_per_datagram": 0}, "link.udp.samples_per_datagram"),
    ],
)
def test_udp_layout_errors_are_one_line(udp, pattern):
    with pytest.raises(ConfigError) as exc:
        link_configs_from_mapping({"link": {"interface": "udp", "udp": udp}})
    assert pattern in str(exc.value) and "\n" not in str(exc.value)


def test_a_port_in_use_is_one_clear_link_error():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as holder:
        holder.bind(("127.0.0.1", 0))
        port = holder.getsockname()[1]
        link, _ = load_link_configs(UDP_TOML)
        link = dataclasses.replace(
            link, udp=dataclasses.replace(link.udp, port=port, embedded_plant=False)
        )
        with open_link(link) as handle:
            acq = handle.make_acquisition(RingBuffer(1000))
            with pytest.raises(LinkError, match=f"127.0.0.1:{port}.*bind_host/port"):
                acq.start()


def test_random_datagrams_never_end_the_thread():
    layout = compile_layout(UdpConfig(samples_per_datagram=2))
    receiver = UdpReceiver("127.0.0.1", 0, layout.datagram_bytes)
    sender = UdpSender("127.0.0.1", receiver.port)
    rng = np.random.default_rng(4)
    junk = [rng.bytes(int(n)) for n in rng.integers(0, 100, 300)]
    wrong_length = sum(len(d) != layout.datagram_bytes for d in junk)
    ring = RingBuffer(100_000)
    try:
        with Acquisition(receiver, ring, protocol=layout) as acq:
            for k in range(0, len(junk), 50):  # paced: loopback drops what overflows
                sender.send_frames(junk[k : k + 50])
                wait_for(lambda k=k: acq.counters().frames >= k + 50)
            assert acq.counters().frames == len(junk)
            assert acq.failure is None and acq.running
    finally:
        sender.close()
        receiver.shutdown()
    assert acq.counters().malformed == wrong_length > 250
