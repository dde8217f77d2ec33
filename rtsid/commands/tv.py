"""``rtsid tv REC``: time-varying identification (skirt decomposition) of a multisine record
(``.npz`` experiment or rtsid ``.mcap`` recording)."""

from __future__ import annotations

import argparse
import sys
import warnings

from rtsid.commands.common import add_output, deprecation_note
from rtsid.errors import InputDataError
from rtsid.ident.skirt import AUTO_MAX_BASIS, BASIS_FAMILIES, SkirtConditioningWarning
from rtsid.ident.skirt import WARN_VARIANCE_INFLATION as WARN
from rtsid.sim.ltv import STUDY_CASES

#: ``--basis-family`` values: ``auto`` (the default) chooses among the families.
FAMILY_CHOICES = ("auto", *BASIS_FAMILIES)


def auto_range_text() -> str:
    """The N_p each family's automatic search covers, as ``--help`` says it."""
    return ", ".join(f"{family} 1…{AUTO_MAX_BASIS[family]}" for family in BASIS_FAMILIES)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "recording",
        nargs="?",
        help=".npz with torque_nm, position_rad, fs_hz, excited_bins, period_samples; or an "
        "rtsid .mcap recording whose config declares [plant.torque_multisine]",
    )
    parser.add_argument(
        "--basis",
        "-p",
        default="auto",
        metavar="N_P",
        help="basis functions N_p, or 'auto' (default): per family every N_p of "
        f"{auto_range_text()} whose local problems are well conditioned (variance inflation "
        f"≤ {WARN:g}; where the line spacing allows fewer, the output says so and why), the "
        "one of best predicted validation VAF",
    )
    parser.add_argument(
        "--basis-family",
        choices=FAMILY_CHOICES,
        default="auto",
        help="time basis: auto (default: the family of best predicted validation VAF; with a "
        "fixed N_p, legendre), legendre (smooth, slow change), fourier (periodic change with "
        "whole cycles in the record: cyclic tasks, gait), bspline (local changes)",
    )
    parser.add_argument(
        "--transient",
        type=int,
        metavar="DEG",
        help="add a transient polynomial of this degree (default: none)",
    )
    parser.add_argument(
        "--trim",
        action="store_true",
        help=".npz: keep only the whole multisine periods at the start (.mcap: always the "
        "longest run of whole periods without lost samples)",
    )
    parser.add_argument(
        "--times", type=int, default=11, metavar="N", help="rows of the printed track (11)"
    )
    parser.add_argument(
        "--common-inertia",
        action="store_true",
        default=True,
        help="hold the inertia constant over time in the K/B/I fit (the default: a joint's "
        "does not change)",
    )
    parser.add_argument(
        "--free-inertia",
        dest="common_inertia",
        action="store_false",
        help="fit the inertia at each time, like K",
    )
    parser.add_argument(
        "--common-damping", action="store_true", help="hold the damping constant over time too"
    )
    parser.add_argument("--plot", metavar="PNG", help="write |G(jω,t)|, K(t), f_n(t) here")
    add_output(
        parser,
        "write the K, B, I, f_n track here as CSV (columns in docs/skirt.md)",
        metavar="CSV",
        old=("--csv",),
    )
    sim = parser.add_argument_group("simulated experiment (the published study)")
    sim.add_argument(
        "--simulate",
        choices=tuple(STUDY_CASES),
        help="simulate this case and write it to --save-simulation instead of reading a file "
        "(CS1–CS3: the published study; SIN2: K(t) sinusoidal, two cycles per record)",
    )
    sim.add_argument("--save-simulation", metavar="NPZ", help="where --simulate writes")
    sim.add_argument(
        "--spacing",
        type=float,
        default=0.8,
        metavar="HZ",
        help="distance between excited lines Δf_exc (0.8)",
    )
    sim.add_argument("--snr", type=float, default=22.0, metavar="DB", help="output SNR (22)")
    sim.add_argument("--seed", type=int, default=1, help="phases and noise seed (1)")


def _old_simulation_output(args: argparse.Namespace) -> None:
    """``--simulate CASE -o FILE.npz`` (before -o meant the track, as in every command): the
    simulation's file, for one more release, with the deprecation note."""
    if args.save_simulation is None and str(args.output or "").lower().endswith(".npz"):
        print(deprecation_note("-o FILE.npz with --simulate", "--save-simulation"), file=sys.stderr)
        args.save_simulation, args.output = args.output, None


def run(args: argparse.Namespace) -> int:
    from rtsid import tv

    if args.plot:
        tv.require_matplotlib()  # fail before the work, not after
        if args.simulate and not args.recording:
            npz = args.output or "X.npz"
            raise InputDataError(
                "--plot draws the identification of a recording; give the file --simulate "
                f"writes as the recording too: rtsid tv --simulate {args.simulate} -o {npz} "
                f"{npz} --plot {args.plot}"
            )
    if args.simulate:
        _old_simulation_output(args)
        if not args.save_simulation:
            raise InputDataError(
                "--simulate needs --save-simulation FILE.npz to write the experiment to"
            )
        tv.simulate_to_npz(
            args.simulate,
            args.save_simulation,
            spacing_hz=args.spacing,
            snr_db=args.snr,
            seed=args.seed,
        )
        print(
            f"wrote {args.save_simulation}: case {args.simulate}, lines {args.spacing:g} Hz "
            f"apart, SNR {args.snr:g} dB; identify it with: rtsid tv {args.save_simulation}"
        )
        if not args.recording:
            return 0
    if not args.recording:
        raise InputDataError(
            f"give a recording (.npz or .mcap), or --simulate {'|'.join(STUDY_CASES)} "
            "--save-simulation FILE.npz"
        )
    data = tv.load_tv(args.recording, trim=args.trim)
    if data.selection:
        print(f"used {data.selection}")
    family = args.basis_family
    estimate = None
    if args.basis == "auto":
        families = BASIS_FAMILIES if family == "auto" else (family,)
        chosen = tv.choose_model(data, families=families, n_transient=args.transient)
        print(tv.format_choice(chosen))
        n_basis, family = chosen.chosen.n_basis, chosen.chosen.basis_family
        estimate = chosen.estimate
    elif args.basis.isdigit() and int(args.basis) >= 1:
        n_basis = int(args.basis)
        family = BASIS_FAMILIES[0] if family == "auto" else family
    else:
        raise InputDataError(f"--basis must be a positive integer or 'auto', got {args.basis!r}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SkirtConditioningWarning)
        common = ("inertia",) * args.common_inertia + ("damping",) * args.common_damping
        result = tv.identify_recording(
            data,
            n_basis=n_basis,
            n_transient=args.transient,
            common=common,
            basis_family=family,
            estimate=estimate,
        )
    for w in caught:
        print(f"rtsid tv: warning: {w.message}", file=sys.stderr)
    print(tv.format_report(result, rows=max(2, args.times)))
    if args.plot:
        print(f"figure: {tv.plot_result(result, args.plot)}")
    if args.output:
        print(f"track: {tv.write_track_csv(result, args.output)}")
    return 0
