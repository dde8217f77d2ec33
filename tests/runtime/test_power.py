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


def test_a_thread_is_put_in_the_real_time_class_and_a_refusal_names_the_key(monkeypatch):
    import threading

    from rtsid.runtime.power import set_realtime_priority

    release = threading.Event()
    thread = threading.Thread(target=release.wait, args=(10,))
    thread.start()
    try:
        assert thread.native_id is not None
        set_realtime_priority(thread.native_id, 0)  # 0: left alone
        assert os.sched_getscheduler(thread.native_id) == os.SCHED_OTHER
        try:
            set_realtime_priority(thread.native_id, 5, "rtsid-worker")
        except ConfigError:
            pytest.skip("this machine does not allow real-time scheduling (not root)")
        assert os.sched_getscheduler(thread.native_id) == os.SCHED_FIFO
        assert os.sched_getparam(thread.native_id).sched_priority == 5
        assert os.sched_getscheduler(0) == os.SCHED_OTHER  # only that thread
    finally:
        release.set()
        thread.join(10)

    def refuse(*args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with pytest.raises(
        ConfigError, match=r"daemon\.realtime_priority.*rtsid-worker.*LimitRTPRIO.*= 0"
    ):
        set_realtime_priority(12345, 10, "rtsid-worker")
