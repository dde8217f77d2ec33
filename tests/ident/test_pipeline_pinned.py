"""The window pipeline's numbers do not move: every case of ``data/pipeline_pinned.py``
(``estimate_window`` and ``sliding_estimates`` on simulated windows and on the shared real
recording) is recomputed and compared with the numbers that script stored, for the kernel
this process runs (compiled, or numpy with ``RTSID_NUMPY_ONLY=1``)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).resolve().parent / "data"
_spec = importlib.util.spec_from_file_location("pipeline_pinned", DATA / "pipeline_pinned.py")
assert _spec is not None and _spec.loader is not None
pinned = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(pinned)

WINDOW_CASES = [name for name, _ in pinned.window_cases()]
STREAM_CASES = [name for name, _ in pinned.stream_cases(None)]
REKLAB_WINDOWS = ("reklab_window_5", "reklab_window_12.099", "reklab_window_40")
#: How far a pinned number may move, relative to the largest of its field: rounding only. The
#: same code and packages round differently on another machine: on an AMD EPYC (AVX-512) the
#: stream cases' IRFs are 1.8e-12 of their field from the numbers pinned on the machine before
#: (the same with numpy's AVX-512 kernels and OpenBLAS's switched off, and with numpy 2.3
#: instead of 2.4; the compiled kernel is built without FMA or contraction, so what differs is
#: below rtsid, e.g. libm), and the deconvolution amplifies a last-bit difference. A change of
#: method or of summation order in rtsid's own code moves them by far more, or it is rounding.
RTOL = 1e-10
#: The log-magnitude fit is Nelder–Mead stopped at a relative step of 1e-7 (``fit_logmag``):
#: its numbers are known to that tolerance, not to rounding (the numpy path's moved by 1.4e-8
#: between the two machines above).
NELDER_MEAD_RTOL = 1e-6


@pytest.fixture(scope="module")
def expected():
    """The stored numbers of this process's kernel, by case and field."""
    prefix = pinned.kernel()
    with np.load(pinned.PINNED) as data:
        arrays = {key: data[key] for key in data.files if key.startswith(prefix + "/")}
    cases: dict[str, dict[str, np.ndarray]] = {}
    for key, value in arrays.items():
        _, case, field = key.split("/")
        cases.setdefault(case, {})[field] = value
    return cases


def assert_same(case, got, want):
    rtol = NELDER_MEAD_RTOL if "logmag" in case else RTOL
    assert want, f"{case} is not in {pinned.PINNED.name}: regenerate it with its script"
    assert sorted(got) == sorted(want), case
    for field, value in got.items():
        stored = want[field]
        assert np.shape(value) == stored.shape, f"{case}.{field}: shape"
        if stored.dtype.kind in "fc":
            finite = np.abs(stored[np.isfinite(stored)])
            scale = float(finite.max()) if finite.size else 0.0
            np.testing.assert_allclose(
                value, stored, rtol=rtol, atol=rtol * scale, err_msg=f"{case}.{field}"
            )
        else:
            np.testing.assert_array_equal(value, stored, err_msg=f"{case}.{field}")


@pytest.mark.parametrize("case", WINDOW_CASES)
def test_estimate_window_gives_the_pinned_numbers(case, expected):
    thunk = dict(pinned.window_cases())[case]
    assert_same(case, pinned.record_window(thunk), expected.get(case, {}))


@pytest.mark.parametrize("case", STREAM_CASES)
def test_sliding_estimates_give_the_pinned_numbers(case, expected):
    thunk = dict(pinned.stream_cases(None))[case]
    got = pinned.record_stream(thunk(), pinned.IRF_EVERY.get(case, pinned.IRF_EVERY_SIMULATED))
    assert_same(case, got, expected.get(case, {}))


def test_the_real_recording_gives_the_pinned_numbers(reklab_path, expected):
    thunk = dict(pinned.stream_cases(reklab_path))["reklab"]
    got = pinned.record_stream(thunk(), pinned.IRF_EVERY["reklab"])
    assert got["scalars"].shape[0] > 500  # 596 windows of 300 ms every 0.1 s
    assert_same("reklab", got, expected.get("reklab", {}))
    windows = dict(pinned.reklab_window_cases(reklab_path))
    assert sorted(windows) == sorted(REKLAB_WINDOWS)
    for case, window in windows.items():
        assert_same(case, pinned.record_window(window), expected.get(case, {}))


def test_the_cases_cover_every_criterion_lost_samples_holds_and_withheld_windows(expected):
    methods = {str(d["texts"][2]) for d in expected.values() if d["texts"].ndim == 1}
    assert {"output_error", "linear", "logmag"} <= methods
    reasons = {str(d["texts"][0]) for d in expected.values() if d["texts"].ndim == 1}
    assert {"no_excitation", "nan"} <= reasons
    assert expected["lost"]["ints"][0] > 0  # lost samples bridged
    assert expected["held_inertia_damping"]["ints"].tolist()[1:] == [1, 1]
    assert (expected["stream_default"]["ints"][:, 1] == 1).any()  # the stream learned a hold
    assert np.isnan(expected["lost"]["scalars"]).sum() == 0
