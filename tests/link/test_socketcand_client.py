"""rtsid's socketcand client: python-can's frames and handshake, read in batches.

The same bytes through python-can's client (a ``can.Message`` per frame, the acquisition
before issue 22) and through rtsid's (batches, compiled or numpy-only) must give the same
ring rows and the same counters, faults included.
"""

from __future__ import annotations

import socket
import threading
import time

import can
import numpy as np
import pytest
from can.interfaces.socketcand.socketcand import convert_ascii_message_to_can_message

from rtsid.benchmarks.link import _read_stream
from rtsid.errors import LinkError
from rtsid.ident.levinson import compiled_kernel
from rtsid.link.acquisition import Acquisition
from rtsid.link.mapping import AnkleDecoder
from rtsid.link.protocol import POSITION_SCALE_RAD, TORQUE_SCALE_NM
from rtsid.link.ring import RingBuffer
from rtsid.link.socketcand import (
    SocketcandBus,
    SocketcandServer,
    format_send,
    parse_records,
    parse_send,
    record_message,
)

LINES = [
    "< frame 100 1764000000.000400 B80B008813803E50 >",
    "< frame 1ABCDEF0 12.5 0102 >",  # extended, short, a timestamp without six digits
    "< frame 7ff 0.000001  >",  # lower-case identifier, no data
    "< error 040 1764000000.250000 >",
]


@pytest.mark.parametrize("line", LINES)
def test_records_become_the_messages_python_cans_client_builds(line):
    records, used, other = parse_records(line.encode())
    assert used == len(line) and other == 0 and len(records) == 1
    ours, theirs = record_message(records[0], "can0"), convert_ascii_message_to_can_message(line)
    theirs.channel = "can0"
    for attr in ("timestamp", "arbitration_id", "is_extended_id", "is_error_frame", "dlc"):
        assert getattr(ours, attr) == getattr(theirs, attr), attr
    assert bytes(ours.data) == bytes(theirs.data)


def test_parse_keeps_an_unfinished_record_and_skips_other_records():
    data = b"< ok >< frame 100 1.000000 00 >< echo >< frame 100 2.0000"
    records, used, other = parse_records(data)
    assert [r[2] for r in records] == [b"1.000000"] and other == 2
    assert data[used:] == b"< frame 100 2.0000"
    assert parse_records(b"no record")[:2] == ([], 0)


def test_send_commands_use_python_cans_format_and_the_server_reads_them():
    msg = can.Message(arbitration_id=0x200, data=[1, 0xF1, 0], is_extended_id=False)
    assert format_send(msg) == "< send 200 3 1 f1 0 >"
    back = parse_send(format_send(msg))
    assert back is not None and bytes(back.data) == bytes(msg.data)


def python_reference(chunk: bytes) -> tuple[list, list, list, list, list] | None:
    """The numpy-only path's decoding of a chunk of built-in state frames."""
    records, _, other = parse_records(chunk)
    if other:
        return None
    decoded = AnkleDecoder.decode_words(
        [int.from_bytes(bytes.fromhex(r[3].decode()), "little") for r in records]
    )
    if decoded is None:
        return None
    return (*decoded, [float(r[2]) for r in records])


@pytest.mark.skipif(not hasattr(compiled_kernel(), "ankle_frames"), reason="no compiled kernel")
def test_the_compiled_decoder_equals_the_python_path_bit_for_bit():
    kernel = compiled_kernel()
    out = (
        np.zeros(64, np.int64),
        np.zeros(64),
        np.zeros(64),
        np.zeros(64, np.uint8),
        np.zeros(64),
    )
    scales = (POSITION_SCALE_RAD, TORQUE_SCALE_NM)
    for chunk in _read_stream(40, 7)[::3]:
        n = kernel.ankle_frames(chunk, b"100", *scales, *out)
        counters, positions, torques, statuses, times = python_reference(chunk)
        assert n == 7
        assert out[0][:n].tolist() == counters and out[3][:n].tolist() == statuses
        assert out[1][:n].tolist() == positions and out[2][:n].tolist() == torques
        assert out[4][:n].tolist() == times  # exactly float("SEC.USEC")
    chunk = _read_stream(2, 3)[1]
    bad = bytearray(chunk)
    bad[40] = ord("0") if bad[40] != ord("0") else ord("1")  # a data nibble: checksum fails
    assert kernel.ankle_frames(bytes(bad), b"100", *scales, *out) == -2
    frames = chunk.split(b">")[:-1]
    swapped = frames[1] + b">" + frames[0] + b">" + frames[2] + b">"
    assert kernel.ankle_frames(swapped, b"100", *scales, *out) == -3
    for odd in (chunk.replace(b"100", b"101", 1), chunk + b"< echo >", chunk[:-1] + b"  >"):
        assert kernel.ankle_frames(odd, b"100", *scales, *out) == -1
    assert kernel.ankle_frames(chunk, b"100", *scales, *(a[:2] for a in out)) == -1  # too many


