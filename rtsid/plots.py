"""Figures of impedance estimates (matplotlib, an optional extra: ``pip install rtsid[plot]``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from rtsid.errors import InputDataError

__all__ = [
    "HELD_LABEL",
    "estimate_series",
    "impedance_figure",
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
#: How a held I or B is labelled: a value carried from earlier fits, not this window's.
HELD_LABEL = "held (median of the last 20 s of fits)"
BAND_LABEL = "95 % interval"


def require_matplotlib() -> Any:
    """``matplotlib.pyplot`` with a file-only backend, or a clear error naming the extra.

    Commands call it before any work when ``--plot`` is given, so a missing extra is one
    line up front, never a figure silently missing after a long run."""
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
    window_s: float = 0.3,
    markers: Sequence[tuple[float, str]] = (),
) -> Path:
    """:func:`impedance_figure` saved as PNG; returns the file written."""
    plt = require_matplotlib()
    fig = impedance_figure(
        t_s,
        series,
        title=title,
        reference=reference,
        truth=truth,
        flagged=flagged,
        window_s=window_s,
        markers=markers,
    )
    return _save(plt, fig, out_png)


def impedance_figure(
    t_s: ArrayLike,
    series: Mapping[str, ArrayLike],
    *,
    title: str,
    reference: Mapping[str, float] | None = None,
    truth: Mapping[str, ArrayLike] | None = None,
    flagged: ArrayLike | None = None,
    window_s: float = 0.3,
    markers: Sequence[tuple[float, str]] = (),
) -> Any:
    """K, B, I and VAF over time, one panel each (a matplotlib figure).

    * Stiffness leads with the tracker's ``K_track`` and its 95 % band (``±1.96·K_track_se``)
      when the series has it; each window's own K is drawn lighter beside it, named
      "K (each 300 ms window)". Without a track, the window's K leads, with its band.
    * B and I: fitted values with their 95 % band where they were fitted; where held
      (``B_held``/``I_held``) a step line labelled :data:`HELD_LABEL`, with no band.
    * K, B and I axes include zero (and the 2nd–98th percentiles of the values drawn), so a
      held median or a steady joint does not look like a changing one; flagged windows are
      orange dots on K and VAF.

    Parameters
    ----------
    t_s : array_like, shape (n,)
        Time of each estimate (window end), s.
    series : mapping
        Arrays ``K``, ``B``, ``I``, ``vaf`` (NaN where a window was withheld) and optionally
        ``K_se``, ``B_se``, ``I_se``, ``K_track``, ``K_track_se``, ``B_held``, ``I_held``
        (held: true/1 where the value is held, not fitted).
    title : str
        Figure title.
    reference : mapping, optional
        Horizontal reference lines per key (e.g. the whole-record estimate).
    truth : mapping, optional
        True values over ``t_s`` per key (simulations).
    flagged : array_like of bool, shape (n,), optional
        Windows whose estimate carries a flag.
    window_s : float
        Window length, s (for the window K's label).
    markers : sequence of (float, str)
        Trial markers (sample time, s; label): a vertical line on every panel, the label
        along it in the top one (as plain text: ``$`` never starts mathtext).

    Returns
    -------
    matplotlib.figure.Figure
    """
    plt = require_matplotlib()
    t = np.asarray(t_s, dtype=float)
    mask = np.zeros(t.size, bool) if flagged is None else np.asarray(flagged, dtype=bool)
    fig, axes = plt.subplots(len(PANELS), 1, sharex=True, figsize=(9, 9), constrained_layout=True)
    drawn = {
        "K": _stiffness_panel(axes[0], t, series, window_s),
        "B": _held_panel(axes[1], t, series, "B"),
        "I": _held_panel(axes[2], t, series, "I"),
    }
    vaf = np.asarray(series["vaf"], dtype=float)
    axes[3].plot(t, vaf, lw=0.8, color="C0", label="VAF (each window)")
    for ax, (key, _, label) in zip(axes, PANELS, strict=True):
        y = np.asarray(series[key], dtype=float)
        if mask.any() and key in ("K", "vaf"):  # a window's flag is not about a held value
            ax.plot(t[mask], y[mask], ".", ms=2, color="C1", label="flagged window")
        if reference and key in reference:
            ax.axhline(reference[key], color="C3", ls="--", lw=1.0, label="whole record")
        if truth and key in truth:
            ax.plot(t, np.asarray(truth[key], dtype=float), color="k", lw=1.0, label="truth")
        if key in drawn:
            extra = [reference[key]] if reference and key in reference else []
            _limits_from_zero(ax, [*drawn[key], np.asarray(extra, dtype=float)])
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=7)
    axes[-1].set_xlabel("time (s)")
    axes[-1].set_ylim(0, 100)
    _draw_markers(axes, markers)
    fig.suptitle(title)
    return fig


def _draw_markers(axes: Sequence[Any], markers: Sequence[tuple[float, str]]) -> None:
    """A dotted vertical line per marker on every panel, its label along it in the top one."""
    for t, label in markers:
        for ax in axes:
            ax.axvline(t, color="0.35", ls=":", lw=0.9)
        axes[0].annotate(
            _plain_text(label, 40),
            xy=(t, 0.98),
            xycoords=("data", "axes fraction"),
            rotation=90,
            va="top",
            ha="right",
            fontsize=6,
            annotation_clip=False,
        )


def _plain_text(label: str, limit: int) -> str:
    """``label`` cut to ``limit`` characters, ``$`` escaped (matplotlib reads ``$…$`` as
    math, and a malformed one fails the whole figure)."""
    text = label if len(label) <= limit else label[: limit - 1] + "…"
    return text.replace("$", r"\$")


#: What :func:`estimate_series` reads of each estimate message (NaN where withheld).
SERIES_KEYS = ("K", "B", "I", "K_se", "B_se", "I_se", "vaf", "I_held", "B_held")
#: Published with every message, also while a window is withheld (the tracker's state).
TRACK_KEYS = ("K_track", "K_track_se")
#: Flags about the computer, not the estimate: a window carrying only these is not flagged.
IGNORED_FLAGS = ("over_budget",)


def estimate_series(
    messages: Sequence[Mapping[str, Any]],
) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """What :func:`impedance_figure` draws from estimate messages (the daemon's, replay's,
    :func:`rtsid.identify`'s as dicts): window end times (s), series by key (NaN where
    withheld; the track also while withheld) and the flagged windows."""
    t = np.array([m["t_end_s"] for m in messages], dtype=float)
    series = {
        k: np.array(
            [m[k] if m.get("ok") and m.get(k) is not None else np.nan for m in messages],
            dtype=float,
        )
        for k in SERIES_KEYS
    }
    for k in TRACK_KEYS:
        series[k] = np.array([np.nan if m.get(k) is None else m[k] for m in messages], dtype=float)
    flagged = np.array(
        [bool(m.get("ok")) and any(f not in IGNORED_FLAGS for f in m["flags"]) for m in messages]
    )
    return t, series, flagged


def _column(series: Mapping[str, ArrayLike], key: str, n: int) -> np.ndarray | None:
    """``series[key]`` as floats, or None when absent or all NaN."""
    if key not in series:
        return None
    y = np.asarray(series[key], dtype=float)
    return y if y.size == n and np.isfinite(y).any() else None


def _band(ax: Any, t: np.ndarray, y: np.ndarray, se: np.ndarray | None, label: str) -> None:
    if se is None:
        return
    ok = np.isfinite(y) & np.isfinite(se)
    if ok.any():
        low, high = y - 1.96 * se, y + 1.96 * se
        ax.fill_between(t, low, high, where=ok, color="C0", alpha=0.25, lw=0, label=label)


def _stiffness_panel(
    ax: Any, t: np.ndarray, series: Mapping[str, ArrayLike], window_s: float
) -> list[np.ndarray]:
    """K_track with its band leading, the window's K lighter; the values drawn."""
    k = np.asarray(series["K"], dtype=float)
    window_label = f"K (each {window_s * 1e3:.0f} ms window)"
    track = _column(series, "K_track", t.size)
    if track is None:
        _band(ax, t, k, _column(series, "K_se", t.size), BAND_LABEL)
        ax.plot(t, k, lw=0.8, color="C0", label=window_label)
        return [k]
    ax.plot(t, k, lw=0.6, color="0.55", alpha=0.7, label=window_label)
    _band(ax, t, track, _column(series, "K_track_se", t.size), f"K_track {BAND_LABEL}")
    ax.plot(t, track, lw=1.5, color="C0", label="K_track (tracked stiffness)")
    return [k, track]


def _held_panel(
    ax: Any, t: np.ndarray, series: Mapping[str, ArrayLike], key: str
) -> list[np.ndarray]:
    """Fitted values with their band; held values as a step line without one."""
    y = np.asarray(series[key], dtype=float)
    held_column = series.get(f"{key}_held")
    held = (
        np.zeros(t.size, bool)
        if held_column is None
        else np.nan_to_num(np.asarray(held_column, dtype=float)) > 0
    )
    fitted = np.where(held, np.nan, y)
    if np.isfinite(fitted).any():
        se = _column(series, f"{key}_se", t.size)
        _band(ax, t, fitted, None if se is None else np.where(held, np.nan, se), BAND_LABEL)
        ax.plot(t, fitted, lw=0.8, color="C0", label=f"{key} (fitted in the window)")
    if held.any():
        ax.step(t, np.where(held, y, np.nan), where="post", lw=1.5, color="C2", label=HELD_LABEL)
    return [y]


def _limits_from_zero(ax: Any, drawn: Sequence[np.ndarray]) -> None:
    """Y-limits from zero (or the lowest value, if negative) to the 98th percentile of what
    is drawn, padded: a steady or held value shows as steady, not as a zoomed wiggle."""
    values = np.concatenate([np.ravel(d) for d in drawn]) if drawn else np.zeros(0)
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return
    low, high = np.percentile(finite, [2, 98]) if finite.size >= 5 else (finite.min(), finite.max())
    low, high = min(0.0, float(low)), max(0.0, float(high))
    pad = 0.15 * ((high - low) or 1.0)
    ax.set_ylim(low - (pad if low < 0 else 0.0), high + pad)


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
    delays = np.array([float(r["reflex_delay_ms"]) for r in rows])
    delay.plot(t, delays, "x:", color="C3", label="delay")
    pinned = np.array([bool(r.get("reflex_delay_at_bound")) for r in rows])
    if pinned.any():  # not a measured delay: it ended at a bound of its search
        delay.plot(
            t[pinned], delays[pinned], "o", mfc="none", color="C3", label="delay at a search bound"
        )
        delay.legend(loc="upper right", fontsize=8)
    delay.set_ylabel("delay (ms)")
    delay.set_ylim(0, max(60.0, 1.2 * float(np.nanmax(delays, initial=0.0))))  # never a zoom
    axes[2].plot(t, [r["vaf_cascade"] for r in rows], "o-", ms=3, label="cascade")
    axes[2].plot(
        t, [r["vaf_intrinsic_irf"] for r in rows], "s--", ms=3, label="intrinsic IRF alone"
    )
    axes[2].set(xlabel="window end (s)", ylabel="VAF (%)")
    axes[2].legend(fontsize=8)
    fig.suptitle(title)
    return _save(plt, fig, out_png)
