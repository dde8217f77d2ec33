"""Filter designs without scipy.signal's import: numpy's firwin and the design cache."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from rtsid.ident import designs
from rtsid.ident.designs import CACHE_ENV, cache_folder, design, firwin_lowpass
from rtsid.ident.filters import band_limit_taps, lowpass_taps
from rtsid.ident.levinson import HAVE_COMPILED_KERNEL

#: The designs rtsid asks the cache for (rtsid/ident/reflex.py and yardstick.py), with the
#: arguments it uses: the decimator at each factor up to 25 (2500 Hz → 100 Hz), its initial
#: conditions and impulse response, the yardstick's filters at common rates.
_SOS_25 = signal.cheby1(8, 0.05, 0.8 / 25, output="sos")
_IMPULSE = np.zeros(400 * 25)
_IMPULSE[0] = 1.0
CACHED = [
    *[("cheby1", (8, 0.05, 0.8 / f), {"output": "sos"}) for f in (2, 5, 10, 25)],
    ("sosfilt_zi", (_SOS_25,), {}),
    ("sosfilt", (_SOS_25, _IMPULSE), {}),
    *[("savgol_coeffs", (11, 3), {"deriv": d, "delta": 1 / 2500.0}) for d in (1, 2)],
    ("butter", (4, 40.0), {"fs": 1000.0, "output": "sos"}),
]


def _bits(a: np.ndarray) -> tuple[str, tuple[int, ...], bytes]:
    return a.dtype.str, a.shape, a.tobytes()


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A design cache of this test's own, and a count of the designs scipy computed."""
    folder = tmp_path / "designs"
    monkeypatch.setenv(CACHE_ENV, str(folder))
    computed: list[str] = []
    compute = designs._computed

    def counted(function, args, kwargs):
        computed.append(function)
        return compute(function, args, kwargs)

    monkeypatch.setattr(designs, "_computed", counted)
    return folder, computed


# ---------------------------------------------------------------------------- firwin
def _rtsid_firwin_arguments():
    """(numtaps, cutoff_hz, fs_hz) as band_limit_taps and lowpass_taps form them, over rates,
    decimations and cut-offs across the whole allowed range."""
    rng = np.random.default_rng(7)
    for fs in (100.0, 500.0, 1000.0, 1024.0, 2000.0, 2500.0, 4000.0, 10000.0, 2500.5):
        for factor in (1, 2, 3, 5, 8, 25):
            nyq_after = fs / (2 * factor)
            for frac in [*np.linspace(0.02, 0.98, 9), *rng.uniform(0.005, 0.995, 4)]:
                cutoff = float(frac * nyq_after)
                band = min(4.0 * cutoff, 2.0 * (nyq_after - cutoff))
                yield int(np.ceil(3.3 * fs / band)) | 1, cutoff, fs
                wide = nyq_after - cutoff
                yield int(np.ceil(3.3 * fs / wide)) | 1, (cutoff + nyq_after) / 2, fs


def test_numpys_firwin_is_scipys_bit_for_bit_over_the_arguments_rtsid_uses():
    cases = [c for c in _rtsid_firwin_arguments() if c[0] <= 8001]
    assert len(cases) > 1000
    differ = [
        (n, cutoff, fs)
        for n, cutoff, fs in cases
        if _bits(firwin_lowpass(n, cutoff, fs))
        != _bits(signal.firwin(n, cutoff, fs=fs, window="hamming"))
    ]
    assert not differ, differ[:5]


def test_numpys_firwin_takes_numpy_scalars_and_integer_rates_as_scipy_does():
    for n, cutoff, fs in [(3, 10.0, 100), (31, np.float64(37.5), np.float64(2500.0)), (9, 1, 4)]:
        assert _bits(firwin_lowpass(n, cutoff, fs)) == _bits(
            signal.firwin(n, cutoff, fs=fs, window="hamming")
        )


def test_the_estimators_fir_filters_are_scipys_firwin():
    got = band_limit_taps(2500.0, 87.5, 5)
    assert _bits(got) == _bits(signal.firwin(got.size, 87.5, fs=2500.0, window="hamming"))
    got = lowpass_taps(1000.0, 30.0, 2)
    want = signal.firwin(got.size, (30.0 + 250.0) / 2, fs=1000.0, window="hamming")
    assert _bits(got) == _bits(want)


