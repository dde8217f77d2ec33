"""``rtsid bench skirt``: the published skirt-decomposition study, reproduced and extended.

Lataire, Pintelon & Louarroudi (Automatica 2012) as applied to joint admittance in the
source documents: plant ``I·φ̈ = τ − B·φ̇ − K(t)·φ`` with I = 0.02, B = 0.05 and K(t) between
0.4 and 6 N·m/rad (CS1 linear, CS2 hyperbolic, CS3 one raised-cosine cycle), 200 Hz, 200 s,
20 periods of a 10 s multisine with lines up to 10 Hz, output SNR 22 dB, an estimation and a
validation realisation. Grid: Δf_exc ∈ {0.2, 0.8, 1.4} Hz × N_p = 1…20.

Printed per point: VAF (%) of the model's prediction of the *noiseless* validation output;
RMSE of the paper's peak-picking resonance (quantised: floor ≈ Δf_exc/√12) and of the
continuous ``f_n(t)`` from the frozen second-order fit, both against ``√(K(t)/I)/2π`` at
1000 times over the record. Then a summary against the floors, the timing (median, p99,
ratio to one FFT of the record measured in the same run), an ablation (half-way windows and
the transient polynomial vs the defaults, and the oracle: the best N_p-term Legendre
expansion of the true frozen G(jω, t)), the three time-basis families (Legendre, Fourier,
B-splines) side by side at the N_p each chooses from the data, on the study's cases and on
SIN2 (two sinusoidal cycles of K(t) per record, the floor case of the tailored bases),
``rtsid tv``'s defaults (family and N_p chosen from the data, one inertia) against the old
ones (Legendre N_p = 8, free inertia), and CS3 side by side with the windowed method.
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from rtsid.errors import NumericalError
from rtsid.ident.skirt import (
    BASIS_FAMILIES,
    WARN_VARIANCE_INFLATION,
    LtvEstimate,
    SkirtConditioningWarning,
    identify_ltv,
    legendre_basis,
    select_basis_size,
    select_model,
)
from rtsid.sim.ltv import LtvExperiment, multisine_experiment

CASES = ("CS1", "CS2", "CS3")
SPACINGS_HZ = (0.2, 0.8, 1.4)
EST_SEED, VAL_SEED = 11, 22
N_TIMES = 1000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--figures", metavar="DIR", help="write the PNG figures here")
    parser.add_argument(
        "--max-basis", type=int, default=20, metavar="N", help="largest N_p of the grid (20)"
    )
    parser.add_argument(
        "--realisations",
        type=int,
        default=5,
        metavar="N",
        help="estimation/validation pairs for the spread table at Δf_exc = 0.8 Hz (5; 0: skip)",
    )
    parser.add_argument(
        "--defaults-only",
        action="store_true",
        help="print only the table of rtsid tv's defaults against the old ones (≈ 1 min)",
    )


@dataclass(frozen=True)
class Point:
    """One (case, Δf_exc, N_p) of the grid; NaN metrics when the estimate was refused."""

    vaf: float
    peak_rmse: float
    fn_rmse: float
    fn_invalid: int
    k_rmse: float
    flag: str  # "" ok, "w" conditioning warning, "x" refused
    seconds: float


@dataclass(frozen=True)
class Case:
    est: LtvExperiment
    val: LtvExperiment
    t_s: np.ndarray
    k_true: np.ndarray
    fn_true: np.ndarray


def _vaf(y: np.ndarray, y_hat: np.ndarray) -> float:
    return float(100.0 * (1.0 - np.var(y - y_hat) / np.var(y)))


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    ok = np.isfinite(a)
    return float(np.sqrt(np.mean((a[ok] - b[ok]) ** 2))) if ok.any() else float("nan")


def _make_case(
    name: str, spacing_hz: float, est_seed: int = EST_SEED, val_seed: int = VAL_SEED
) -> Case:
    est = multisine_experiment(name, spacing_hz=spacing_hz, seed=est_seed)
    val = multisine_experiment(name, spacing_hz=spacing_hz, seed=val_seed)
    n = est.torque_nm.size
    idx = np.linspace(0, n - 1, N_TIMES).round().astype(int)
    t = idx / est.fs_hz
    k = est.stiffness_nm_per_rad[idx]
    return Case(est, val, t, k, np.sqrt(k / est.inertia) / (2 * np.pi))


def _identify(case: Case, n_basis: int, **kw: Any) -> tuple[LtvEstimate | None, str, float]:
    e = case.est
    flag = ""
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SkirtConditioningWarning)
        try:
            est = identify_ltv(
                e.torque_nm,
                e.position_rad,
                e.fs_hz,
                e.excited_bins,
                e.period_samples,
                n_basis=n_basis,
                **kw,
            )
        except NumericalError:
            return None, "x", time.perf_counter() - start
    seconds = time.perf_counter() - start
    if any(issubclass(w.category, SkirtConditioningWarning) for w in caught):
        flag = "w"
    return est, flag, seconds


def _evaluate(case: Case, n_basis: int, **kw: Any) -> Point:
    est, flag, seconds = _identify(case, n_basis, **kw)
    if est is None:
        nan = float("nan")
        return Point(nan, nan, nan, 0, nan, flag, seconds)
    return _score(case, est, flag, seconds)


def _score(
    case: Case, est: LtvEstimate, flag: str, seconds: float, common: tuple[str, ...] = ()
) -> Point:
    """Validation VAF, resonance and K errors of an estimate of ``case``'s record."""
    vaf = _vaf(case.val.position_clean_rad, est.simulate(case.val.torque_nm))
    peak = _rmse(est.resonance_from_peak(case.t_s), case.fn_true)
    track = est.fit_second_order(case.t_s, common=common)
    fn = track.natural_frequency_hz
    return Point(
        vaf,
        peak,
        _rmse(fn, case.fn_true),
        int(np.sum(~np.isfinite(fn))),
        _rmse(track.stiffness, case.k_true),
        flag,
        seconds,
    )