# ------------------------------------------------------------------ the same bytes, two clients
def faulty_stream() -> list[bytes]:
    """Reads of the built-in protocol with faults, cut at odd places."""
    lines = b"".join(_read_stream(300, 4))
    records = [r + b">" for r in lines.split(b">")[:-1]]
    del records[500:503]  # a gap of 3
    records.insert(700, records[690])  # a duplicate
    bad = bytearray(records[800])
    bad[-5] = ord("1") if bad[-5] == ord("0") else ord("0")  # a checksum that fails
    records[800] = bytes(bad)
    records.insert(900, b"< frame 200 1764000000.360000 0101000000000000 >")  # a command
    records.insert(950, b"< error 004 1764000000.380000 >")
    records.insert(1000, b"< echo >")
    records.insert(1100, records[1190])  # a stray from the future, refuted later
    data = b"".join(records)
    sizes = [192, 193, 47, 1, 500, 4000, 96]
    chunks, at, k = [], 0, 0
    while at < len(data):
        chunks.append(data[at : at + sizes[k % len(sizes)]])
        at += sizes[k % len(sizes)]
        k += 1
    return chunks


def serve_once(listener: socket.socket, chunks: list[bytes], done: threading.Event) -> None:
    conn, _ = listener.accept()
    with conn:
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.sendall(b"< hi >")
        for _ in range(2):
            seen = b""
            while b">" not in seen:
                seen += conn.recv(64)
            conn.sendall(b"< ok >")
        time.sleep(0.1)  # python-can's client reads '< ok >' alone
        for chunk in chunks:
            conn.sendall(chunk)
            time.sleep(0.0005)
        done.wait(30.0)


def acquire(client: str, chunks: list[bytes], monkeypatch, numpy_only: bool = False):
    with socket.create_server(("127.0.0.1", 0)) as listener:
        done = threading.Event()
        server = threading.Thread(target=serve_once, args=(listener, chunks, done))
        server.start()
        port = listener.getsockname()[1]
        try:
            if client == "python-can":
                bus = can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="can0")
            else:
                bus = SocketcandBus("can0", "127.0.0.1", port)
            ring = RingBuffer(5000)
            acq = Acquisition(bus, ring, receive_timeout_s=0.02)
            if numpy_only:
                monkeypatch.setattr(acq, "_kernel", None)
            with acq:
                deadline = time.monotonic() + 30.0
                while acq.counters().frames < 1201 and time.monotonic() < deadline:
                    time.sleep(0.01)
                time.sleep(0.1)
            bus.shutdown()
        finally:
            done.set()
            server.join(10.0)
    counters = acq.counters()
    snap = ring.read_since(0, 4999)
    return counters, snap


@pytest.mark.parametrize("numpy_only", [False, True])
def test_the_same_bytes_give_the_same_rows_and_counters_as_python_cans_client(
    monkeypatch, numpy_only
):
    chunks = faulty_stream()
    theirs, their_rows = acquire("python-can", chunks, monkeypatch)
    ours, our_rows = acquire("rtsid", chunks, monkeypatch, numpy_only)
    assert theirs.frames == 1201 and theirs.lost_samples == 4 and theirs.gaps == 2  # + bad sum
    assert theirs.malformed == 1 and theirs.error_frames == 1 and theirs.commands_seen == 1
    assert theirs.strays == 1 and theirs.duplicates == 1
    fields = ("frames", "samples", "gaps", "lost_samples", "duplicates", "malformed")
    fields += ("strays", "error_frames", "commands_seen", "unknown_id", "out_of_order")
    assert {f: getattr(ours, f) for f in fields} == {f: getattr(theirs, f) for f in fields}
    for column in ("sample_index", "position_rad", "torque_nm", "valid", "status"):
        assert np.array_equal(getattr(our_rows, column), getattr(their_rows, column)), column
    assert np.array_equal(our_rows.bus_time_s, their_rows.bus_time_s, equal_nan=True)


def test_a_closed_connection_is_a_bus_error_and_the_handshake_is_bounded():
    with socket.create_server(("127.0.0.1", 0)) as listener:
        done = threading.Event()
        server = threading.Thread(target=serve_once, args=(listener, [], done))
        server.start()
        bus = SocketcandBus("can0", "127.0.0.1", listener.getsockname()[1])
        done.set()
        server.join(10.0)
        with pytest.raises(can.CanOperationError, match="closed the connection"):
            for _ in range(100):  # bounded: the server has closed its end
                bus.recv_chunk(0.5)
        bus.shutdown()
    with SocketcandServer(port=0, channel="can0") as srv:
        with pytest.raises(LinkError, match="refused to open channel 'can9'"):
            SocketcandBus("can9", "127.0.0.1", srv.port, timeout_s=2.0)
