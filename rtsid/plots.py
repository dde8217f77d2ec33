"""Figures of impedance estimates (matplotlib, an optional extra: ``pip install rtsid[plot]``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from rtsid.errors import InputDataError

__all__ = [
    "plot_cascade",
    "plot_cascade_windows",
    "plot_distributions",
    "plot_impedance_track",
    "require_matplotlib",
]

PANELS = (
    ("K", "K_se", "stiffness K\n(N·m/rad)"),
    ("B", "B_se", "damping B\n(N·m·s/rad)"),
    ("I", "I_se", "inertia I\n(kg·m²)"),
    ("vaf", None, "VAF (%)"),
)


def require_matplotlib() -> Any:
    """``matplotlib.pyplot`` with a file-only backend, or a clear error naming the extra."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise InputDataError(
            "plots need matplotlib; install the extra with: pip install 'rtsid[plot]'"
        ) from None
    return plt


def plot_impedance_track(
    t_s: ArrayLike,
    series: Mapping[str, ArrayLike],
    out_png: str | Path,
    *,
    title: str,
    reference: Mapping[str, float] | None = None,
    truth: Mapping[str, ArrayLike] | None = None,
    flagged: ArrayLike | None = None,
) -> Path:
    """K, B, I with ±1.96·SE bands and VAF over time, one panel each, saved as PNG.

    Axis limits follow the 2nd–98th percentiles so a few wild windows do not flatten the
    rest; flagged windows are drawn as orange dots.

    Parameters
    ----------
    t_s : array_like, shape (n,)
        Time of each estimate (window end), s.
    series : mapping
        Arrays ``K``, ``B``, ``I``, ``vaf`` and optionally ``K_se``, ``B_se``, ``I_se``
        (NaN where a window was withheld).
    out_png : str or Path
        Output file.
    title : str
        Figure title.
    reference : mapping, optional
        Horizontal reference lines per key (e.g. the whole-record estimate).
    truth : mapping, optional
        True values over ``t_s`` per key (simulations).
    flagged : array_like of bool, shape (n,), optional
        Windows whose estimate carries a flag.

    Returns
    -------
    Path
        The file written.
    """
    plt = require_matplotlib()
    t = np.asarray(t_s, dtype=float)
    fig, axes = plt.subplots(len(PANELS), 1, sharex=True, figsize=(9, 8), constrained_layout=True)
    for ax, (key, se_key, label) in zip(axes, PANELS, strict=True):
        y = np.asarray(series[key], dtype=float)
        ax.plot(t, y, lw=0.8, color="C0", label="windowed estimate")
        if flagged is not None:
            mask = np.asarray(flagged, dtype=bool)
            ax.plot(t[mask], y[mask], ".", ms=3, color="C1", label="flagged window")
        _robust_limits(ax, y, reference.get(key) if reference else None)
        if se_key and se_key in series:
            se = np.asarray(series[se_key], dtype=float)
            ax.fill_between(
                t, y - 1.96 * se, y + 1.96 * se, color="C0", alpha=0.2, lw=0, label="95 % interval"
            )
        if reference and key in reference:
            ax.axhline(reference[key], color="C3", ls="--", lw=1.0, label="whole record")
        if truth and key in truth:
            ax.plot(t, np.asarray(truth[key], dtype=float), color="k", lw=1.0, label="truth")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time (s)")
    axes[-1].set_ylim(0, 100)
    fig.suptitle(title)
    return _save(plt, fig, out_png)


def _robust_limits(ax: Any, y: np.ndarray, reference: float | None) -> None:
    finite = y[np.isfinite(y)]
    if finite.size < 5:
        return
    low, high = np.percentile(finite, [2, 98])
    if reference is not None:
        low, high = min(low, reference), max(high, reference)
    pad = 0.25 * (high - low or abs(high) or 1.0)
    ax.set_ylim(low - pad, high + pad)


def _save(plt: Any, fig: Any, out_png: str | Path) -> Path:
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_distributions(
    series: Mapping[str, ArrayLike],
    out_png: str | Path,
    *,
    title: str,
    reference: Mapping[str, float] | None = None,
) -> Path:
    """Histograms of K, B, I and VAF over windows (2nd–98th percentile range), as PNG."""
    plt = require_matplotlib()
    fig, axes = plt.subplots(1, len(PANELS), figsize=(12, 3.2), constrained_layout=True)
    for ax, (key, _, label) in zip(axes, PANELS, strict=True):
        y = np.asarray(series[key], dtype=float)
        y = y[np.isfinite(y)]
        low, high = np.percentile(y, [2, 98]) if y.size else (0.0, 1.0)
        ax.hist(y[(y >= low) & (y <= high)], bins=40, color="C0", alpha=0.8)
        ax.axvline(float(np.median(y)), color="k", lw=1.0, label="median")
        if reference and key in reference:
            ax.axvline(reference[key], color="C3", ls="--", lw=1.0, label="whole record")
        ax.set_xlabel(label.replace("\n", " "))
    axes[0].set_ylabel("windows")
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    return _save(plt, fig, out_png)