def _oracle_vaf(case: Case, n_basis: int, template: LtvEstimate) -> float:
    """VAF of the best N_p-term Legendre expansion of the true frozen G(jω, t)."""
    e = case.est
    w = 2 * np.pi * template.frequencies_hz
    g = 1.0 / (e.stiffness_nm_per_rad[:, None] - e.inertia * w**2 + 1j * e.damping * w)
    g_p = np.linalg.lstsq(legendre_basis(g.shape[0], n_basis).T, g, rcond=None)[0]
    oracle = replace(template, G_p=np.asarray(g_p, dtype=np.complex128))
    return _vaf(case.val.position_clean_rad, oracle.simulate(case.val.torque_nm))


def _fmt(x: float, spec: str, flag: str = "") -> str:
    if not np.isfinite(x):
        return "—"
    return f"{x:{spec}}{flag}"


def _grid_table(spacing: float, grid: dict[tuple[str, int], Point], bases: Iterable[int]) -> str:
    floor = spacing / np.sqrt(12)
    head = "N_p | " + " | ".join(f"{c} VAF % | {c} peak | {c} fit" for c in CASES)
    lines = [
        f"Δf_exc = {spacing:g} Hz (every {round(spacing * 10 * 20)}th bin of the 0.005 Hz grid); "
        f"peak-picking floor Δf_exc/√12 = {floor:.3f} Hz; RMSE in Hz",
        "",
        "| " + head + " |",
        "|" + "---|" * (1 + 3 * len(CASES)),
    ]
    for nb in bases:
        cells = [str(nb)]
        for c in CASES:
            p = grid[(c, nb)]
            mark = {"w": " ⚠", "x": ""}.get(p.flag, "")
            cells += [
                _fmt(p.vaf, ".1f", mark),
                _fmt(p.peak_rmse, ".3f"),
                _fmt(p.fn_rmse, ".3f", f" ({p.fn_invalid} NaN)" if p.fn_invalid else ""),
            ]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    lines.append(
        f"⚠ conditioning warning (variance inflated > {WARN_VARIANCE_INFLATION:g}×); "
        "— refused (singular)."
    )
    return "\n".join(lines)


def _timed(fn: Callable[[], object], repeats: int) -> np.ndarray:
    out = np.empty(repeats)
    for i in range(repeats):
        start = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - start
    return out


def _windowed_track(
    position: np.ndarray, torque: np.ndarray, fs_hz: float, window_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int, float]:
    """Window-centre times, K and I of :func:`sliding_estimates` (hop 1 s), counts, seconds."""
    from rtsid.ident.stream import sliding_estimates
    from rtsid.ident.window import EstimatorOptions

    # Options for this slow plant (f_n 0.7–2.8 Hz, 200 Hz sampling) instead of the ankle
    # defaults: low-pass 20 Hz, no decimation, fit band 0.5–10 Hz, IRF lags ±0.1 s. The record
    # is an admittance experiment: the noise (22 dB) is on the angle, the regressor of an
    # output-error fit, which it biases (errors in variables: K RMSE 3.6 N·m/rad); the IRF's
    # relative fit on the excited band does not (0.08), and nothing is held (I, B fitted).
    opts = EstimatorOptions(
        lowpass_hz=20.0,
        analysis_fs_hz=200.0,
        lag_s=0.1,
        fit_method="relative",
        fit_band_hz=(0.5, 10.0),
        min_excitation_rad=0.0,
        hold="none",
    )
    start = time.perf_counter()
    res = list(
        sliding_estimates(position, torque, fs_hz, window_s=window_s, hop_s=1.0, options=opts)
    )
    seconds = time.perf_counter() - start
    kept = [(r, r.estimate) for r in res if r.estimate is not None]
    tc = np.array([(r.start + r.stop - 1) / 2 / fs_hz for r, _ in kept])
    k = np.array([est.K for _, est in kept])
    inertia = np.array([est.I for _, est in kept])
    return tc, k, inertia, len(kept), len(res), seconds


