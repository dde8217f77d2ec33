import threading

from rtsid.link.markers import MarkerInbox, WireMarker


def test_inbox_drains_in_order_and_empties():
    inbox = MarkerInbox()
    inbox.put(WireMarker(10, "trial 1 start"))
    inbox.put(WireMarker(25, "trial 1 end"))
    assert inbox.drain() == [WireMarker(10, "trial 1 start"), WireMarker(25, "trial 1 end")]
    assert inbox.drain() == []


def test_a_full_inbox_counts_what_it_drops():
    inbox = MarkerInbox(capacity=2)
    for i in range(5):
        inbox.put(WireMarker(i, "m"))
    assert [m.sample_index for m in inbox.drain()] == [0, 1]
    assert inbox.dropped == 3


def test_a_writer_thread_and_a_reader_lose_nothing():
    inbox = MarkerInbox(capacity=100_000)
    n = 20_000

    def write() -> None:
        for i in range(n):
            inbox.put(WireMarker(i, "m"))

    writer = threading.Thread(target=write)
    writer.start()
    got: list[WireMarker] = []
    while writer.is_alive() or len(got) < n:
        got.extend(inbox.drain())
        if not writer.is_alive() and len(got) < n:
            got.extend(inbox.drain())
            break
    writer.join(timeout=10)
    assert [m.sample_index for m in got] == list(range(n))