def plot_cascade(cascade: Any, out_png: str | Path, *, title: str, excerpt_s: float = 10.0) -> Path:
    """A parallel cascade's two pathways: measured torque with the intrinsic and reflex
    predictions over the first ``excerpt_s`` scored seconds, and the reflex IRF with the
    delayed low-pass fitted to it. ``cascade`` is a :class:`rtsid.ident.cascade.CascadeFit`."""
    plt = require_matplotlib()
    fs = cascade.fs_hz
    n = min(cascade.measured.size, round(excerpt_s * fs))
    t = (cascade.first_scored + np.arange(n)) / fs
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 7))
    top.plot(t, cascade.measured[:n], color="0.6", lw=1.0, label="measured")
    top.plot(t, cascade.intrinsic_torque[:n], lw=0.9, label="intrinsic pathway")
    top.plot(t, cascade.reflex_torque[:n], lw=0.9, label="reflex pathway")
    top.set(xlabel="time (s)", ylabel="torque (N·m)")
    top.set_title(
        f"VAF: cascade {cascade.vaf_total:.1f} %, intrinsic IRF alone "
        f"{cascade.vaf_intrinsic_only:.1f} %",
        fontsize=9,
    )
    top.legend(loc="upper right", fontsize=8)
    reflex = cascade.reflex
    lags = np.arange(reflex.irf.size) / fs
    bottom.plot(lags * 1e3, reflex.irf, lw=1.0, label=f"reflex IRF (MDL rank {reflex.rank})")
    fine = np.linspace(0, lags[-1], 1000)
    bottom.plot(
        fine * 1e3,
        reflex.dynamics.response(fine),
        lw=1.0,
        label=f"delayed low-pass: gain {reflex.gain:.3g} N·m·s/rad, "
        f"delay {reflex.delay_s * 1e3:.0f} ms"
        + (
            f" (at the {reflex.dynamics.delay_at_bound} bound of its search)"
            if reflex.dynamics.delay_at_bound
            else ""
        ),
    )
    bottom.set(xlabel="lag (ms)", ylabel="N·m per rad/s per s")
    bottom.legend(loc="upper right", fontsize=8)
    fig.suptitle(title)
    return _save(plt, fig, out_png)


def plot_cascade_windows(
    rows: Sequence[Mapping[str, float | str]], out_png: str | Path, *, title: str
) -> Path:
    """Window-by-window cascades: intrinsic K (with ±1.96·SE) beside the K of a fit without a
    reflex model, the reflex gain and delay, and the cascade's VAF."""
    plt = require_matplotlib()
    t = np.array([r["t_end_s"] for r in rows])
    k, se = np.array([r["K"] for r in rows]), np.array([r["K_se"] for r in rows])
    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    axes[0].fill_between(t, k - 1.96 * se, k + 1.96 * se, alpha=0.25)
    axes[0].plot(t, k, "o-", ms=3, label="intrinsic K")
    axes[0].plot(t, [r["K_no_reflex_model"] for r in rows], "s--", ms=3, label="K, no reflex model")
    axes[0].set_ylabel("K (N·m/rad)")
    axes[0].legend(fontsize=8)
    axes[1].plot(t, [r["reflex_gain_nm_s_per_rad"] for r in rows], "o-", ms=3, label="gain")
    axes[1].set_ylabel("reflex gain\n(N·m·s/rad)")
    delay = axes[1].twinx()
    delay.plot(t, [r["reflex_delay_ms"] for r in rows], "x:", color="C3", label="delay")
    delay.set_ylabel("delay (ms)")
    axes[2].plot(t, [r["vaf_cascade"] for r in rows], "o-", ms=3, label="cascade")
    axes[2].plot(
        t, [r["vaf_intrinsic_irf"] for r in rows], "s--", ms=3, label="intrinsic IRF alone"
    )
    axes[2].set(xlabel="window end (s)", ylabel="VAF (%)")
    axes[2].legend(fontsize=8)
    fig.suptitle(title)
    return _save(plt, fig, out_png)
