"""Time-varying identification of a multisine experiment: load, identify, report, plot.

The work behind ``rtsid tv``: a recording of a torque-driven multisine experiment (input
torque, output angle, and the multisine's definition) goes through
:func:`rtsid.ident.skirt.identify_ltv`; the result is ``G(jω, t)`` at the excited lines, the
frozen second-order track ``K(t), B(t), I(t), f_n(t)`` and the paper's peak-picking
resonance, compared with the truth when the recording carries it (simulated experiments
made with :func:`simulate_to_npz` do).

Recording formats:

* ``.npz`` (:func:`load_tv_npz`): ``torque_nm`` (n,), ``position_rad`` (n,), ``fs_hz``
  (scalar), ``excited_bins`` (excited DFT bins of one period), ``period_samples`` (scalar);
  optional truth ``stiffness_nm_per_rad`` (n,), ``inertia``, ``damping``.
* rtsid MCAP recordings (:func:`load_tv_mcap`): the ``/samples`` channel, and the multisine
  declared in the stored configuration's ``[plant.torque_multisine]`` (the virtual plant's
  ``mode = "torque_multisine"`` writes it; a real rig declares it the same way). The
  longest run of whole periods without lost samples is used; with a simulated plant the
  truth ``K(t)`` comes from the stored ``[plant.stiffness_profile]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtsid.config import section_from_mapping
from rtsid.errors import InputDataError, RecordingError, RtsidError
from rtsid.ident.skirt import (
    BASIS_FAMILIES,
    BasisSelection,
    LtvEstimate,
    ModelSelection,
    SecondOrderTrack,
    fourier_harmonics,
    identify_ltv,
    select_basis_size,
    select_model,
)
from rtsid.io.files import atomic_write, read_npz
from rtsid.io.mcap_read import read_run_config
from rtsid.io.recording import read_recording
from rtsid.link.config import TorqueMultisineConfig, plant_config_from_mapping
from rtsid.link.signals import PlantTruth
from rtsid.sim.ltv import multisine_experiment

__all__ = [
    "TvData",
    "TvResult",
    "auto_basis",
    "choose_basis",
    "choose_model",
    "format_choice",
    "format_report",
    "identify_recording",
    "load_tv",
    "load_tv_mcap",
    "load_tv_npz",
    "plot_result",
    "require_matplotlib",
    "simulate_to_npz",
]

FloatArray = NDArray[np.float64]
REQUIRED = ("torque_nm", "position_rad", "fs_hz", "excited_bins", "period_samples")


@dataclass(frozen=True)
class TvData:
    """A multisine experiment ready for :func:`identify_recording`.

    Attributes
    ----------
    torque_nm, position_rad : numpy.ndarray, shape (n,)
        Input torque (N·m) and output angle (rad).
    fs_hz : float
        Sampling rate, Hz.
    excited_bins : numpy.ndarray of int
        Excited DFT bins of one multisine period.
    period_samples : int
        Samples per period.
    stiffness_nm_per_rad : numpy.ndarray or None
        True ``K(t)`` per sample when known (simulation), N·m/rad.
    inertia : float or None
        True inertia when known, kg·m².
    """

    torque_nm: FloatArray
    position_rad: FloatArray
    fs_hz: float
    excited_bins: NDArray[np.int64]
    period_samples: int
    stiffness_nm_per_rad: FloatArray | None = None
    inertia: float | None = None
    selection: str = ""


def load_tv(path: str | Path, *, trim: bool = False) -> TvData:
    """A multisine experiment from ``.npz`` (:func:`load_tv_npz`) or ``.mcap``
    (:func:`load_tv_mcap`), by suffix."""
    suffix = Path(path).suffix.lower()
    if suffix == ".mcap":
        return load_tv_mcap(path)
    if suffix == ".npz":
        return load_tv_npz(path, trim=trim)
    raise InputDataError(
        f"{str(path)!r}: rtsid tv reads .npz experiments and .mcap recordings, not {suffix!r} "
        "files (import other files with 'rtsid convert' first)"
    )


def load_tv_npz(path: str | Path, *, trim: bool = False) -> TvData:
    """Read a multisine experiment from ``.npz``.

    Parameters
    ----------
    path : str or Path
        The file.
    trim : bool
        Keep only the whole periods at the start of the record (otherwise a record that is
        not a whole number of periods is refused by the identification).

    Raises
    ------
    InputDataError
        Missing, empty or unreadable file, or a required array missing.
    RecordingError
        A scalar that is not one finite number.
    """
    p = Path(path)
    hint = "make a time-varying experiment with 'rtsid tv --simulate CS3 --save-simulation exp.npz'"
    arrays = read_npz(p, REQUIRED, hint=hint)
    period = int(_scalar(arrays, "period_samples", p))
    torque = np.asarray(arrays["torque_nm"], dtype=np.float64)
    position = np.asarray(arrays["position_rad"], dtype=np.float64)
    truth = arrays.get("stiffness_nm_per_rad")
    n = torque.size
    if n == 0 or position.size != n:
        raise InputDataError(
            f"recording {str(p)!r}: torque_nm ({n}) and position_rad ({position.size}) must hold "
            "the same, non-zero number of samples"
        )
    if trim and period > 0 and n % period:
        n = (n // period) * period
        if n == 0:
            raise InputDataError(
                f"the record ({torque.size} samples) is shorter than one {period}-sample period"
            )
    return TvData(
        torque_nm=torque[:n],
        position_rad=position[:n],
        fs_hz=_scalar(arrays, "fs_hz", p),
        excited_bins=np.asarray(arrays["excited_bins"], dtype=np.int64),
        period_samples=period,
        stiffness_nm_per_rad=None if truth is None else np.asarray(truth, dtype=float)[:n],
        inertia=_scalar(arrays, "inertia", p) if "inertia" in arrays else None,
    )


def load_tv_mcap(path: str | Path) -> TvData:
    """Read a multisine experiment from an rtsid MCAP recording (footer-less files too).

    Given any part of a rotated daemon session (``…-001.mcap``, …), every part is read.

    The multisine comes from the stored configuration's ``[plant.torque_multisine]``
    (period, excited bins; its first period starts at sample ``start_index``). Periods are
    counted from there; the longest run of consecutive whole periods whose samples are all
    valid is returned (``TvData.selection`` says which). A recording of the virtual plant
    in ``mode = "torque_multisine"`` carries the truth ``K(t)`` and ``I`` too.

    Raises
    ------
    RecordingError
        Missing or unreadable file, or no samples.
    InputDataError
        No multisine declared in the stored configuration, or no whole period without
        lost samples.
    """
    p = Path(path)
    if not p.is_file():
        raise RecordingError(f"recording {str(p)!r} does not exist; check the path")
    document = read_run_config(p)
    declared = _declared_multisine(document, p)
    first, fs_hz, position, torque, valid = _recorded_rows(p)
    ms = declared.multisine(fs_hz)
    period = ms.period_samples
    j0, j1 = _longest_whole_periods(valid, first, declared.start_index, period)
    if j1 <= j0:
        raise InputDataError(
            f"recording {str(p)!r} holds no whole {declared.period_s:g} s multisine period "
            f"without lost samples after sample {declared.start_index} (rows {first}.."
            f"{first + valid.size - 1}); record at least two periods, or check the link for "
            "lost samples"
        )
    lo = declared.start_index + j0 * period - first
    hi = declared.start_index + j1 * period - first
    selection = (
        f"periods {j0}..{j1 - 1} of the multisine ({j1 - j0} × {period} samples: rows "
        f"{lo + first}..{hi + first - 1}, t = {(lo + first) / fs_hz:g}..{(hi + first) / fs_hz:g} "
        f"s); times below count from row {lo + first}"
    )
    k_true, inertia = _simulated_truth(document, first + lo, hi - lo, fs_hz)
    return TvData(
        torque_nm=torque[lo:hi],
        position_rad=position[lo:hi],
        fs_hz=fs_hz,
        excited_bins=ms.excited_bins,
        period_samples=period,
        stiffness_nm_per_rad=k_true,
        inertia=inertia,
        selection=selection,
    )


def _declared_multisine(document: dict[str, Any], path: Path) -> TorqueMultisineConfig:
    plant = document.get("plant")
    table = plant.get("torque_multisine") if isinstance(plant, dict) else None
    declared = section_from_mapping(TorqueMultisineConfig, table, "plant.torque_multisine")
    if not declared.declared:
        raise InputDataError(
            f"recording {str(path)!r} declares no torque multisine (its stored config has no "
            "[plant.torque_multisine] period_s > 0); record one with [plant] mode = "
            '"torque_multisine" (hw/configs/torque-multisine.toml), declare the rig\'s multisine '
            "in [plant.torque_multisine] when recording, or give an .npz experiment"
        )
    return declared


def _recorded_rows(path: Path) -> tuple[int, float, FloatArray, FloatArray, NDArray[np.bool_]]:
    """All rows of the recording session on one index grid (the one recording reader):
    ``(first, fs_hz, position, torque, valid)``; lost rows and non-finite values are invalid."""
    rows = read_recording(path).samples.all_rows()
    valid = rows.valid & np.isfinite(rows.position_rad) & np.isfinite(rows.torque_nm)
    return rows.first_index, rows.fs_hz, rows.position_rad, rows.torque_nm, valid


def _longest_whole_periods(
    valid: NDArray[np.bool_], first: int, start_index: int, period: int
) -> tuple[int, int]:
    """``(j0, j1)``: periods ``j0 .. j1 − 1`` (counted from ``start_index``) are the longest
    run (earliest of equals) whose rows are all present and valid; ``j1 == j0`` if none."""
    j_lo = max(0, -((start_index - first) // period))  # first period starting at a row
    j_hi = (first + valid.size - start_index) // period  # periods ending at or before the end
    if j_hi <= j_lo:
        return 0, 0
    lo = start_index + j_lo * period - first
    rows = valid[lo : lo + (j_hi - j_lo) * period].reshape(-1, period)
    whole: list[bool] = np.all(rows, axis=1).tolist()
    best, best_at, run = 0, 0, 0
    for j, ok in enumerate(whole):
        run = run + 1 if ok else 0
        if run > best:
            best, best_at = run, j - run + 1
    return j_lo + best_at, j_lo + best_at + best


def _simulated_truth(
    document: dict[str, Any], first: int, n: int, fs_hz: float
) -> tuple[FloatArray | None, float | None]:
    """True ``K`` per row and the simulated inertia when the virtual plant ran the
    experiment (``[plant] mode = "torque_multisine"``), else ``(None, None)``."""
    plant = document.get("plant")
    if not isinstance(plant, dict) or plant.get("mode") != "torque_multisine":
        return None, None
    cfg = plant_config_from_mapping(plant)
    k = PlantTruth.from_config(cfg).stiffness_at((first + np.arange(n)) / fs_hz)
    return np.asarray(k, dtype=float), cfg.inertia + cfg.robot_inertia


def _scalar(arrays: dict[str, Any], key: str, path: Path) -> float:
    value = np.asarray(arrays[key])
    if value.size != 1 or not np.isfinite(value).all():
        raise RecordingError(
            f"recording {str(path)!r}: {key} must be one finite number, got shape {value.shape}"
        )
    return float(value.reshape(()))


def simulate_to_npz(
    case: str, path: str | Path, *, spacing_hz: float = 0.8, snr_db: float = 22.0, seed: int = 1
) -> TvData:
    """Simulate one realisation of a study case (CS1/CS2/CS3 of the published study, or
    SIN2: two sinusoidal cycles of K(t) per record) and save it.

    The file holds the arrays :func:`load_tv_npz` reads plus the truth and the noiseless
    angle (``position_clean_rad``).
    """
    exp = multisine_experiment(case, spacing_hz=spacing_hz, snr_db=snr_db, seed=seed)
    with atomic_write(path, "wb", what="experiment") as fh:
        np.savez_compressed(fh, **exp.as_npz_dict())  # type: ignore[arg-type]
    return TvData(
        exp.torque_nm,
        exp.position_rad,
        exp.fs_hz,
        exp.excited_bins,
        exp.period_samples,
        exp.stiffness_nm_per_rad,
        exp.inertia,
    )


@dataclass(frozen=True)
class TvResult:
    """Identification of one recording.

    Attributes
    ----------
    estimate : LtvEstimate
        ``G_p`` and everything derived from it.
    track : SecondOrderTrack
        Frozen second-order fit over ``track.t_s``.
    peak_hz : numpy.ndarray
        The paper's peak-picking resonance at ``track.t_s``, Hz.
    stiffness_true, natural_frequency_true_hz : numpy.ndarray or None
        Truth at ``track.t_s`` when known.
    """

    estimate: LtvEstimate
    track: SecondOrderTrack
    peak_hz: FloatArray
    stiffness_true: FloatArray | None
    natural_frequency_true_hz: FloatArray | None


def auto_basis(
    data: TvData,
    n_max: int | None = None,
    *,
    basis_family: str = "legendre",
    n_transient: int | None = None,
) -> int:
    """``N_p`` that ``rtsid tv -p auto`` uses for ``basis_family`` (see :func:`choose_basis`)."""
    return choose_basis(data, n_max, basis_family=basis_family, n_transient=n_transient).n_basis


def choose_basis(
    data: TvData,
    n_max: int | None = None,
    *,
    basis_family: str = "legendre",
    n_transient: int | None = None,
) -> BasisSelection:
    """``N_p`` for ``basis_family`` chosen from the record, with the candidates and scores
    (:func:`rtsid.ident.skirt.select_basis_size`).

    The candidates run up to the largest well-conditioned ``N_p`` (at most ``n_max``,
    default per family :data:`rtsid.ident.skirt.AUTO_MAX_BASIS`: Legendre 20); the one with
    the best predicted validation VAF (Mallows' C_p on the record) is chosen. On the
    published study with Legendre polynomials this picks N_p = 20 for lines 0.8 Hz apart
    and the best N_p of the grid for 0.2 Hz, see docs/skirt.md.
    """
    if data.period_samples < 1 or data.torque_nm.size < data.period_samples:
        raise InputDataError("choosing N_p needs at least one whole multisine period")
    return select_basis_size(
        data.torque_nm,
        data.position_rad,
        data.fs_hz,
        data.excited_bins,
        data.period_samples,
        basis_family=basis_family,
        n_max=n_max,
        n_transient=n_transient,
    )


def choose_model(
    data: TvData,
    *,
    families: tuple[str, ...] = BASIS_FAMILIES,
    n_transient: int | None = None,
) -> ModelSelection:
    """Basis family and ``N_p`` chosen from the record, as ``rtsid tv`` does by default
    (:func:`rtsid.ident.skirt.select_model`): per family every well-conditioned ``N_p`` up
    to :data:`rtsid.ident.skirt.AUTO_MAX_BASIS` (Legendre 20, Fourier 101, B-splines 80),
    then the best predicted validation VAF over all of them.
    """
    if data.period_samples < 1 or data.torque_nm.size < data.period_samples:
        raise InputDataError("choosing the model needs at least one whole multisine period")
    return select_model(
        data.torque_nm,
        data.position_rad,
        data.fs_hz,
        data.excited_bins,
        data.period_samples,
        families=families,
        n_transient=n_transient,
    )


def format_choice(selection: ModelSelection | BasisSelection) -> str:
    """What was chosen from the data and why, for the report: the model and its predicted
    validation VAF, the runners-up, and one line per family whose search stopped short of
    its documented range (with the reason)."""
    if isinstance(selection, BasisSelection):
        selection = ModelSelection((selection,), selection.estimate)
    best = selection.chosen
    band = f" of the output up to {selection.band_hz:.3g} Hz" if selection.decimation > 1 else ""
    lines = [
        f"model chosen from the data: {best.basis_family} N_p = {best.n_basis}, predicted "
        f"validation VAF{band} {best.chosen_vaf:.1f} % (best of {len(best.candidates)} N_p, "
        f"{best.candidates[0]}…{best.candidates[-1]})"
    ]
    if selection.runners_up:
        lines.append(
            "runners-up: "
            + ", ".join(
                f"{s.basis_family} N_p = {s.n_basis}: {s.chosen_vaf:.1f} %"
                for s in selection.runners_up
            )
        )
    lines += [f"{s.basis_family} cap: {s.cap_reason}" for s in selection.families if s.cap_reason]
    lines += [f"{family} not used: {why}" for family, why in selection.refused]
    return "\n".join(lines)


#: Parameters ``rtsid tv`` holds constant over the record by default (a joint's inertia
#: does not change; the high, noisy lines that determine it are then pooled).
DEFAULT_COMMON: tuple[str, ...] = ("inertia",)


def identify_recording(
    data: TvData,
    *,
    n_basis: int = 8,
    n_transient: int | None = None,
    n_times: int = 401,
    common: tuple[str, ...] = DEFAULT_COMMON,
    basis_family: str = "legendre",
    estimate: LtvEstimate | None = None,
) -> TvResult:
    """Skirt decomposition of ``data`` and the second-order track at ``n_times`` times.

    ``common`` names parameters held constant over time in the second-order fit
    (``"inertia"``, the default, and ``"damping"``; ``()`` frees them: see
    :meth:`LtvEstimate.fit_second_order`). ``estimate``: an estimate of ``data`` already
    made (e.g. :attr:`BasisSelection.estimate`), used instead of ``n_basis`` and
    ``basis_family``.
    """
    est = estimate or identify_ltv(
        data.torque_nm,
        data.position_rad,
        data.fs_hz,
        data.excited_bins,
        data.period_samples,
        n_basis=n_basis,
        n_transient=n_transient,
        basis_family=basis_family,
    )
    t = est.default_times(n_times)
    track = est.fit_second_order(t, common=common)
    k_true = fn_true = None
    if data.stiffness_nm_per_rad is not None:
        k_true = np.interp(
            t, np.arange(data.torque_nm.size) / data.fs_hz, data.stiffness_nm_per_rad
        )
        if data.inertia:
            fn_true = np.sqrt(k_true / data.inertia) / (2 * np.pi)
    return TvResult(est, track, est.resonance_from_peak(t), k_true, fn_true)


def _rmse(a: FloatArray, b: FloatArray) -> str:
    ok = np.isfinite(a)
    text = f"{np.sqrt(np.mean((a[ok] - b[ok]) ** 2)):.3g}"
    return text if ok.all() else f"{text} ({np.sum(~ok)} of {a.size} times without resonance)"


def _basis_detail(est: LtvEstimate) -> str:
    """What the basis resolves in time, for the report."""
    if est.basis_family == "fourier":
        h = fourier_harmonics(est.n_basis)
        return f" (harmonics up to {h} of the {est.n_samples / est.fs_hz:g} s record)"
    if est.basis_family == "bspline" and est.n_basis > 3:
        return f" (knots {est.duration_s / (est.n_basis - 3):.3g} s apart)"
    return ""


def format_report(result: TvResult, rows: int = 11) -> str:
    """Summary and a table of the tracks at ``rows`` times (with the truth when known)."""
    est, tr = result.estimate, result.track
    f = est.frequencies_hz
    lines = [
        f"record: {est.n_samples} samples at {est.fs_hz:g} Hz ({est.n_periods} periods of "
        f"{est.period_samples}); {f.size} excited lines {f[0]:g}…{f[-1]:g} Hz"
        + (f", {f[1] - f[0]:g} Hz apart" if f.size > 1 else ""),
        f"model: N_p = {est.n_basis} {est.basis_name}{_basis_detail(est)}, transient polynomial "
        f"{'off' if est.n_transient is None else f'degree {est.n_transient}'}, worst variance "
        f"inflation {est.variance_inflation:.2f}",
    ]
    truth = result.stiffness_true is not None
    head = f"{'t s':>7} {'K N·m/rad':>10} {'B N·m·s/rad':>12} {'I kg·m²':>9} {'f_n Hz':>7}"
    head += f" {'peak Hz':>8} {'fit err':>8}"
    if truth:
        head += f" {'K true':>7}"
    if result.natural_frequency_true_hz is not None:
        head += f" {'f_n true':>8}"
    lines += ["", head]
    for i in np.linspace(0, tr.t_s.size - 1, rows).round().astype(int):
        row = (
            f"{tr.t_s[i]:7.1f} {tr.stiffness[i]:10.3f} {tr.damping[i]:12.4f} "
            f"{tr.inertia[i]:9.5f} {tr.natural_frequency_hz[i]:7.3f} {result.peak_hz[i]:8.3f} "
            f"{tr.fit_error[i]:8.3f}"
        )
        if result.stiffness_true is not None:
            row += f" {result.stiffness_true[i]:7.3f}"
        if result.natural_frequency_true_hz is not None:
            row += f" {result.natural_frequency_true_hz[i]:8.3f}"
        lines.append(row)
    if result.stiffness_true is not None:
        lines += ["", f"K(t) RMSE {_rmse(tr.stiffness, result.stiffness_true)} N·m/rad"]
    if result.natural_frequency_true_hz is not None:
        fn = result.natural_frequency_true_hz
        floor = (f[1] - f[0]) / np.sqrt(12) if f.size > 1 else float("nan")
        lines.append(
            f"f_n(t) RMSE: second-order fit {_rmse(tr.natural_frequency_hz, fn)} Hz; "
            f"peak picking {_rmse(result.peak_hz, fn)} Hz (its quantisation floor ≈ "
            f"Δf_exc/√12 = {floor:.3f} Hz)"
        )
    return "\n".join(lines)


def require_matplotlib() -> Any:
    """``matplotlib.figure`` or a one-line error saying how to install it."""
    try:
        from matplotlib import figure
    except ImportError:
        raise RtsidError(
            "plotting needs matplotlib, which is not installed; "
            "install the extra with: pip install 'rtsid[plot]'"
        ) from None
    return figure


def plot_result(result: TvResult, path: str | Path, title: str = "") -> Path:
    """|G(jω, t)| as an image, K(t) and f_n(t) over time (with the truth when known)."""
    figure = require_matplotlib()
    est, tr = result.estimate, result.track
    fig = figure.Figure(figsize=(9, 8.5), layout="constrained")
    ax_g, ax_k, ax_f = fig.subplots(3, 1, sharex=True)
    g_db = 20 * np.log10(np.abs(est.G(tr.t_s)).T)
    f = est.frequencies_hz
    df = f[1] - f[0] if f.size > 1 else 1.0
    extent = (tr.t_s[0], tr.t_s[-1], f[0] - df / 2, f[-1] + df / 2)
    img = ax_g.imshow(
        g_db, aspect="auto", origin="lower", extent=extent, cmap="viridis", interpolation="nearest"
    )
    fig.colorbar(img, ax=ax_g, label="|G| dB re 1 rad/(N·m)")
    ax_g.set_ylabel("frequency (Hz)")
    ax_g.set_title(title or f"|G(jω, t)|, N_p = {est.n_basis}")
    ax_k.plot(tr.t_s, tr.stiffness, label="skirt + 2nd-order fit")
    if result.stiffness_true is not None:
        ax_k.plot(tr.t_s, result.stiffness_true, "k--", label="truth")
    ax_k.set_ylabel("K (N·m/rad)")
    ax_k.legend(loc="best")
    ax_f.plot(tr.t_s, tr.natural_frequency_hz, label="2nd-order fit f_n")
    ax_f.step(tr.t_s, result.peak_hz, where="mid", alpha=0.7, label="peak of |G| (paper)")
    if result.natural_frequency_true_hz is not None:
        ax_f.plot(tr.t_s, result.natural_frequency_true_hz, "k--", label="truth √(K/I)/2π")
    ax_f.set_ylabel("resonance (Hz)")
    ax_f.set_xlabel("time (s)")
    ax_f.legend(loc="best")
    out = Path(path)
    try:
        fig.savefig(out, dpi=110)
    except OSError as exc:
        raise RecordingError(f"cannot write the figure {str(out)!r}: {exc}") from None
    return out


def write_track_csv(result: TvResult, path: str | Path) -> Path:
    """The second-order track (and truth when known) as CSV, one row per time.

    Columns (units in docs/skirt.md): ``t_s``, ``K``, ``B``, ``I``, ``f_n_hz``, ``f_peak_hz``,
    ``fit_error`` and, when the truth is known, ``K_true``; the estimates' CSV conventions
    (:mod:`rtsid.io.estimate_csv`): shortest round-trip numbers, NaN as an empty field.
    """
    from rtsid.io.estimate_csv import encode_value
    from rtsid.io.files import atomic_write

    tr = result.track
    cols = {
        "t_s": tr.t_s,
        "K": tr.stiffness,
        "B": tr.damping,
        "I": tr.inertia,
        "f_n_hz": tr.natural_frequency_hz,
        "f_peak_hz": result.peak_hz,
        "fit_error": tr.fit_error,
    }
    if result.stiffness_true is not None:
        cols["K_true"] = result.stiffness_true
    out = Path(path)
    lines = [",".join(cols)]
    lines += [",".join(encode_value(v) for v in row) for row in zip(*cols.values(), strict=True)]
    with atomic_write(out, what="track") as fh:
        fh.write("\n".join(lines) + "\n")
    return out
