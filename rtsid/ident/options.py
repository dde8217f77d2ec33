"""Options of the window pipeline: :class:`EstimatorOptions` (the ``[estimator]`` section).

Every step of :func:`rtsid.ident.window.estimate_window` reads its settings from one frozen
:class:`EstimatorOptions`, checked once when it is made: a bad value is refused there with the
field's name, never half-way through a window.
"""

from __future__ import annotations

from dataclasses import dataclass

from rtsid.errors import invalid, require_choice, require_range

__all__ = ["FIT_METHODS", "HOLD_CHOICES", "EstimatorOptions"]


FIT_METHODS = ("output_error", "relative", "logmag")
HOLD_CHOICES = ("none", "inertia", "inertia_damping")


@dataclass(frozen=True)
class EstimatorOptions:
    """Options of :func:`~rtsid.ident.window.estimate_window` (the ``[estimator]`` section).

    The defaults need no preset: the analysis is planned from the perturbation's spectrum
    (:mod:`rtsid.ident.analysis`), so a 1 kHz PRBS recording and a 2500 Hz robot with a
    40 Hz band both work as they are. Set a value to override the choice.

    Attributes
    ----------
    lag_s : float
        IRF lag span: lags ``−lag_s … +lag_s``.
    lowpass_hz : float or None
        −6 dB cut-off of the band-limiting FIR applied to both signals, Hz
        (None: 1.5 × the perturbation's band edge).
    analysis_fs_hz : float or None
        Decimate to about this rate (None: at least 10 × the cut-off).
    ridge : float
        Relative diagonal loading of ``R_uu`` (stabilises the recursion where the
        perturbation has little power).
    refine : int
        Refinement sweeps removing the Toeplitz approximation's edge bias
        (see :func:`rtsid.ident.irf.estimate_irf`).
    fit_method : {"output_error", "relative", "logmag"}
        Output error (minimum torque prediction error; default), the closed-form fit of the
        IRF's response weighted by ``1/|Z|``, or the source's log-magnitude Nelder–Mead.
    fit_band_hz : (float, float) or None
        Frequencies of the relative and log-magnitude fits (None: 1 Hz to the cut-off).
    fit_points : int
        Frequencies in their grid.
    weight_power : float
        Their weights: the input's amplitude spectrum to this power.
    torque_sign : float
        +1, or −1 for rigs that report torque inverted.
    detrend : {"linear", "mean", "none"}
        Trend removed from both signals before filtering (the output-error fit also carries
        an offset and a trend as nuisance terms, so what is left cannot bias it).
    uncertainty : bool
        Compute standard errors.
    min_excitation_rad : float
        Windows whose position standard deviation is below this are withheld
        (``reason="no_excitation"``).
    min_relative_excitation : float
        In a stream of windows (:class:`~rtsid.ident.stream.WindowStream`), a window whose
        band-limited position varies by less than this fraction of the median of the last
        ``hold_horizon_s`` of windows is withheld too (``reason="no_excitation"``): the
        perturbation paused, and what the torque does then says nothing about stiffness
        (0: no such check).
    max_lost_percent : float
        A window may have up to this share of lost samples, bridged by sums over valid
        samples only (:mod:`rtsid.ident.gaps`); more withholds it (``reason="gap"``).
    max_gap_s : float
        Longest run of lost samples that is bridged, s.
    hold : {"none", "inertia", "inertia_damping"}
        Parameters held at a value learned over ``hold_horizon_s`` (or at ``hold_inertia``)
        instead of fitted per window; K always stays per window. Streams (the worker,
        ``rtsid identify``, replay) learn the value; a lone ``estimate_window`` call holds
        only what it is given.
    hold_horizon_s : float
        Horizon of the learned values (median of the full fits over the last this many
        seconds of windows).
    hold_inertia : float or None
        A fixed inertia to hold, kg·m² (e.g. from a calibration); None: learned.
    low_vaf_percent : float
        An estimate whose ``vaf`` is below this carries the ``low_vaf`` flag.
    """

    lag_s: float = 0.02
    lowpass_hz: float | None = None
    analysis_fs_hz: float | None = None
    ridge: float = 1e-3
    refine: int = 3
    fit_method: str = "output_error"
    fit_band_hz: tuple[float, float] | None = None
    fit_points: int = 30
    weight_power: float = 0.5
    torque_sign: float = 1.0
    detrend: str = "linear"
    uncertainty: bool = True
    min_excitation_rad: float = 1e-5
    min_relative_excitation: float = 0.1
    max_lost_percent: float = 2.0
    max_gap_s: float = 0.004
    hold: str = "inertia_damping"
    hold_horizon_s: float = 20.0
    hold_inertia: float | None = None
    low_vaf_percent: float = 50.0

    def __post_init__(self) -> None:
        if self.fit_method == "linear":  # the name before output error (recordings keep it)
            object.__setattr__(self, "fit_method", "relative")
        require_range("lag_s", self.lag_s, 0.0, low_inclusive=False)
        if self.lowpass_hz is not None:
            require_range("lowpass_hz", self.lowpass_hz, 0.0, low_inclusive=False)
        if self.analysis_fs_hz is not None:
            require_range("analysis_fs_hz", self.analysis_fs_hz, 0.0, low_inclusive=False)
        require_range("ridge", self.ridge, 0.0)
        require_range("refine", self.refine, 0)
        require_choice("fit_method", self.fit_method, FIT_METHODS)
        require_choice("torque_sign", self.torque_sign, (1.0, -1.0))
        require_choice("detrend", self.detrend, ("linear", "mean", "none"))
        require_choice("hold", self.hold, HOLD_CHOICES)
        require_range("hold_horizon_s", self.hold_horizon_s, 0.0, 3600.0, low_inclusive=False)
        if self.hold_inertia is not None:
            require_range("hold_inertia", self.hold_inertia, 0.0, low_inclusive=False)
            if self.hold == "none":
                raise invalid(
                    "hold_inertia",
                    self.hold_inertia,
                    "no value while hold = 'none' (set hold = 'inertia' to hold it)",
                )
        require_range("low_vaf_percent", self.low_vaf_percent, 0.0, 100.0)
        require_range("fit_points", self.fit_points, 3)
        require_range("min_excitation_rad", self.min_excitation_rad, 0.0)
        require_range("min_relative_excitation", self.min_relative_excitation, 0.0, 1.0)
        require_range("max_lost_percent", self.max_lost_percent, 0.0, 100.0)
        require_range("max_gap_s", self.max_gap_s, 0.0, 1.0)
        if self.fit_band_hz is not None:
            object.__setattr__(self, "fit_band_hz", tuple(self.fit_band_hz))
            self._check_fit_band(self.fit_band_hz)

    def _check_fit_band(self, band: tuple[float, float]) -> None:
        lo, hi = band
        if not 0 <= lo < hi:
            raise invalid("fit_band_hz", band, "(low, high) with 0 <= low < high")
        if self.lowpass_hz is not None and hi > self.lowpass_hz:
            raise invalid("fit_band_hz", band, f"a band below lowpass_hz = {self.lowpass_hz} Hz")