#: Skirt variants of the CS3 comparison: (N_p, common parameters, neighbours each side).
COMPARISON_VARIANTS: tuple[tuple[int, tuple[str, ...], int], ...] = (
    (12, (), 1),
    (20, (), 1),
    (20, ("inertia",), 1),
    (20, ("inertia",), 2),
)
#: Which of them the comparison figure shows.
FIGURE_VARIANT = 2


def _window_comparison(
    case: Case, variants: tuple[tuple[int, tuple[str, ...], int], ...]
) -> tuple[str, dict[str, np.ndarray]]:
    try:
        import rtsid.ident.window  # noqa: F401
    except ImportError:
        return "windowed method (rtsid.ident.window) not available: comparison skipped", {}
    e = case.est
    t_all = np.arange(e.torque_nm.size) / e.fs_hz
    lines = [
        "CS3, Δf_exc = 0.8 Hz: stiffness track of the windowed method (rtsid.estimate_window "
        "on sliding windows, hop 1 s, angle fed as 'position' and applied torque as 'torque') "
        "and of the skirt decomposition (frozen second-order fit of G(jω, t); 'common I': "
        "inertia held constant over time and fitted jointly), on the same "
        "record with 22 dB output noise and on its noiseless version. Errors at the centres "
        "of the 5 s windows (except the windowed rows: their own centres).",
        "",
        "| record | method | K RMSE N·m/rad | K max abs err | f_n RMSE Hz | time s |",
        "|---|---|---|---|---|---|",
    ]
    data: dict[str, np.ndarray] = {}
    records = (("22 dB", e.position_rad), ("noiseless", e.position_clean_rad))
    for label, angle in records:
        for window_s in (2.0, 5.0, 10.0):
            tc, k, inertia, kept, total, seconds = _windowed_track(
                angle, e.torque_nm, e.fs_hz, window_s
            )
            k_true = np.interp(tc, t_all, e.stiffness_nm_per_rad)
            fn_true = np.sqrt(k_true / e.inertia) / (2 * np.pi)
            with np.errstate(invalid="ignore"):
                fn = np.sqrt(k / inertia) / (2 * np.pi)
            if window_s == 5.0 and label == "22 dB":
                data = {"t_s": tc, "k_window": k, "k_true": k_true}
            lines.append(
                f"| {label} | windowed {window_s:g} s ({kept}/{total} windows) | "
                f"{_rmse(k, k_true):.3f} | {np.max(np.abs(k - k_true)):.2f} | "
                f"{_rmse(fn, fn_true):.3f} | {seconds:.2f} |"
            )
        tc5 = data["t_s"]
        k_true = data["k_true"]
        fn_true = np.sqrt(k_true / e.inertia) / (2 * np.pi)
        for n_basis, common, neighbours in variants:
            start = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SkirtConditioningWarning)
                est = identify_ltv(
                    e.torque_nm,
                    angle,
                    e.fs_hz,
                    e.excited_bins,
                    e.period_samples,
                    n_basis=n_basis,
                    neighbours=neighbours,
                )
            track = est.fit_second_order(tc5, common=common)
            seconds = time.perf_counter() - start
            name = (
                f"skirt N_p = {n_basis}"
                + (", common I" if common else "")
                + (f", {neighbours} neighbours each side" if neighbours > 1 else "")
                + (
                    f" (⚠ variance ×{est.variance_inflation:.1f})"
                    if est.variance_inflation > WARN_VARIANCE_INFLATION
                    else ""
                )
            )
            if (n_basis, common, neighbours) == variants[FIGURE_VARIANT] and label == "22 dB":
                data["k_skirt"] = track.stiffness
                data["skirt_label"] = np.array(name)
            lines.append(
                f"| {label} | {name} | {_rmse(track.stiffness, k_true):.3f} | "
                f"{np.nanmax(np.abs(track.stiffness - k_true)):.2f} | "
                f"{_rmse(track.natural_frequency_hz, fn_true):.3f} | {seconds:.2f} |"
            )
    return "\n".join(lines), data


