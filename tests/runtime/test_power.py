import os
import struct

import pytest

from rtsid.errors import ConfigError
from rtsid.runtime.power import cpu_latency_request


def open_paths() -> set[str]:
    fds = "/proc/self/fd"
    return {os.path.realpath(os.path.join(fds, fd)) for fd in os.listdir(fds)}


def test_request_is_written_and_held_for_the_block_only(tmp_path):
    device = tmp_path / "cpu_dma_latency"
    device.write_bytes(b"")
    with cpu_latency_request(0, str(device)) as held:
        assert held
        assert struct.unpack("i", device.read_bytes()) == (0,)
        assert str(device) in open_paths()  # the kernel keeps the request while it is open
    assert str(device) not in open_paths()


def test_negative_latency_makes_no_request(tmp_path):
    device = tmp_path / "absent"
    with cpu_latency_request(-1, str(device)) as held:
        assert not held
    assert not device.exists()


def test_unopenable_device_is_a_config_error_naming_the_key_and_the_fix(tmp_path):
    with pytest.raises(ConfigError, match=r"daemon\.cpu_latency_us.*cpu_latency_us = -1"):
        with cpu_latency_request(0, str(tmp_path / "no" / "such" / "device")):
            pass
