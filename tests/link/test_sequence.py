"""Stray frames against real gaps: what the Sequencer writes, counts and drops."""

from __future__ import annotations

import pytest

from rtsid.link.sequence import CONTRADICTIONS, MAX_STRAY_RUN, Sequencer


def feed(indices: list[int], first: int = 0) -> tuple[Sequencer[int], list[int], int]:
    """Offer each index (the item is its arrival position); return the sequencer, the
    indices written, in order, and the lost samples the writes imply. Checks that every row
    written carries a frame with that index; ``arrivals`` maps each row to that frame's
    arrival position."""
    seq: Sequencer[int] = Sequencer(last=first - 1)
    written: list[int] = []
    lost = 0
    arrivals.clear()
    for arrival, index in enumerate(indices):
        if index <= seq.last:
            continue  # late: the caller's business
        for row, item in seq.offer(index, arrival):
            assert indices[item] == row
            arrivals[row] = item
            lost += row - (written[-1] if written else first - 1) - 1
            written.append(row)
    return seq, written, lost


arrivals: dict[int, int] = {}


@pytest.mark.parametrize("k", [1, 2, 3, 5, MAX_STRAY_RUN])
@pytest.mark.parametrize("offset", [CONTRADICTIONS + 1, 40, 1000, 1001, 3000, 4000])
def test_a_run_of_consecutive_strays_is_dropped_like_one(k: int, offset: int) -> None:
    strays = [100 + offset + j for j in range(k)]  # +1000, +1001, … after sample 100
    indices = [*range(101), *strays, *range(101, 200)]
    seq, written, lost = feed(indices)
    assert written == list(range(200)) and lost == 0
    assert seq.strays == k and seq.held == 0 and seq.duplicates == 0
    # the strays' rows carry the real frames, which came after them
    assert all(arrivals[i] > 100 + k for i in range(101, 200))


def test_a_stray_closer_than_the_contradictions_is_taken_for_a_reordered_frame() -> None:
    # Documented limit: +2 could be the next-but-one frame arriving early. It is written;
    # the real frame with that index then arrives late (the caller counts a duplicate).
    seq, written, lost = feed([*range(101), 102, *range(101, 200)])
    assert written == list(range(200)) and lost == 0 and seq.strays == 0


@pytest.mark.parametrize("k", [2, 3, 5])
def test_strays_at_scattered_offsets_in_a_row_are_all_dropped(k: int) -> None:
    strays = [100 + 3000 - 700 * j for j in range(k)]  # descending, far apart
    seq, written, lost = feed([*range(101), *strays, *range(101, 200)])
    assert written == list(range(200)) and lost == 0 and seq.strays == k


@pytest.mark.parametrize("size", [1, 2, 3, 5, 1000, 3000])
def test_a_real_gap_of_the_same_size_is_still_a_gap(size: int) -> None:
    after = list(range(101 + size, 300 + size))
    seq, written, lost = feed([*range(101), *after])
    assert written == [*range(101), *after] and lost == size
    assert seq.strays == 0 and seq.held == 0


@pytest.mark.parametrize("k", [1, 2, 5])
def test_strays_next_to_a_real_gap_are_told_apart(k: int) -> None:
    strays = [1100 + j for j in range(k)]
    after = list(range(150, 300))  # 49 samples really lost after 100
    seq, written, lost = feed([*range(101), *strays, *after])
    assert written == [*range(101), *after] and lost == 49 and seq.strays == k
    seq, written, lost = feed([*range(101), *after[:3], *strays, *after[3:]])
    assert written == [*range(101), *after] and lost == 49 and seq.strays == k


def test_reordered_frames_fill_a_held_jump_and_duplicates_of_held_frames_are_counted() -> None:
    seq, written, lost = feed([0, 1, 3, 2, 4, 6, 6, 5, 7, 8])
    assert written == list(range(9)) and lost == 0
    assert seq.strays == 0 and seq.duplicates == 1


def test_more_strays_in_a_row_than_the_bound_are_a_jump_as_documented() -> None:
    strays = [1100 + j for j in range(MAX_STRAY_RUN + 1)]
    seq, written, _ = feed([*range(101), *strays])
    assert written == [*range(101), *strays] and seq.strays == 0


def test_a_held_run_is_refuted_by_exactly_the_documented_number_of_frames() -> None:
    seq, _, _ = feed([*range(101), 1100, 1101, *range(101, 101 + CONTRADICTIONS - 1)])
    assert seq.held == 2 and seq.strays == 0
    seq.offer(seq.last + 1, -1)
    assert seq.held == 0 and seq.strays == 2