def run(args: argparse.Namespace) -> int:
    if args.defaults_only:
        print(_defaults(("SIN2", "CS3") if args.quick else FAMILY_CASES))
        return 0
    spacings = (0.8,) if args.quick else SPACINGS_HZ
    bases = (1, 4, 8, 12) if args.quick else tuple(range(1, args.max_basis + 1))
    print(
        f"skirt decomposition study: cases {', '.join(CASES)}, Δf_exc {spacings} Hz, "
        f"N_p {bases[0]}…{bases[-1]}; 200 s at 200 Hz, 20 periods, SNR 22 dB\n"
    )

    start = time.perf_counter()
    cases = {(c, s): _make_case(c, s) for s in spacings for c in CASES}
    sim_s = time.perf_counter() - start
    print(f"simulated {2 * len(cases)} records (RK4, 8 sub-steps) in {sim_s:.1f} s\n")

    start = time.perf_counter()
    grids: dict[float, dict[tuple[str, int], Point]] = {}
    for s in spacings:
        grids[s] = {(c, nb): _evaluate(cases[(c, s)], nb) for c in CASES for nb in bases}
    grid_s = time.perf_counter() - start

    for s in spacings:
        print(_grid_table(s, grids[s], bases))
        print()

    print(_summary(grids, bases, grid_s))
    print()
    print(_timing(cases[("CS3", 0.8)] if 0.8 in spacings else cases[next(iter(cases))]))
    print()
    print(_ablation(cases, spacings, (8, 12, 16)))
    print()
    print(_families(spacings, ("SIN2", "CS3") if args.quick else FAMILY_CASES, cases))
    print()
    print(_defaults(("SIN2", "CS3") if args.quick else FAMILY_CASES, cases))
    print()
    if not args.quick and args.realisations > 0:
        print(_spread(args.realisations, (8, 12, 20)))
        print()
    comparison: dict[str, np.ndarray] = {}
    if 0.8 in spacings:
        text, comparison = _window_comparison(cases[("CS3", 0.8)], COMPARISON_VARIANTS)
        print(text)
    if args.figures:
        paths = _write_figures(Path(args.figures), cases, grids, bases, comparison)
        print("\nfigures: " + ", ".join(str(p) for p in paths))
    return 0


#: Cases of the basis-family table: the floor case (two sinusoidal cycles) and the study's.
FAMILY_CASES = ("SIN2", *CASES)
#: The floor of the tailored bases on SIN2 at Δf_exc = 0.8 Hz: validation VAF %, f_n RMSE Hz.
FAMILY_FLOOR = (95.0, 0.05)


def _families(
    spacings: tuple[float, ...], names: tuple[str, ...], cases: dict[tuple[str, float], Case]
) -> str:
    """Each basis family at the N_p ``rtsid tv -p auto --basis-family F`` chooses."""
    lines = [
        "Basis families side by side: N_p chosen from the estimation record alone (the best "
        "predicted validation VAF — Mallows' C_p — among the well-conditioned N_p, as "
        "'rtsid tv -p auto --basis-family F'), then the validation VAF % (noiseless "
        "validation output) and the continuous f_n RMSE (Hz) at that N_p. SIN2: "
        "K(t) = 3.2 + 2.8·sin(2π·2t/200 s), two cycles per record (not in the paper).",
        "",
        "| Δf_exc Hz | case | "
        + " | ".join(f"{f} N_p | {f} VAF % | {f} f_n RMSE" for f in BASIS_FAMILIES)
        + " |",
        "|---|---|" + "---|" * (3 * len(BASIS_FAMILIES)),
    ]
    floor: dict[str, Point] = {}
    for s in spacings:
        for name in names:
            case = cases.get((name, s)) or _make_case(name, s)
            e = case.est
            cells = []
            for family in BASIS_FAMILIES:
                chosen = select_basis_size(
                    e.torque_nm,
                    e.position_rad,
                    e.fs_hz,
                    e.excited_bins,
                    e.period_samples,
                    basis_family=family,
                )
                p = _evaluate(case, chosen.n_basis, basis_family=family)
                if name == "SIN2" and s == 0.8:
                    floor[family] = p
                nan = f" ({p.fn_invalid} NaN)" if p.fn_invalid else ""
                cells += [str(chosen.n_basis), _fmt(p.vaf, ".1f"), _fmt(p.fn_rmse, ".3f", nan)]
            lines.append(f"| {s:g} | {name} | " + " | ".join(cells) + " |")
    if floor:
        vaf_floor, fn_floor = FAMILY_FLOOR
        met = [f for f, p in floor.items() if p.vaf >= vaf_floor and p.fn_rmse <= fn_floor]
        tailored = [f for f in met if f != BASIS_FAMILIES[0]]
        lines += [
            "",
            f"floor (SIN2, Δf_exc = 0.8 Hz, 22 dB: a tailored basis with validation VAF ≥ "
            f"{vaf_floor:g} % and f_n RMSE ≤ {fn_floor:g} Hz at its chosen N_p): "
            + (f"met by {', '.join(tailored)}" if tailored else "NOT met")
            + f"; Legendre {'meets' if BASIS_FAMILIES[0] in met else 'does not meet'} it",
        ]
    return "\n".join(lines)