# ------------------------------------------------------------------------- the cache
@pytest.mark.parametrize(("function", "args", "kwargs"), CACHED, ids=lambda v: str(v)[:12])
def test_a_design_is_scipys_computed_then_read_back_bit_for_bit(cache, function, args, kwargs):
    folder, computed = cache
    want = np.asarray(getattr(signal, function)(*args, **kwargs), dtype=np.float64)
    first, again = design(function, *args, **kwargs), design(function, *args, **kwargs)
    assert _bits(first) == _bits(want) and _bits(again) == _bits(want)
    assert computed == [function]  # the second came from the cache
    assert len(list(folder.glob("*.design"))) == 1
    again[...] = 0.0  # each call's array is the caller's own
    assert _bits(design(function, *args, **kwargs)) == _bits(want)


def test_other_arguments_are_another_entry(cache):
    folder, computed = cache
    a = design("cheby1", 8, 0.05, 0.8 / 25, output="sos")
    b = design("cheby1", 8, 0.05, 0.8 / 24, output="sos")
    c = design("cheby1", 8, 0.05, 0.8 / 25, output="sos")
    assert computed == ["cheby1", "cheby1"] and len(list(folder.glob("*.design"))) == 2
    assert _bits(a) == _bits(c) and _bits(a) != _bits(b)
    # an int and a float of the same value are other arguments (scipy may treat them apart)
    design("savgol_coeffs", 11, 3, deriv=1, delta=1.0)
    design("savgol_coeffs", 11, 3, deriv=1, delta=1)
    assert computed[-2:] == ["savgol_coeffs", "savgol_coeffs"]


def _one_entry(folder: Path) -> Path:
    (entry,) = folder.glob("*.design")
    return entry


@pytest.mark.parametrize(
    "damage",
    [
        lambda blob: blob[: len(blob) - 8],  # cut short
        lambda blob: blob[:-1] + bytes([blob[-1] ^ 1]),  # one bit of the data flipped
        lambda blob: b"garbage",  # not an entry at all
        lambda blob: blob.replace(b'"shape": [', b'"shape": ["x", '),  # a bad header
        lambda blob: b"",  # empty
    ],
    ids=["truncated", "bit_flip", "garbage", "bad_header", "empty"],
)
def test_a_corrupt_entry_is_computed_again_and_rewritten(cache, damage):
    folder, computed = cache
    want = design("cheby1", 8, 0.05, 0.8 / 25, output="sos")
    entry = _one_entry(folder)
    entry.write_bytes(damage(entry.read_bytes()))
    assert _bits(design("cheby1", 8, 0.05, 0.8 / 25, output="sos")) == _bits(want)
    assert computed == ["cheby1", "cheby1"]
    assert _bits(design("cheby1", 8, 0.05, 0.8 / 25, output="sos")) == _bits(want)
    assert computed == ["cheby1", "cheby1"]  # the rewritten entry is read


def test_an_entry_of_another_scipy_is_stale_and_not_read(cache, monkeypatch):
    folder, computed = cache
    design("butter", 4, 40.0, fs=1000.0, output="sos")
    installed = _one_entry(folder)
    monkeypatch.setattr(designs, "_versions", lambda: "scipy 0.0.1 numpy 0.0.1 x86_64")
    design("butter", 4, 40.0, fs=1000.0, output="sos")
    assert computed == ["butter", "butter"]
    (other,) = set(folder.glob("*.design")) - {installed}  # one entry per scipy
    # an entry whose own key names another scipy is not read either (a file moved in place)
    installed.replace(other)
    design("butter", 4, 40.0, fs=1000.0, output="sos")
    assert computed == ["butter", "butter", "butter"]


