from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from rtsid.link import protocol
from rtsid.link.protocol import (
    COMMAND_ID,
    STATE_ID,
    Command,
    database,
    decode_command,
    decode_state,
    encode_command,
    encode_state_block,
)

REPO = Path(__file__).resolve().parents[2]


def test_hw_dbc_is_the_packaged_dbc():
    packaged = protocol.dbc_path().read_bytes()
    assert (REPO / "hw" / "ankle.dbc").read_bytes() == packaged


def test_dbc_defines_the_three_frames_with_the_module_constants():
    db = database()
    state = db.get_message_by_frame_id(STATE_ID)
    assert state.name == "AnkleState" and state.length == 8
    pos = state.get_signal_by_name("Position")
    trq = state.get_signal_by_name("Torque")
    assert pos.scale == protocol.POSITION_SCALE_RAD and pos.length == 24 and pos.is_signed
    assert trq.scale == protocol.TORQUE_SCALE_NM and trq.length == 20 and trq.is_signed
    assert state.get_signal_by_name("Counter").length == 12
    assert db.get_message_by_frame_id(COMMAND_ID).name == "PerturbationCommand"
    assert db.get_message_by_frame_id(protocol.DIAGNOSTICS_ID).is_multiplexed()


@settings(max_examples=300, deadline=None)
@given(
    pos=st.integers(-(1 << 23), (1 << 23) - 1),
    trq=st.integers(-(1 << 19), (1 << 19) - 1),
    ctr=st.integers(0, 4095),
    status=st.integers(0, 15),
)
def test_fast_decoder_and_vectorised_encoder_agree_with_cantools(pos, trq, ctr, status):
    payload = encode_state_block(
        np.array([pos]), np.array([trq]), np.array([ctr]), np.array([status])
    )[0].tobytes()
    decoded = database().decode_message(STATE_ID, payload, scaling=False)
    assert decoded["Position"] == pos and decoded["Torque"] == trq
    assert decoded["Counter"] == ctr
    bits = (
        decoded["PositionSaturated"]
        | decoded["TorqueSaturated"] << 1
        | decoded["PerturbationOn"] << 2
        | decoded["Discontinuity"] << 3
    )
    assert bits == status
    assert decode_state(payload) == (pos, trq, ctr, status)
    scaled = database().decode_message(STATE_ID, payload)
    assert scaled["Position"] == pos * protocol.POSITION_SCALE_RAD
    assert scaled["Torque"] == trq * protocol.TORQUE_SCALE_NM


def test_checksum_rejects_every_single_bit_flip_and_an_all_zero_frame():
    payload = bytearray(encode_state_block(*(np.array([v]) for v in (-1234, 5678, 99, 5)))[0])
    assert decode_state(bytes(payload)) is not None
    for bit in range(64):
        flipped = bytearray(payload)
        flipped[bit // 8] ^= 1 << (bit % 8)
        assert decode_state(bytes(flipped)) is None, bit
    assert decode_state(bytes(8)) is None


def test_quantisation_clips_and_flags():
    raw, clipped = protocol.quantise_position(np.array([0.1234564, -9.0, 9.0]))
    assert raw.tolist() == [123456, -(1 << 23), (1 << 23) - 1]
    assert clipped.tolist() == [False, True, True]


def test_command_round_trip_through_cantools():
    cmd = Command(enable=True, kind="multisine", amplitude_rad=0.045, bandwidth_hz=30, counter=7)
    data = encode_command(cmd)
    assert decode_command(data) == cmd
    decoded = database().decode_message(COMMAND_ID, data, decode_choices=True)
    assert decoded["Kind"] == "multisine" and decoded["Enable"] == 1
    assert abs(decoded["Amplitude"] - 0.045) < 1e-9 and decoded["Bandwidth"] == 30


def test_diagnostics_pages_decode():
    data = protocol.encode_diagnostics(1, Uptime=12, TxOverflows=3)
    assert protocol.decode_diagnostics(data) == {"Page": 1, "Uptime": 12, "TxOverflows": 3}