#: The floor of ``rtsid tv``'s defaults on SIN2 at Δf_exc = 0.8 Hz (issue 19): validation
#: VAF %, f_n RMSE Hz.
DEFAULTS_FLOOR = (99.0, 0.03)


def _defaults(names: tuple[str, ...], cases: dict[tuple[str, float], Case] | None = None) -> str:
    """``rtsid tv``'s defaults (family and N_p chosen from the record, one inertia for the
    record) against the old defaults (Legendre N_p = 8, inertia free per time), Δf_exc =
    0.8 Hz."""
    from rtsid.tv import DEFAULT_COMMON

    lines = [
        "rtsid tv's defaults against the old ones, Δf_exc = 0.8 Hz, 22 dB: new = basis family "
        "and N_p chosen from the estimation record (best predicted validation VAF over "
        "Legendre 1…20, Fourier 1…101, B-splines 1…80, where well conditioned), inertia "
        "common to the record; old = Legendre N_p = 8, inertia free at each time. Validation "
        "VAF % of the noiseless validation output, continuous f_n and K RMSE at 1000 times; "
        "CPU s = choice + estimate + fit, this process's CPU time (simulation excluded).",
        "",
        "| case | defaults | model | VAF % | f_n RMSE Hz | K RMSE N·m/rad | CPU s |",
        "|---|---|---|---|---|---|---|",
    ]
    floor: Point | None = None
    for name in names:
        case = (cases or {}).get((name, 0.8)) or _make_case(name, 0.8)
        e = case.est
        start = time.process_time()
        old_est, _, _ = _identify(case, 8)
        assert old_est is not None
        old = _score(case, old_est, "", time.process_time() - start)
        start = time.process_time()
        chosen = select_model(
            e.torque_nm, e.position_rad, e.fs_hz, e.excited_bins, e.period_samples
        )
        new = _score(case, chosen.estimate, "", 0.0, DEFAULT_COMMON)
        new = replace(new, seconds=time.process_time() - start)
        if name == "SIN2":
            floor = new
        sel = chosen.chosen
        for label, model, p in (
            ("old", "legendre N_p = 8", old),
            ("new", f"{sel.basis_family} N_p = {sel.n_basis}", new),
        ):
            nan = f" ({p.fn_invalid} NaN)" if p.fn_invalid else ""
            lines.append(
                f"| {name} | {label} | {model} | {_fmt(p.vaf, '.1f')} | "
                f"{_fmt(p.fn_rmse, '.3f', nan)} | {_fmt(p.k_rmse, '.3f')} | {p.seconds:.2f} |"
            )
    if floor is not None:
        vaf_floor, fn_floor = DEFAULTS_FLOOR
        met = floor.vaf >= vaf_floor and floor.fn_rmse <= fn_floor
        lines += [
            "",
            f"floor (rtsid tv's defaults on SIN2: validation VAF ≥ {vaf_floor:g} % and f_n RMSE "
            f"≤ {fn_floor:g} Hz): {'met' if met else 'NOT met'} ({floor.vaf:.1f} %, "
            f"{floor.fn_rmse:.3f} Hz)",
        ]
    return "\n".join(lines)


