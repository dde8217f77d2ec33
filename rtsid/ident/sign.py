"""Is the torque sign inverted? One judgement over a stream's window estimates.

A rig that reports torque with the opposite sign gives windows that all read K < 0, B < 0
and I < 0: a passive joint cannot have them. The judgement counts, over the estimable
windows of one stream, those with ``K < 0`` and ``B < 0`` (and ``I < 0`` where I was fitted,
not held), and calls the sign inverted once at least :data:`MIN_WINDOWS` windows were
estimable and at least :data:`INVERTED_SHARE` of them read negative.

Measured with :func:`rtsid.ident.stream.sliding_estimates` (300 ms windows every 0.1 s,
default estimator; the inverted column negates the torque; simulated records from
:func:`rtsid.sim.reflex.prbs_ankle_with_reflex`, 30 s at 2500 Hz):

====================================================  ==================  ================
record                                                 correct sign        inverted sign
====================================================  ==================  ================
shared real recording (reklab_ankle_z, 596 windows)    0 of 596            588 of 596
simulated ankle K 150, 3 % and 30 % noise              0 of 298            298 of 298
simulated ankle K 20, B 0.3, 30 % noise                0 of 298            283 of 298
simulated reflex (gain 25, 40 ms), 10 % noise          0 of 298            288 of 298
simulated reflex (gain 25), K 20, 30 % noise           0 of 298            149 of 298
====================================================  ==================  ================

A robot alone (nobody attached, the virtual plant's 0.05 kg·m² footplate, with and without
its calibration subtracted; 20 s, 20 ms hop, three seeds each), where K and B are near zero,
read so in at most 3 of 986 windows (running share from the 50th window ≤ 0.06): a
calibration baseline run is not stopped. With the correct sign no window of any record above
read all three negative, so a majority rule has a wide margin against a false refusal; with
the sign inverted the share after the first 50 windows was 0.90–1.0 (0.46 on the last,
adversarial record, where the whole record's share, 0.50, still refuses it).

The identify command judges the whole record; the daemon and replay judge the running count
after every window, from the :data:`MIN_WINDOWS`-th on (the same function).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "INVERTED_SHARE",
    "MIN_WINDOWS",
    "SignCount",
    "inverted_torque_message",
    "reads_inverted",
    "torque_sign_inverted",
]

#: Estimable windows needed before the sign is judged.
MIN_WINDOWS = 50
#: Share of those windows reading K, B (and a fitted I) < 0 that calls the sign inverted.
INVERTED_SHARE = 0.5


def reads_inverted(K: float, B: float, I: float, I_held: bool = False) -> bool:  # noqa: E741
    """Whether one window reads as a joint seen through an inverted torque sign: ``K < 0``
    and ``B < 0``, and ``I < 0`` unless ``I`` is held (a held value is not this window's)."""
    return K < 0 and B < 0 and (I_held or I < 0)


def torque_sign_inverted(inverted: int, estimable: int) -> bool:
    """The judgement: at least :data:`MIN_WINDOWS` estimable windows, and at least
    :data:`INVERTED_SHARE` of them read inverted (:func:`reads_inverted`)."""
    return estimable >= MIN_WINDOWS and inverted >= INVERTED_SHARE * estimable


def inverted_torque_message(inverted: int, estimable: int, fix: str) -> str:
    """The one line that refuses an inverted sign; ``fix`` names the switch to use."""
    return (
        f"most windows read K, B, I < 0 ({inverted} of {estimable}): the torque sign is "
        f"inverted; {fix}"
    )


@dataclass
class SignCount:
    """The running count a stream keeps for :func:`torque_sign_inverted`."""

    inverted: int = 0
    estimable: int = 0

    def add(self, K: float, B: float, I: float, I_held: bool = False) -> bool:  # noqa: E741
        """Count one estimable window; True when the sign is now judged inverted."""
        self.estimable += 1
        self.inverted += reads_inverted(K, B, I, I_held)
        return torque_sign_inverted(self.inverted, self.estimable)