def test_an_unwritable_cache_computes_every_design_and_never_fails(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    monkeypatch.setenv(CACHE_ENV, str(blocker / "designs"))  # its folder cannot be made
    want = signal.cheby1(8, 0.05, 0.8 / 25, output="sos")
    assert _bits(design("cheby1", 8, 0.05, 0.8 / 25, output="sos")) == _bits(want)
    assert blocker.read_text() == "not a folder"


def test_scipys_own_errors_reach_the_caller(cache):
    with pytest.raises(ValueError):
        design("cheby1", 8, 0.05, 1.5, output="sos")  # a cut-off above Nyquist
    assert not list(cache[0].glob("*"))


def test_the_cache_folder_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.delenv(CACHE_ENV, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_folder() == tmp_path / "xdg" / "rtsid" / "designs"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_folder() == tmp_path / "home" / ".cache" / "rtsid" / "designs"
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "mine"))
    assert cache_folder() == tmp_path / "mine"
    monkeypatch.setenv(CACHE_ENV, "off")
    assert cache_folder() is None


def test_with_the_cache_off_nothing_is_read_or_written(tmp_path, monkeypatch):
    monkeypatch.setenv(CACHE_ENV, "off")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("HOME", str(tmp_path))
    want = signal.savgol_coeffs(11, 3, deriv=2, delta=0.001)
    assert _bits(design("savgol_coeffs", 11, 3, deriv=2, delta=0.001)) == _bits(want)
    assert not list(tmp_path.rglob("*"))


def test_arguments_the_cache_cannot_key_are_computed_and_not_stored(cache):
    folder, computed = cache
    want = signal.firwin(11, [0.2], window="hamming")
    assert _bits(design("firwin", 11, [0.2], window="hamming")) == _bits(want)  # a list
    assert computed == ["firwin"] and not list(folder.glob("*"))


# --------------------------------------------------------------- what a replay imports
@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """The bench's simulated recording (slow lane on), 6 s: two reflex fits."""
    from rtsid.benchmarks.replay import _recording

    path, _, _ = _recording(tmp_path_factory.mktemp("recording"), 6.0)
    return path


def _replay_in_a_fresh_process(
    recording: Path, cache_dir: Path, numpy_only: bool = False
) -> list[str]:
    code = (
        "import sys, json; from pathlib import Path; from rtsid.replay import replay_file; "
        "r = replay_file(Path(sys.argv[1])); "
        "drop = {'compute_ms', 'host_time_ns', 'fit_ms', 'latency_ms'}; "
        "rows = [{k: v for k, v in m.items() if k not in drop} for m in r.messages + r.reflex]; "
        "print(json.dumps(rows, sort_keys=True, default=repr)); "
        "print(sorted(m for m in ('scipy', 'scipy.signal') if m in sys.modules))"
    )
    env = {**__import__("os").environ, CACHE_ENV: str(cache_dir)}
    if numpy_only:
        env["RTSID_NUMPY_ONLY"] = "1"
    done = subprocess.run(
        [sys.executable, "-c", code, str(recording)],
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
        env=env,
    )
    return done.stdout.splitlines()


@pytest.mark.parametrize("numpy_only", [False, True], ids=["compiled", "numpy_only"])
def test_a_replay_with_the_designs_cached_imports_no_scipy_and_gives_the_same_numbers(
    tmp_path, recording, numpy_only
):
    if not numpy_only and not HAVE_COMPILED_KERNEL:  # this process runs the numpy path
        pytest.skip(
            "the compiled kernel is not built (or RTSID_NUMPY_ONLY=1): numpy_only covers it"
        )
    cold = _replay_in_a_fresh_process(recording, tmp_path / "designs", numpy_only)
    assert list((tmp_path / "designs").glob("*.design"))  # the first run stored its designs
    warm = _replay_in_a_fresh_process(recording, tmp_path / "designs", numpy_only)
    off = _replay_in_a_fresh_process(recording, Path("off"), numpy_only)
    assert cold[-1] == off[-1] == "['scipy', 'scipy.signal']"
    if not numpy_only:  # (the numpy path filters with scipy.signal's sosfilt as its reference)
        assert warm[-1] == "[]", warm[-1]  # neither scipy nor scipy.signal
    assert '"K"' in warm[0] and '"variant"' in warm[0]  # estimates and reflex fits
    assert warm[0] == cold[0] == off[0]  # every one of their numbers, bit for bit (JSON)