def _summary(
    grids: dict[float, dict[tuple[str, int], Point]], bases: tuple[int, ...], grid_s: float
) -> str:
    lines = [
        "Summary against the floors (Δf_exc = 0.8 Hz)",
        "",
        "| case | best N_p | VAF % at best | VAF % at N_p=8 | VAF % at N_p=12 | "
        "f_n fit RMSE at N_p=8 Hz | peak RMSE at N_p=8 Hz (floor 0.231) |",
        "|---|---|---|---|---|---|---|",
    ]
    ok = True
    g = grids.get(0.8)
    if g is None:
        return "Δf_exc = 0.8 Hz not in this run"
    for c in CASES:
        vafs = {nb: g[(c, nb)].vaf for nb in bases}
        best = max((nb for nb in bases if np.isfinite(vafs[nb])), key=lambda nb: vafs[nb])
        p8 = g.get((c, 8))
        p12 = g.get((c, 12))
        ok &= vafs[best] > 90 and p8 is not None and p8.fn_rmse < 0.1
        lines.append(
            f"| {c} | {best} | {vafs[best]:.1f} | {p8.vaf if p8 else float('nan'):.1f} | "
            f"{p12.vaf if p12 else float('nan'):.1f} | "
            f"{p8.fn_rmse if p8 else float('nan'):.3f} | "
            f"{p8.peak_rmse if p8 else float('nan'):.3f} |"
        )
    lines += [
        "",
        f"floors (VAF > 90 % at the best N_p, continuous f_n RMSE < 0.1 Hz at N_p = 8): "
        f"{'met' if ok else 'NOT met'}",
        f"whole grid ({sum(len(v) for v in grids.values())} identifications + validation + "
        f"fits, simulation excluded): {grid_s:.1f} s (floor 60 s: "
        f"{'met' if grid_s <= 60 else 'NOT met'})",
        "The source's 'resonance RMSE < 0.1 Hz at Δf_exc = 0.8 Hz' is not reachable with its "
        "peak-picking metric: the peak sits on the 0.8 Hz line grid, so its RMSE against a "
        "continuously moving f_n(t) cannot go below ≈ 0.8/√12 = 0.23 Hz. The continuous "
        "second-order fit reaches it.",
    ]
    return "\n".join(lines)


def _timing(case: Case) -> str:
    e = case.est
    repeats = 20
    fft = _timed(lambda: np.fft.fft(e.position_rad), 200)
    rows = [
        "Timing (200 s at 200 Hz, Δf_exc = 0.8 Hz; baseline: one complex FFT of the "
        f"record, median {np.median(fft) * 1e3:.2f} ms)",
        "",
        "| stage | median ms | p99 ms | × FFT |",
        "|---|---|---|---|",
    ]
    for nb in (1, 8, 20):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SkirtConditioningWarning)
            times = _timed(
                lambda nb=nb: identify_ltv(  # type: ignore[misc]
                    e.torque_nm,
                    e.position_rad,
                    e.fs_hz,
                    e.excited_bins,
                    e.period_samples,
                    n_basis=nb,
                ),
                repeats,
            )
        rows.append(
            f"| identify_ltv N_p = {nb} | {np.median(times) * 1e3:.1f} | "
            f"{np.percentile(times, 99) * 1e3:.1f} | {np.median(times) / np.median(fft):.0f} |"
        )
    est = identify_ltv(
        e.torque_nm, e.position_rad, e.fs_hz, e.excited_bins, e.period_samples, n_basis=12
    )
    fit = _timed(lambda: est.fit_second_order(case.t_s), repeats)
    sim = _timed(lambda: est.simulate(case.val.torque_nm), repeats)
    rows.append(
        f"| fit_second_order, {N_TIMES} times, N_p = 12 | {np.median(fit) * 1e3:.1f} | "
        f"{np.percentile(fit, 99) * 1e3:.1f} | {np.median(fit) / np.median(fft):.0f} |"
    )
    rows.append(
        f"| simulate (validation output), N_p = 12 | {np.median(sim) * 1e3:.1f} | "
        f"{np.percentile(sim, 99) * 1e3:.1f} | {np.median(sim) / np.median(fft):.0f} |"
    )
    return "\n".join(rows)


def _spread(realisations: int, bases: tuple[int, ...]) -> str:
    """Median and range over independent estimation/validation pairs at Δf_exc = 0.8 Hz."""
    points: dict[tuple[str, int], list[Point]] = {}
    for r in range(realisations):
        for c in CASES:
            case = _make_case(c, 0.8, est_seed=100 + r, val_seed=200 + r)
            for nb in bases:
                points.setdefault((c, nb), []).append(_evaluate(case, nb))

    def cell(values: list[float], spec: str) -> str:
        v = np.asarray(values)
        return f"{np.median(v):{spec}} ({np.min(v):{spec}}–{np.max(v):{spec}})"

    lines = [
        f"Spread over {realisations} independent realisations (phases and noise of both the "
        "estimation and the validation record), Δf_exc = 0.8 Hz: median (min–max)",
        "",
        "| case | N_p | VAF % | f_n fit RMSE Hz | peak RMSE Hz | K RMSE N·m/rad |",
        "|---|---|---|---|---|---|",
    ]
    for c in CASES:
        for nb in bases:
            pts = points[(c, nb)]
            lines.append(
                f"| {c} | {nb} | {cell([p.vaf for p in pts], '.1f')} | "
                f"{cell([p.fn_rmse for p in pts], '.3f')} | "
                f"{cell([p.peak_rmse for p in pts], '.3f')} | "
                f"{cell([p.k_rmse for p in pts], '.3f')} |"
            )
    return "\n".join(lines)


def _ablation(
    cases: dict[tuple[str, float], Case], spacings: tuple[float, ...], bases: tuple[int, ...]
) -> str:
    variants: tuple[tuple[str, dict[str, Any]], ...] = (
        ("±0.5 gap + poly (paper-literal)", dict(window_lines=0.5, n_transient=2)),
        ("±1.0 gap + poly", dict(window_lines=1.0, n_transient=2)),
        ("±1.0 gap, no poly", dict(window_lines=1.0)),
        ("±1.25 gap, no poly (default)", dict()),
    )
    lines = [
        "Ablation: validation VAF % (CS1 / CS2 / CS3) by local-problem design — how far each "
        "window reaches (in line spacings each side) and whether it has a transient "
        "polynomial — against the oracle (best N_p-term Legendre expansion of the true frozen G)",
        "",
        "| Δf_exc Hz | N_p | " + " | ".join(v[0] for v in variants) + " | oracle |",
        "|---|---|" + "---|" * (len(variants) + 1),
    ]
    for s in spacings:
        for nb in bases:
            cells = []
            template = None
            for _, kw in variants:
                vals = []
                for c in CASES:
                    est, _, _ = _identify(cases[(c, s)], nb, **kw)
                    if est is None:
                        vals.append("—")
                        continue
                    template = est
                    case = cases[(c, s)]
                    vals.append(
                        f"{_vaf(case.val.position_clean_rad, est.simulate(case.val.torque_nm)):.1f}"
                    )
                cells.append(" / ".join(vals))
            if template is not None:
                oracle = " / ".join(
                    f"{_oracle_vaf(cases[(c, s)], nb, template):.1f}" for c in CASES
                )
            else:
                oracle = "—"
            lines.append(f"| {s:g} | {nb} | " + " | ".join(cells) + f" | {oracle} |")
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------
# figures (matplotlib is an optional extra: imported only here)
# ----------------------------------------------------------------------------------------


def _write_figures(
    out_dir: Path,
    cases: dict[tuple[str, float], Case],
    grids: dict[float, dict[tuple[str, int], Point]],
    bases: tuple[int, ...],
    comparison: dict[str, np.ndarray],
) -> list[Path]:
    from rtsid.tv import require_matplotlib

    figure = require_matplotlib()
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [_figure_grid(figure, out_dir, grids, bases)]
    spacing = 0.8 if 0.8 in grids else next(iter(grids))
    paths.append(_figure_resonance(figure, out_dir, cases, spacing, 10))
    dense = 0.2 if 0.2 in grids else spacing
    paths.append(_figure_image(figure, out_dir, cases, dense, 8))
    if comparison:
        paths.append(_figure_window(figure, out_dir, comparison))
    return paths


def _figure_grid(
    figure: Any,
    out_dir: Path,
    grids: dict[float, dict[tuple[str, int], Point]],
    bases: tuple[int, ...],
) -> Path:
    fig = figure.Figure(figsize=(12, 6.5), layout="constrained")
    axes = fig.subplots(2, len(CASES), sharex=True)
    colors = {0.2: "tab:blue", 0.8: "tab:orange", 1.4: "tab:green"}
    nb = np.array(bases)
    for j, c in enumerate(CASES):
        for s, grid in grids.items():
            col = colors.get(s, "k")
            vaf = np.array([grid[(c, b)].vaf for b in bases])
            peak = np.array([grid[(c, b)].peak_rmse for b in bases])
            fit = np.array([grid[(c, b)].fn_rmse for b in bases])
            axes[0, j].plot(
                nb, np.clip(vaf, -5, 100), "o-", color=col, ms=3, label=f"Δf_exc = {s:g} Hz"
            )
            axes[1, j].semilogy(nb, peak, "s--", color=col, ms=3, alpha=0.7)
            axes[1, j].semilogy(nb, fit, "o-", color=col, ms=3)
            axes[1, j].axhline(s / np.sqrt(12), color=col, lw=0.8, ls=":")
        axes[0, j].set_title(c)
        axes[0, j].set_ylim(-5, 100)
        axes[0, j].axhline(90, color="grey", lw=0.6)
        axes[1, j].axhline(0.1, color="grey", lw=0.6)
        axes[1, j].set_xlabel("N_p")
    axes[0, 0].set_ylabel("validation VAF (%)")
    axes[1, 0].set_ylabel("resonance RMSE (Hz)\n-- peak picking, — 2nd-order fit")
    axes[0, 0].legend(loc="lower right", fontsize=8)
    path = out_dir / "skirt_vaf_rmse.png"
    fig.savefig(path, dpi=100)
    return path


def _case_panels(
    figure: Any, cases: dict[tuple[str, float], Case], spacing: float, n_basis: int
) -> tuple[Any, Any, list[tuple[Any, str, Case, Any]]]:
    """A row of panels, one per case, with each case's identification (skipped if none)."""
    fig = figure.Figure(figsize=(12, 3.6), layout="constrained")
    axes = fig.subplots(1, len(CASES), sharey=True)
    panels = []
    for ax, c in zip(axes, CASES, strict=True):
        case = cases[(c, spacing)]
        est, _, _ = _identify(case, n_basis)
        if est is not None:
            panels.append((ax, c, case, est))
    return fig, axes, panels


def _figure_resonance(
    figure: Any, out_dir: Path, cases: dict[tuple[str, float], Case], spacing: float, n_basis: int
) -> Path:
    fig, axes, panels = _case_panels(figure, cases, spacing, n_basis)
    for ax, c, case, est in panels:
        ax.plot(case.t_s, case.fn_true, "k--", label="truth √(K/I)/2π")
        ax.step(
            case.t_s,
            est.resonance_from_peak(case.t_s),
            where="mid",
            alpha=0.8,
            label="peak of |G| (paper)",
        )
        ax.plot(
            case.t_s, est.fit_second_order(case.t_s).natural_frequency_hz, label="2nd-order fit"
        )
        ax.set_title(f"{c}, Δf_exc = {spacing:g} Hz, N_p = {n_basis}")
        ax.set_xlabel("time (s)")
    axes[0].set_ylabel("resonance frequency (Hz)")
    axes[0].legend(fontsize=8)
    path = out_dir / f"skirt_resonance_np{n_basis}.png"
    fig.savefig(path, dpi=100)
    return path


def _figure_image(
    figure: Any, out_dir: Path, cases: dict[tuple[str, float], Case], spacing: float, n_basis: int
) -> Path:
    fig, axes, panels = _case_panels(figure, cases, spacing, n_basis)
    for ax, c, case, est in panels:
        f = est.frequencies_hz
        df = f[1] - f[0]
        g_db = 20 * np.log10(np.abs(est.G(case.t_s)).T)
        img = ax.imshow(
            g_db,
            aspect="auto",
            origin="lower",
            cmap="viridis",
            interpolation="nearest",
            vmin=-45,
            vmax=15,
            extent=(case.t_s[0], case.t_s[-1], f[0] - df / 2, f[-1] + df / 2),
        )
        ax.plot(case.t_s, case.fn_true, "w--", lw=0.8)
        ax.set_title(f"|G(jω, t)| {c}, Δf_exc = {spacing:g} Hz, N_p = {n_basis}")
        ax.set_xlabel("time (s)")
    axes[0].set_ylabel("frequency (Hz)")
    fig.colorbar(img, ax=list(axes), label="dB re 1 rad/(N·m)")
    path = out_dir / "skirt_G_image.png"
    fig.savefig(path, dpi=100)
    return path


def _figure_window(figure: Any, out_dir: Path, data: dict[str, np.ndarray]) -> Path:
    fig = figure.Figure(figsize=(9, 5.5), layout="constrained")
    ax_k, ax_e = fig.subplots(2, 1, sharex=True)
    t = data["t_s"]
    ax_k.plot(t, data["k_true"], "k--", label="truth")
    ax_k.plot(t, data["k_window"], label="windowed (EUREKA IRF + fit), 5 s windows")
    ax_k.plot(t, data["k_skirt"], label=f"{data['skirt_label']} + 2nd-order fit")
    ax_k.set_ylabel("K (N·m/rad)")
    ax_k.set_title("CS3, Δf_exc = 0.8 Hz, SNR 22 dB: stiffness tracks")
    ax_k.legend(fontsize=8)
    ax_e.plot(t, data["k_window"] - data["k_true"], label="windowed")
    ax_e.plot(t, data["k_skirt"] - data["k_true"], label="skirt")
    ax_e.axhline(0, color="k", lw=0.6)
    ax_e.set_ylabel("K error (N·m/rad)")
    ax_e.set_xlabel("time (s)")
    ax_e.legend(fontsize=8)
    path = out_dir / "skirt_vs_window_cs3.png"
    fig.savefig(path, dpi=100)
    return path
