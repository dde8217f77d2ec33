/*
 * EUREKA (Wiggins & Robinson 1965; Levinson 1947) for a symmetric Toeplitz system R x = b.
 *
 * Compiled kernel behind rtsid.ident.levinson.eureka; the pure-numpy version in levinson.py
 * is the reference and the fallback when this module cannot be built. Only the buffer
 * protocol is used (no numpy headers). The GIL is released only for large systems: for the
 * small per-window systems, handing it over costs the caller a switch interval.
 *
 * Also the per-window pipeline of rtsid.ident.window: window_irf (front end: detrend, FIR
 * decimation, correlations, EUREKA and refinement, with std(u) and the trends' slopes),
 * band_limit (a torque explained elsewhere, band-limited like the window's), window_fit (the
 * relative fit's back end), oe_design / oe_fit / oe_vafs (the output-error back end in three
 * calls) and oe_window (the same in one call, with the full fit the held parameters learn
 * from and the newest hop's K: rtsid.ident.fused), reflex_rect_hop (the fast lane's reflex
 * prediction, one hop of rtsid.ident.reflex.ReflexStream); the numpy stages are their tested
 * reference.
 *
 * solve(r, b, x, work) -> (status, alpha)
 *   r     float64[n]  first column of R (r[0] > 0)
 *   b     float64[n]  right-hand side
 *   x     float64[n]  output: the solution
 *   work  float64[2n] scratch (prediction-error filter and reversed r)
 *   status = -1 on success, else the step k at which the prediction-error variance alpha
 *            stopped being positive (R is not positive definite); alpha is the final
 *            prediction-error variance (or the offending one).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <float.h>
#include <math.h>

/* Release the GIL only for systems this large (≈ 1 ms and up); shorter calls keep it so that
 * a latency-critical caller does not wait a whole switch interval to get it back. */
#define RELEASE_GIL_ABOVE 1000

static double dot_lanes(const double *u, const double *v, Py_ssize_t n, int *done);
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__ELF__)
#define GLUE7_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define GLUE7_CLONES
#endif
#if defined(__GNUC__) || defined(__clang__)
#define G7_QUADS 1 /* glue7 (end of file): the window path's loops four lanes wide */
typedef double g7_quad __attribute__((vector_size(32), aligned(8))); /* unaligned loads */
/* macros rather than inline functions: a vector returned by a baseline function changes its
 * ABI under AVX, which GCC warns of */
#define g7_at(p) (*(const g7_quad *)(p))
#define g7_of(x) ((g7_quad){(x), (x), (x), (x)})
/* dot_unrolled's four running sums s0 … s3 (s_i over i ≡ i mod 4) as one vector, the
 * remainder into s0, then (s0 + s1) + (s2 + s3): its result bit for bit. Inlined into the
 * clones that call it (each with its clone's instructions); g7_dot for everyone else. */
static inline __attribute__((always_inline)) double g7_dot_inline(const double *u,
                                                                  const double *v, Py_ssize_t n)
{
    g7_quad s = g7_of(0.0);
    Py_ssize_t i = 0;
    for (; i + 4 <= n; i += 4) s += g7_at(u + i) * g7_at(v + i);
    double q[4];
    memcpy(q, &s, sizeof q);
    for (; i < n; i++) q[0] += u[i] * v[i];
    return (q[0] + q[1]) + (q[2] + q[3]);
}
#define WINDOW_DOT g7_dot_inline
static double g7_dot(const double *u, const double *v, Py_ssize_t n);
static Py_ssize_t g7_fir_rows(const double *phases, const Py_ssize_t *at, const double *taps,
                              Py_ssize_t nt, Py_ssize_t m, double *out);
static Py_ssize_t g7_smooth_rows(const double *padded, const double *mirror, Py_ssize_t n,
                                 Py_ssize_t lags, double *smoothed);
static Py_ssize_t g7_predict_rows(const double *h, const double *u, Py_ssize_t nh,
                                  Py_ssize_t lag, Py_ssize_t t0, Py_ssize_t t1, double *out);
static void g7_band_powers(const double *meas, const double *err, Py_ssize_t n,
                           Py_ssize_t kmax, const double *table, double *total, double *left);
#else
#define WINDOW_DOT dot_unrolled
#endif
static void xcorr_lanes(const double *u, const double *y, Py_ssize_t n, Py_ssize_t first,
                        Py_ssize_t last, double norm, double *c); /* fits4 */

static double dot_unrolled(const double *u, const double *v, Py_ssize_t n)
{
#ifdef G7_QUADS
    return g7_dot(u, v, n); /* the same four sums, one vector (glue7) */
#endif
    int done = 0; /* the same sums in vector lanes where the compiler has them (end of file) */
    double lanes_sum = dot_lanes(u, v, n, &done);
    if (done) return lanes_sum;
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    Py_ssize_t i = 0;
    for (; i + 4 <= n; i += 4) {
        s0 += u[i] * v[i];
        s1 += u[i + 1] * v[i + 1];
        s2 += u[i + 2] * v[i + 2];
        s3 += u[i + 3] * v[i + 3];
    }
    for (; i < n; i++) {
        s0 += u[i] * v[i];
    }
    return (s0 + s1) + (s2 + s3);
}

static Py_ssize_t eureka_solve(const double *r, const double *b, double *x, double *a,
                               double *rr, Py_ssize_t n, double *alpha_out)
{
    /* rr[j] = r[n-1-j], so r[k-i] for i = 0..k-1 is rr[n-1-k .. n-2], contiguous. */
    for (Py_ssize_t j = 0; j < n; j++) {
        rr[j] = r[n - 1 - j];
    }
    double alpha = r[0];
    *alpha_out = alpha;
    if (!(alpha > 0.0)) {
        return 0;
    }
    a[0] = 1.0;
    x[0] = b[0] / alpha;
    for (Py_ssize_t k = 1; k < n; k++) {
        const double *rk = rr + (n - 1 - k);
        double refl = -dot_unrolled(a, rk, k) / alpha;
        a[k] = 0.0;
        Py_ssize_t i = 0, j = k;
        for (; i < j; i++, j--) {
            double ai = a[i], aj = a[j];
            a[i] = ai + refl * aj;
            a[j] = aj + refl * ai;
        }
        if (i == j) {
            a[i] += refl * a[i];
        }
        alpha *= (1.0 - refl * refl);
        *alpha_out = alpha;
        if (!(alpha > 0.0)) {
            return k;
        }
        double mu = (b[k] - dot_unrolled(x, rk, k)) / alpha;
        x[k] = 0.0;
        for (Py_ssize_t m = 0; m <= k; m++) {
            x[m] += mu * a[k - m];
        }
    }
    return -1;
}

static int get_doubles(PyObject *obj, Py_buffer *view, int writable, const char *name)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) != 0) {
        return -1;
    }
    if (view->itemsize != sizeof(double) || view->format == NULL || strcmp(view->format, "d") != 0) {
        PyErr_Format(PyExc_TypeError, "%s must be a contiguous float64 buffer", name);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}


/* ------------------------------------------------------------------ window front end
 * prepare_irf: detrend, FIR low-pass + decimate, correlate, EUREKA and refinement sweeps for
 * one window in one call (what rtsid.ident.window.prepare_window + irf.estimate_irf do in
 * numpy, which stays the reference). Loops are O(N·T) and O(M·L).
 */
/* kern625 (section at the end of this file): detrend_into's passes merged, the slope returned */
static double detrend_sloped(const double *x, double *out, Py_ssize_t n, double sign, int kind,
                             int want_slope);
/* where phase p of n samples in phases of factor starts (detrend_phases, fir_phases) */
static double centred_squares(Py_ssize_t n);
/* winpath (section at the end of this file): loops of the window path two lanes at a time */
static void stencil_rows(const double *u, Py_ssize_t n, double fs, double *d1, double *d2,
                         double *u0);
static void minus_line(double *out, Py_ssize_t n, double coef, double t);
static void phase_minus_line(const double *x, Py_ssize_t p, Py_ssize_t n, Py_ssize_t factor,
                             double sign, double off, double line, double t, double *phase);
static inline Py_ssize_t phase_start(Py_ssize_t p, Py_ssize_t n, Py_ssize_t factor)
{
    const Py_ssize_t rest = n % factor;
    return p * (n / factor) + (p < rest ? p : rest);
}
static double detrend_phases(const double *x, double *out, Py_ssize_t n, double sign, int kind,
                             int want_slope, Py_ssize_t factor);
static void fir_phases(const double *phases, Py_ssize_t n, const double *taps, Py_ssize_t nt,
                       Py_ssize_t factor, double *out, Py_ssize_t m);
/* kern625: the published VAF's DFT from a table of its twiddles kept per plan (band_table): for
 * each group of 4 bins and each sample, the 4 cosines then the 4 sines (the last group padded
 * with zeros) */
#define BAND_TABLE_SIZE(n, kmax) ((((kmax) + 3) / 4) * (n) * 8)
static Py_ssize_t band_powers_table(const double *meas, const double *err, Py_ssize_t n,
                                    Py_ssize_t kmax, const double *table, double *total,
                                    double *left);
static Py_ssize_t fir_decimate_lanes(const double *x, const double *taps, Py_ssize_t nt,
                                     Py_ssize_t factor, double *out, Py_ssize_t m);
/* kept for compiled callers elsewhere; the window's kernels now use the forms above */
static double line_slope(const double *x, Py_ssize_t n, double sign) __attribute__((unused));
static void detrend_into(const double *x, double *out, Py_ssize_t n, double sign, int kind)
    __attribute__((unused));
static void fir_decimate(const double *x, Py_ssize_t n, const double *taps, Py_ssize_t nt,
                         Py_ssize_t factor, double *out, Py_ssize_t m) __attribute__((unused));
/* kern625: the IRF's torque prediction and the three VAFs with the model's torque oe_fit formed */
static void irf_model_vafs(const double *u, const double *y, Py_ssize_t m, const double *h,
                           Py_ssize_t lag, double fs, const double *model, Py_ssize_t edge,
                           double *by_irf, double *vafs);

static void detrend_into(const double *x, double *out, Py_ssize_t n, double sign, int kind)
{
    (void)detrend_sloped(x, out, n, sign, kind, 0);
}

static void fir_decimate(const double *x, Py_ssize_t n, const double *taps, Py_ssize_t nt,
                         Py_ssize_t factor, double *out, Py_ssize_t m)
{
    for (Py_ssize_t k = fir_decimate_lanes(x, taps, nt, factor, out, m); k < m; k++) {
        const double *seg = x + k * factor + nt - 1;
        double acc = 0.0;
        for (Py_ssize_t j = 0; j < nt; j++) {
            acc += taps[j] * seg[-j];
        }
        out[k] = acc;
    }
    (void)n;
}

/* c[k - first] = sum_t u[t] * y[t + k] / norm for k = first..last (t over the overlap) */
static void xcorr(const double *u, const double *y, Py_ssize_t n, Py_ssize_t first,
                  Py_ssize_t last, double norm, double *c)
{
    for (Py_ssize_t k = first; k <= last; k++) {
        Py_ssize_t lo = k < 0 ? -k : 0, hi = k > 0 ? n - k : n;
        double acc = 0.0;
        for (Py_ssize_t t = lo; t < hi; t++) {
            acc += u[t] * y[t + k];
        }
        c[k - first] = acc / norm;
    }
}

/* Blocked forms of the window path's sums, bit for bit the loops they replace (the section
 * "the window path at a full-rate plan" at the end of this file). */
static void lagged_predict(const double *h, const double *u, Py_ssize_t nh, Py_ssize_t lag,
                           Py_ssize_t t0, Py_ssize_t t1, double *out);
static void xcorr_blocked(const double *u, const double *y, Py_ssize_t n, Py_ssize_t first,
                          Py_ssize_t last, double norm, double *c);
static void band_smooth(const double *row, const double *r, Py_ssize_t n, Py_ssize_t lags,
                        double *smoothed);
static Py_ssize_t eureka_filters(const double *r, double *rr, double *filters, double *alphas,
                                 Py_ssize_t n, double *alpha_out);
static void eureka_apply(const double *rr, const double *filters, const double *alphas,
                         const double *b, double *x, Py_ssize_t n);
#define FILTERS_SIZE(nh) ((nh) * ((nh) + 1) / 2 + (nh))
/* The refinement sweeps on the rows' Gram matrix (section "the sweeps on a Gram matrix" at the
 * end of this file); GRAM_SWEEPS_WORK(nh) doubles of scratch. */
static void gram_sweeps(const double *u, const double *y, Py_ssize_t m, Py_ssize_t lag,
                        const double *auto_sums, const double *cross_sums, double loading,
                        Py_ssize_t sweeps, double fs, const double *rr, const double *filters,
                        const double *alphas, double *h, double *work);
#define GRAM_SWEEPS_WORK(nh) ((nh) * (nh) + 4 * (nh))
static Py_ssize_t band_powers(const double *meas, const double *err, Py_ssize_t n,
                              Py_ssize_t kmax, const double *tw_cos, const double *tw_sin,
                              double *total, double *left);

/* work: WINDOW_IRF_WORK(n, nh) doubles */
#define WINDOW_IRF_WORK(n, nh) (2 * (n) + 3 * (nh) + FILTERS_SIZE(nh) + GRAM_SWEEPS_WORK(nh))

static Py_ssize_t window_irf_sloped(const double *pos, const double *trq, Py_ssize_t n,
                                    const double *taps, Py_ssize_t nt, Py_ssize_t factor,
                                    double sign, int kind, Py_ssize_t lag, double ridge,
                                    Py_ssize_t sweeps, double fs, double *u, double *y,
                                    Py_ssize_t m, double *h, double *phi, double *work,
                                    double *alpha, double *slopes);

/* window_irf: the front end as before (py_window_irf now calls window_irf_sloped, which also
 * hands back the trends' slopes; other compiled callers keep this one). */
__attribute__((unused)) static Py_ssize_t window_irf(const double *pos, const double *trq, Py_ssize_t n,
                             const double *taps, Py_ssize_t nt, Py_ssize_t factor, double sign,
                             int kind, Py_ssize_t lag, double ridge, Py_ssize_t sweeps,
                             double fs, double *u, double *y, Py_ssize_t m, double *h,
                             double *phi, double *work, double *alpha)
{
    return window_irf_sloped(pos, trq, n, taps, nt, factor, sign, kind, lag, ridge, sweeps, fs, u,
                             y, m, h, phi, work, alpha, NULL);
}

/* ------------------------------------------------------------------ window back end
 * window_fit: stages 5-7 of rtsid.ident.window for the linear fit, in one call: excitation
 * weights (Hann periodogram, 3-bin smoothing, interpolation onto the fit grid), the closed-form
 * weighted fit re-weighted by 1/|Z|, the IRF's and the model's torque predictions, the three
 * VAFs and the sandwich standard errors. window.fit_parameters, predict_torque,
 * standard_errors and _three_vafs are the numpy reference it is tested against.
 */
static const double STENCIL_D1[9] = {1.0 / 280, -4.0 / 105, 1.0 / 5, -4.0 / 5, 0.0,
                                     4.0 / 5, -1.0 / 5, 4.0 / 105, -1.0 / 280};
static const double STENCIL_D2[9] = {-1.0 / 560, 8.0 / 315, -1.0 / 5, 8.0 / 5, -205.0 / 72,
                                     8.0 / 5, -1.0 / 5, 8.0 / 315, -1.0 / 560};

static const double TWO_PI = 6.283185307179586476925286766559;

enum { FIT_OK = -1, FIT_FIRST_SINGULAR = 1, FIT_FINAL_SINGULAR = 2, FIT_NOT_PD = 3, FIT_ZERO_RESPONSE = 4 };

typedef struct {
    double s0, s2, s4, det;
} normal_sums_t;

/* Σw², Σw²ω², Σw²ω⁴ and the 2 × 2 determinant; 0 when (I, K) cannot be separated. */
static int normal_sums(const double *omega, const double *w, Py_ssize_t nf, normal_sums_t *q)
{
    q->s0 = q->s2 = q->s4 = 0.0;
    for (Py_ssize_t i = 0; i < nf; i++) {
        double w2 = w[i] * w[i], o2 = omega[i] * omega[i];
        q->s0 += w2;
        q->s2 += w2 * o2;
        q->s4 += w2 * o2 * o2;
    }
    q->det = q->s4 * q->s0 - q->s2 * q->s2;
    return q->det > 0.0;
}

/* (S_uu(f) / max S_uu)^power on the grid f, from the Hann-tapered periodogram of u. */
static void excitation_weights(const double *u, const double *hann, Py_ssize_t m, double fs,
                               const double *f, Py_ssize_t nf, double power, double *w,
                               double *scratch)
{
    const Py_ssize_t nbins = m / 2 + 1;
    const double df = fs / (double)m;
    double fmax = 0.0;
    for (Py_ssize_t i = 0; i < nf; i++) fmax = f[i] > fmax ? f[i] : fmax;
    Py_ssize_t need = (Py_ssize_t)(fmax / df) + 3; /* interpolation + smoothing neighbours */
    if (need > nbins) need = nbins;
    double *cos_t = scratch, *sin_t = scratch + m, *tapered = sin_t + m, *spec = tapered + m;
    for (Py_ssize_t t = 0; t < m; t++) {
        double angle = TWO_PI * (double)t / (double)m;
        cos_t[t] = cos(angle);
        sin_t[t] = sin(angle);
        tapered[t] = u[t] * hann[t];
    }
    for (Py_ssize_t k = 0; k < need; k++) {
        double re = 0.0, im = 0.0;
        Py_ssize_t idx = 0;
        for (Py_ssize_t t = 0; t < m; t++) {
            re += tapered[t] * cos_t[idx];
            im -= tapered[t] * sin_t[idx];
            idx += k;
            if (idx >= m) idx -= m;
        }
        spec[k] = re * re + im * im;
    }
    double top = 0.0;
    for (Py_ssize_t i = 0; i < nf; i++) {
        Py_ssize_t j = (Py_ssize_t)(f[i] / df);
        double value;
        if (j >= nbins - 1) {
            j = nbins - 1;
            value = (spec[j - 1] + spec[j]) / 3.0; /* right edge: spec[nbins] is 0 */
        } else {
            double left = ((j > 0 ? spec[j - 1] : 0.0) + spec[j] + spec[j + 1]) / 3.0;
            double right = (spec[j] + spec[j + 1] + (j + 2 < nbins ? spec[j + 2] : 0.0)) / 3.0;
            double xj = (double)j * df;
            double slope = (right - left) / ((double)(j + 1) * df - xj);
            value = slope * (f[i] - xj) + left;
        }
        w[i] = value;
        top = value > top ? value : top;
    }
    for (Py_ssize_t i = 0; i < nf; i++) {
        w[i] = top > 0.0 ? pow(w[i] / top, power) : 1.0;
    }
}

/* (I, B, K) of the weighted fit to z = [Re H; Im H]; with rows != NULL also the solution
 * map rows (3 × 2nf) whose product with z gives them. */
static int weighted_fit(const double *omega, const double *w, Py_ssize_t nf, const double *z,
                        double *params, double *rows)
{
    normal_sums_t q;
    if (!normal_sums(omega, w, nf, &q)) return 0;
    double r_i = 0.0, r_k = 0.0, r_b = 0.0;
    for (Py_ssize_t i = 0; i < nf; i++) {
        double w2 = w[i] * w[i], w2o2 = w2 * omega[i] * omega[i];
        double p_i = (q.s2 * w2 - q.s0 * w2o2) / q.det;
        double p_k = (q.s4 * w2 - q.s2 * w2o2) / q.det;
        double p_b = w2 * omega[i] / q.s2;
        r_i += p_i * z[i];
        r_k += p_k * z[i];
        r_b += p_b * z[nf + i];
        if (rows != NULL) {
            rows[i] = p_i;
            rows[nf + i] = 0.0;
            rows[2 * nf + i] = 0.0;
            rows[3 * nf + i] = p_b;
            rows[4 * nf + i] = p_k;
            rows[5 * nf + i] = 0.0;
        }
    }
    params[0] = r_i;
    params[1] = r_b;
    params[2] = r_k;
    return 1;
}

static int linear_fit(const double *h, Py_ssize_t nh, const double *stacked, const double *f,
                      Py_ssize_t nf, const double *base, double *params, double *sens,
                      double *scratch)
{
    double *omega = scratch, *z = omega + nf, *w = z + 2 * nf, *rows = w + nf;
    for (Py_ssize_t i = 0; i < nf; i++) omega[i] = TWO_PI * f[i];
    for (Py_ssize_t i = 0; i < 2 * nf; i++) {
        z[i] = dot_unrolled(stacked + i * nh, h, nh);
    }
    double first[3];
    if (!weighted_fit(omega, base, nf, z, first, NULL)) return FIT_FIRST_SINGULAR;
    double top = 0.0;
    for (Py_ssize_t i = 0; i < nf; i++) {
        double re = first[2] - first[0] * omega[i] * omega[i], im = first[1] * omega[i];
        w[i] = sqrt(re * re + im * im);
        top = w[i] > top ? w[i] : top;
    }
    if (!(top > 0.0)) return FIT_ZERO_RESPONSE;
    double floor = 1e-6 * top;
    for (Py_ssize_t i = 0; i < nf; i++) w[i] = base[i] / (w[i] > floor ? w[i] : floor);
    if (!weighted_fit(omega, w, nf, z, params, rows)) return FIT_FINAL_SINGULAR;
    for (int r = 0; r < 3; r++) {
        for (Py_ssize_t j = 0; j < nh; j++) {
            double acc = 0.0;
            for (Py_ssize_t i = 0; i < 2 * nf; i++) acc += rows[r * 2 * nf + i] * stacked[i * nh + j];
            sens[r * nh + j] = acc;
        }
    }
    return FIT_OK;
}

/* Measured torque, IRF prediction and model prediction at samples edge .. m-edge-1. */
static void predictions(const double *u, const double *y, Py_ssize_t m, const double *h,
                        Py_ssize_t lag, double fs, const double *params, Py_ssize_t edge,
                        double *measured, double *by_irf, double *by_model)
{
    const Py_ssize_t nh = 2 * lag + 1;
    lagged_predict(h, u, nh, lag, edge, m - edge, by_irf - edge); /* Σ_j h(j)·u(t + L − j) */
    for (Py_ssize_t t = edge; t < m - edge; t++) {
        double acc = by_irf[t - edge], d1 = 0.0, d2 = 0.0;
        for (int s = 0; s < 9; s++) {
            d1 += u[t - 4 + s] * STENCIL_D1[s];
            d2 += u[t - 4 + s] * STENCIL_D2[s];
        }
        measured[t - edge] = y[t];
        by_irf[t - edge] = acc / fs;
        by_model[t - edge] = params[0] * (d2 * (fs * fs)) + params[1] * (d1 * fs) + params[2] * u[t];
    }
}

static double centred_mean(const double *x, Py_ssize_t n)
{
    double s = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) s += x[i];
    return s / (double)n;
}

/* vaf[0] model vs measured, vaf[1] IRF vs measured, vaf[2] model vs IRF; percent. */
static void three_vafs(const double *measured, const double *by_irf, const double *by_model,
                       Py_ssize_t n, double *vaf)
{
    double mm = centred_mean(measured, n), mi = centred_mean(by_irf, n),
           mo = centred_mean(by_model, n);
    double tot_m = 0.0, tot_i = 0.0, e_model = 0.0, e_irf = 0.0, e_fit = 0.0;
    for (Py_ssize_t t = 0; t < n; t++) {
        double a = measured[t] - mm, b = by_irf[t] - mi, c = by_model[t] - mo;
        tot_m += a * a;
        tot_i += b * b;
        e_model += (a - c) * (a - c);
        e_irf += (a - b) * (a - b);
        e_fit += (b - c) * (b - c);
    }
    double totals[3] = {tot_m, tot_m, tot_i}, errors[3] = {e_model, e_irf, e_fit};
    for (int k = 0; k < 3; k++) {
        double v = 1.0 - errors[k] / totals[k];
        vaf[k] = totals[k] <= 0.0 ? 0.0 : (v > 0.0 ? v : 0.0) * 100.0;
    }
}

/* Biased autocorrelation (1/n) Σ x(t) x(t+k), k = 0..last (0 where the overlap is empty). */
static void auto_corr(const double *x, Py_ssize_t n, Py_ssize_t last, double *out)
{
    for (Py_ssize_t k = 0; k <= last; k++) {
        out[k] = k < n ? dot_unrolled(x, x + k, n - k) / (double)n : 0.0;
    }
}

/* Sandwich standard errors of (I, B, K): diag(M R⁻¹ C_φ R⁻¹ Mᵀ)·fs², C_φ from the residual's
 * Bartlett-tapered autocorrelation (see window._parameter_covariance). */
static int sandwich_errors(const double *inner_u, const double *residual, Py_ssize_t n,
                           const double *phi, const double *sens, Py_ssize_t nh, double fs,
                           double *se, double *scratch)
{
    const Py_ssize_t nl = nh < n - 1 ? nh : n - 1;
    double *phi_ee = scratch, *phi_u = phi_ee + nl + 1, *c = phi_u + nh + nl;
    double *z = c + nh, *a = z + nh, *rr = a + nh;
    auto_corr(residual, n, nl, phi_ee);
    for (Py_ssize_t k = 0; k <= nl; k++) phi_ee[k] *= 1.0 - (double)k / (double)(nl + 1);
    auto_corr(inner_u, n, nh - 1 + nl, phi_u);
    for (Py_ssize_t k = 0; k < nh; k++) {
        double acc = 0.0;
        for (Py_ssize_t l = -nl; l <= nl; l++) {
            Py_ssize_t at = k + l < 0 ? -(k + l) : k + l;
            acc += phi_u[at] * phi_ee[l < 0 ? -l : l];
        }
        c[k] = acc / (double)n;
    }
    for (int r = 0; r < 3; r++) {
        double alpha;
        if (eureka_solve(phi, sens + r * nh, z, a, rr, nh, &alpha) >= 0) return FIT_NOT_PD;
        double var = 0.0;
        for (Py_ssize_t i = 0; i < nh; i++) {
            double acc = 0.0;
            for (Py_ssize_t j = 0; j < nh; j++) acc += c[i > j ? i - j : j - i] * z[j];
            var += z[i] * acc;
        }
        var *= fs * fs;
        se[r] = var > 0.0 ? sqrt(var) : 0.0;
    }
    return FIT_OK;
}

static Py_ssize_t window_fit(const double *u, const double *y, Py_ssize_t m, const double *h,
                             Py_ssize_t lag, const double *phi, const double *stacked,
                             const double *f, Py_ssize_t nf, const double *hann, double fs,
                             double power, int uncertainty, double *params, double *sens,
                             double *out, double *work)
{
    const Py_ssize_t nh = 2 * lag + 1, edge = lag > 4 ? lag : 4, n = m - 2 * edge;
    double *base = work, *scratch = base + nf;
    excitation_weights(u, hann, m, fs, f, nf, power, base, scratch);
    Py_ssize_t status = linear_fit(h, nh, stacked, f, nf, base, params, sens, scratch);
    if (status != FIT_OK) return status;
    double *measured = scratch, *by_irf = measured + n, *by_model = by_irf + n;
    predictions(u, y, m, h, lag, fs, params, edge, measured, by_irf, by_model);
    three_vafs(measured, by_irf, by_model, n, out + 3);
    out[0] = out[1] = out[2] = NAN;
    if (!uncertainty) return FIT_OK;
    for (Py_ssize_t t = 0; t < n; t++) by_model[t] = measured[t] - by_irf[t]; /* residual */
    return sandwich_errors(u + edge, by_model, n, phi, sens, nh, fs, out, by_model + n);
}

/* ------------------------------------------------------------------ output-error back end
 * The default fit (rtsid.ident.second_order.OutputErrorDesign) and its assessment
 * (rtsid.ident.assess) for a window without lost samples, in three calls; the numpy code is
 * the reference they are tested against (RTSID_NUMPY_ONLY=1 runs it).
 *
 * oe_design: the regressors (θ̈, θ̇, θ by the 9-point stencils at samples 4 … m−5), each row and
 *   the torque with its offset and trend projected out, and their 4 × 4 Gram matrix. O(m).
 * oe_fit: (I, B, K) with the first k held, by the normalised normal equations (Gaussian
 *   elimination with partial pivoting, as LAPACK's gesv), the sandwich standard errors with
 *   the residual's Bartlett-tapered autocorrelation over `lags` lags (O(m·lags)), the model's
 *   torque and its VAF against the measured torque.
 * oe_vafs: vaf_irf and vaf_fit (the IRF's and the model's predictions over the fully supported
 *   samples, O(m·L)), and the published VAF over the DFT bins 1 … kmax (O(m·kmax)).
 */
enum { OE_OK = -1, OE_ZERO_TORQUE = 1, OE_INSEPARABLE = 2 };

/* rows[r] minus its offset and linear trend over n samples, into out[r] (as _without_trend). */
static void without_trend(const double *row, double *out, Py_ssize_t n)
{
    const double centre = (double)(n - 1) / 2.0;
    double mean = 0.0, tx = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) mean += row[i];
    mean /= (double)n;
    /* t = (double)i − centre exactly (steps of 1); Σt² the loop's exact sum (kern625) */
    double t = -centre;
    for (Py_ssize_t i = 0; i < n; i++, t += 1.0) {
        const double c = row[i] - mean;
        out[i] = c;
        tx += c * t;
    }
    const double coef = tx / centred_squares(n);
    minus_line(out, n, coef, -centre);
}

static Py_ssize_t oe_design(const double *u, const double *y, Py_ssize_t m, double fs,
                            double *regressors, double *projected, double *gram)
{
    const Py_ssize_t n = m - 8;
    double *d2 = regressors, *d1 = regressors + n, *u0 = regressors + 2 * n;
    stencil_rows(u, n, fs, d1, d2, u0);
    for (int r = 0; r < 3; r++) without_trend(regressors + r * n, projected + r * n, n);
    without_trend(y + 4, projected + 3 * n, n);
    for (int a = 0; a < 4; a++) {
        for (int b = a; b < 4; b++) {
            gram[4 * a + b] = gram[4 * b + a] =
                dot_unrolled(projected + a * n, projected + b * n, n);
        }
    }
    return gram[15] > 0.0 ? OE_OK : OE_ZERO_TORQUE;
}

/* LU with partial pivoting of the p × p matrix a (row-major, in place); piv[i] the row swapped
 * into place i; returns the determinant. */
static double lu_factor(double *a, int p, int *piv)
{
    double det = 1.0;
    for (int c = 0; c < p; c++) {
        int best = c;
        for (int r = c + 1; r < p; r++) {
            if (fabs(a[r * p + c]) > fabs(a[best * p + c])) best = r;
        }
        piv[c] = best;
        if (best != c) {
            for (int j = 0; j < p; j++) {
                double tmp = a[c * p + j];
                a[c * p + j] = a[best * p + j];
                a[best * p + j] = tmp;
            }
            det = -det;
        }
        double pivot = a[c * p + c];
        det *= pivot;
        if (pivot == 0.0) continue;
        for (int r = c + 1; r < p; r++) {
            double f = a[r * p + c] / pivot;
            a[r * p + c] = f;
            for (int j = c + 1; j < p; j++) a[r * p + j] -= f * a[c * p + j];
        }
    }
    return det;
}

static void lu_solve(const double *lu, int p, const int *piv, double *x)
{
    for (int c = 0; c < p; c++) {
        double tmp = x[c];
        x[c] = x[piv[c]];
        x[piv[c]] = tmp;
    }
    for (int r = 0; r < p; r++) {
        for (int j = 0; j < r; j++) x[r] -= lu[r * p + j] * x[j];
    }
    for (int r = p - 1; r >= 0; r--) {
        for (int j = r + 1; j < p; j++) x[r] -= lu[r * p + j] * x[j];
        x[r] /= lu[r * p + r];
    }
}

/* cov = G⁻¹·sym(M)·G⁻¹ for the free regressors x (p rows of n), G their Gram block; the
 * diagonal's square roots into se. */
static void oe_sandwich(const double *x, int p, const double *residual, Py_ssize_t n,
                        const double *g_norm_lu, const int *piv, const double *scale,
                        Py_ssize_t lags, double kept, double *se, double *scratch)
{
    if (lags > n - 1) lags = n - 1;
    double *r = scratch, *smoothed = r + lags + 1;
    for (Py_ssize_t k = 0; k <= lags; k++) {
        r[k] = dot_unrolled(residual, residual + k, n - k) / (double)n *
               (1.0 - (double)k / (double)(lags + 1)) / kept;
    }
    double middle[9], inv[9];
    for (int b = 0; b < p; b++) {
        band_smooth(x + b * n, r, n, lags, smoothed);
        for (int a = 0; a < p; a++) middle[a * p + b] = dot_unrolled(x + a * n, smoothed, n);
    }
    /* G⁻¹ = S⁻¹·N⁻¹·S⁻¹ with N the normalised Gram block (factored by the caller). */
    for (int c = 0; c < p; c++) {
        double col[3] = {0.0, 0.0, 0.0};
        col[c] = 1.0;
        lu_solve(g_norm_lu, p, piv, col);
        for (int r2 = 0; r2 < p; r2++) inv[r2 * p + c] = col[r2] / (scale[r2] * scale[c]);
    }
    for (int i = 0; i < p; i++) {
        double var = 0.0;
        for (int a = 0; a < p; a++) {
            for (int b = 0; b < p; b++) {
                var += inv[i * p + a] * 0.5 * (middle[a * p + b] + middle[b * p + a]) * inv[b * p + i];
            }
        }
        se[i] = var > 0.0 ? sqrt(var) : 0.0;
    }
}

/* VAF, %, of `predicted` against `measured` (n samples), as rtsid.ident.vaf.vaf. */
static double vaf_of(const double *measured, const double *predicted, Py_ssize_t n)
{
    double mm = 0.0, me = 0.0;
    for (Py_ssize_t t = 0; t < n; t++) {
        mm += measured[t];
        me += measured[t] - predicted[t];
    }
    mm /= (double)n;
    me /= (double)n;
    double total = 0.0, left = 0.0;
    for (Py_ssize_t t = 0; t < n; t++) {
        double a = measured[t] - mm, e = measured[t] - predicted[t] - me;
        total += a * a;
        left += e * e;
    }
    if (!(total > 0.0)) return 0.0;
    double v = 1.0 - left / total;
    return (v > 0.0 ? v : 0.0) * 100.0;
}

static Py_ssize_t oe_fit(const double *regressors, const double *projected, const double *gram,
                         const double *measured, Py_ssize_t n, int k, const double *held, int uncertainty,
                         Py_ssize_t lags, double *params, double *se, double *model,
                         double *vaf_out, double *scratch)
{
    const int p = 3 - k;
    double norm[9], scale[3], rhs[3];
    int piv[3];
    for (int i = 0; i < p; i++) {
        scale[i] = sqrt(gram[4 * (k + i) + (k + i)]);
        if (!(scale[i] > 0.0)) return OE_INSEPARABLE;
    }
    for (int i = 0; i < p; i++) {
        double b = gram[4 * (k + i) + 3];
        for (int j = 0; j < k; j++) b -= gram[4 * (k + i) + j] * held[j];
        rhs[i] = b / scale[i];
        for (int j = 0; j < p; j++) {
            norm[i * p + j] = gram[4 * (k + i) + (k + j)] / (scale[i] * scale[j]);
        }
    }
    if (!(lu_factor(norm, p, piv) > 1e-12)) return OE_INSEPARABLE;
    lu_solve(norm, p, piv, rhs);
    for (int j = 0; j < k; j++) params[j] = held[j];
    for (int i = 0; i < p; i++) params[k + i] = rhs[i] / scale[i];
    for (int i = 0; i < 3; i++) se[i] = NAN;
    for (Py_ssize_t t = 0; t < n; t++) {
        model[t] = params[0] * regressors[t] + params[1] * regressors[n + t] +
                   params[2] * regressors[2 * n + t];
    }
    *vaf_out = vaf_of(measured, model, n);
    if (uncertainty) {
        double *residual = scratch;
        for (Py_ssize_t t = 0; t < n; t++) {
            residual[t] = projected[3 * n + t] - (params[0] * projected[t] +
                                                  params[1] * projected[n + t] +
                                                  params[2] * projected[2 * n + t]);
        }
        oe_sandwich(projected + k * n, p, residual, n, norm, piv, scale, lags < 1 ? 1 : lags,
                    1.0, se + k, residual + n);
    }
    return OE_OK;
}

/* Published VAF over the DFT bins 1 … kmax of the n = m − 8 stencil rows (samples 4 … m−5):
 * measured y + torque trend + explained, model + K·position trend + explained, each centred
 * (as assess.published_vaf with in_band). tw_cos/tw_sin: cos, sin of 2πj/n, j = 0 … n−1. */
static double band_vaf_tabled(const double *y, const double *model, Py_ssize_t n,
                              double torque_slope, double k_position_slope,
                              const double *explained, Py_ssize_t kmax, const double *tw_cos,
                              const double *tw_sin, const double *table, double *scratch)
{
    double *meas = scratch, *err = scratch + n;
    double mm = 0.0, me = 0.0;
    for (Py_ssize_t t = 0; t < n; t++) {
        double index = (double)(t + 4), extra = explained != NULL ? explained[t + 4] : 0.0;
        double a = y[t + 4] + torque_slope * index + extra;
        double b = model[t] + k_position_slope * index + extra;
        meas[t] = a;
        err[t] = a - b;
        mm += a;
        me += a - b;
    }
    mm /= (double)n;
    me /= (double)n;
    for (Py_ssize_t t = 0; t < n; t++) {
        meas[t] -= mm;
        err[t] -= me;
    }
    double total = 0.0, left = 0.0;
    Py_ssize_t k = table != NULL ? band_powers_table(meas, err, n, kmax, table, &total, &left)
                                 : band_powers(meas, err, n, kmax, tw_cos, tw_sin, &total, &left);
    for (; k <= kmax; k++) {
        double mr = 0.0, mi = 0.0, er = 0.0, ei = 0.0;
        Py_ssize_t idx = 0;
        for (Py_ssize_t t = 0; t < n; t++) {
            mr += meas[t] * tw_cos[idx];
            mi -= meas[t] * tw_sin[idx];
            er += err[t] * tw_cos[idx];
            ei -= err[t] * tw_sin[idx];
            idx += k;
            if (idx >= n) idx -= n;
        }
        total += mr * mr + mi * mi;
        left += er * er + ei * ei;
    }
    if (!(total > 0.0)) return 0.0;
    double v = 1.0 - left / total;
    return (v > 0.0 ? v : 0.0) * 100.0;
}

/* band_vaf with the twiddles as tw_cos, tw_sin give them; band_vaf_tabled also takes them as
 * band_table lays them out for a plan (kern625; NULL: not). */
static double band_vaf(const double *y, const double *model, Py_ssize_t n, double torque_slope,
                       double k_position_slope, const double *explained, Py_ssize_t kmax,
                       const double *tw_cos, const double *tw_sin, double *scratch)
{
    return band_vaf_tabled(y, model, n, torque_slope, k_position_slope, explained, kmax, tw_cos,
                           tw_sin, NULL, scratch);
}

/* Acquire `count` float64 buffers (those from `first_writable` on writable); on failure the
 * ones acquired are released and -1 returned. */
static int get_buffers(PyObject **objs, int count, int first_writable, const char **names,
                       Py_buffer *b)
{
    for (int i = 0; i < count; i++) {
        if (get_doubles(objs[i], &b[i], i >= first_writable, names[i]) < 0) {
            for (int j = 0; j < i; j++) PyBuffer_Release(&b[j]);
            return -1;
        }
    }
    return 0;
}

static void release_buffers(Py_buffer *b, int count)
{
    for (int i = 0; i < count; i++) PyBuffer_Release(&b[i]);
}

static PyObject *py_oe_design(PyObject *self, PyObject *args)
{
    PyObject *objs[5];
    double fs;
    if (!PyArg_ParseTuple(args, "OOdOOO", &objs[0], &objs[1], &fs, &objs[2], &objs[3], &objs[4])) {
        return NULL;
    }
    const char *names[5] = {"u", "y", "regressors", "projected", "gram"};
    Py_buffer b[5];
    if (get_buffers(objs, 5, 2, names, b) < 0) return NULL;
    Py_ssize_t m = b[0].len / 8, n = m - 8;
    PyObject *result = NULL;
    if (b[1].len != b[0].len || n < 2 || b[2].len / 8 != 3 * n || b[3].len / 8 != 4 * n ||
        b[4].len / 8 != 16) {
        PyErr_SetString(PyExc_ValueError, "oe_design: inconsistent sizes");
    } else {
        result = PyLong_FromSsize_t(oe_design(b[0].buf, b[1].buf, m, fs, b[2].buf, b[3].buf,
                                              b[4].buf));
    }
    release_buffers(b, 5);
    return result;
}

static PyObject *py_oe_fit(PyObject *self, PyObject *args)
{
    PyObject *objs[8];
    int k, uncertainty;
    Py_ssize_t lags;
    if (!PyArg_ParseTuple(args, "OOOOiOpnOOO", &objs[0], &objs[1], &objs[2], &objs[3], &k,
                          &objs[4], &uncertainty, &lags, &objs[5], &objs[6], &objs[7])) {
        return NULL;
    }
    const char *names[8] = {"regressors", "projected", "gram", "y", "held", "params", "se", "model"};
    Py_buffer b[8];
    if (get_buffers(objs, 8, 5, names, b) < 0) return NULL;
    Py_ssize_t n = b[0].len / 24;
    PyObject *result = NULL;
    if (b[0].len != 24 * n || n < 2 || b[1].len / 8 != 4 * n || b[2].len / 8 != 16 ||
        b[3].len / 8 != n + 8 || k < 0 || k > 2 || b[4].len / 8 < k || b[5].len / 8 != 3 ||
        b[6].len / 8 != 3 || b[7].len / 8 != n) {
        PyErr_SetString(PyExc_ValueError, "oe_fit: inconsistent sizes");
    } else {
        Py_ssize_t nl = lags < 1 ? 1 : (lags > n - 1 ? n - 1 : lags);
        double *work = PyMem_Malloc(sizeof(double) * (2 * n + nl + 2));
        if (work == NULL) {
            PyErr_NoMemory();
        } else {
            double vaf = 0.0;
            const double *y = b[3].buf;
            Py_ssize_t status = oe_fit(b[0].buf, b[1].buf, b[2].buf, y + 4, n, k, b[4].buf,
                                       uncertainty, lags, b[5].buf, b[6].buf, b[7].buf, &vaf,
                                       work);
            PyMem_Free(work);
            result = Py_BuildValue("nd", status, vaf);
        }
    }
    release_buffers(b, 8);
    return result;
}

static PyObject *py_oe_vafs(PyObject *self, PyObject *args)
{
    PyObject *objs[8];
    double fs, torque_slope, k_position_slope;
    Py_ssize_t kmax;
    if (!PyArg_ParseTuple(args, "OOOOOdOddnOO", &objs[0], &objs[1], &objs[2], &objs[3],
                          &objs[4], &fs, &objs[5], &torque_slope, &k_position_slope, &kmax,
                          &objs[6], &objs[7])) {
        return NULL;
    }
    const char *names[8] = {"u", "y", "h", "params", "model", "explained", "tw_cos", "tw_sin"};
    int has_explained = objs[5] != Py_None;
    if (!has_explained) objs[5] = objs[1]; /* a stand-in buffer, not read */
    Py_buffer b[8];
    if (get_buffers(objs, 8, 8, names, b) < 0) return NULL;
    Py_ssize_t m = b[0].len / 8, nh = b[2].len / 8, lag = (nh - 1) / 2, n = m - 8;
    Py_ssize_t edge = lag > 4 ? lag : 4, inner = m - 2 * edge;
    PyObject *result = NULL;
    if (b[1].len != b[0].len || nh % 2 != 1 || lag < 1 || inner < 2 || n < 2 ||
        b[3].len / 8 != 3 || b[4].len / 8 != n || b[5].len != b[0].len ||
        b[6].len / 8 != n || b[7].len / 8 != n || kmax < 0 || kmax > n / 2) {
        PyErr_SetString(PyExc_ValueError, "oe_vafs: inconsistent sizes");
    } else {
        double *work = PyMem_Malloc(sizeof(double) * (3 * inner + 2 * n));
        if (work == NULL) {
            PyErr_NoMemory();
        } else {
            double vafs[3];
            predictions(b[0].buf, b[1].buf, m, b[2].buf, lag, fs, b[3].buf, edge, work,
                        work + inner, work + 2 * inner);
            three_vafs(work, work + inner, work + 2 * inner, inner, vafs);
            double published = band_vaf(b[1].buf, b[4].buf, n, torque_slope, k_position_slope,
                                        has_explained ? b[5].buf : NULL, kmax, b[6].buf,
                                        b[7].buf, work);
            PyMem_Free(work);
            result = Py_BuildValue("ddd", published, vafs[1], vafs[2]);
        }
    }
    release_buffers(b, 8);
    return result;
}

/* ------------------------------------------------------------------ the stream's back end
 * oe_window: one window's whole output-error back end in one call, what
 * rtsid.ident.stream.WindowStream runs in numpy (its tested reference): the design (oe_design);
 * the full fit the held parameters learn from, and its VAF (oe_fit, k = 0, no SEs; skipped
 * when nothing is held: the published fit is then the full fit); the published fit with the
 * first k held and its SEs (oe_fit); its VAFs (as oe_vafs); and the K of the window's newest
 * rows (split_newest, as rtsid.ident.split.SplitProblem.newest).
 */
enum {
    OW_WHOLE = 0,       /* I, B, K of the full fit, then its VAF (4) */
    OW_PARAMS = 4,      /* I, B, K published (3) */
    OW_SE = 7,          /* their standard errors (3) */
    OW_VAFS = 10,       /* vaf, vaf_irf, vaf_fit (3) */
    OW_NEWEST = 13,     /* K of the newest rows, its relative variance, their centre row (3) */
    OW_SIZE = 16,
};

/* The inverse of the p × p matrix a (row-major) by LU with partial pivoting, into inv;
 * 0 when a pivot is zero (singular). */
static int invert(const double *a, int p, double *inv)
{
    double lu[36];
    int piv[6];
    for (int i = 0; i < p * p; i++) lu[i] = a[i];
    lu_factor(lu, p, piv);
    for (int i = 0; i < p; i++) {
        if (lu[i * p + i] == 0.0) return 0;
    }
    for (int c = 0; c < p; c++) {
        double col[6] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
        col[c] = 1.0;
        lu_solve(lu, p, piv, col);
        for (int r = 0; r < p; r++) inv[r * p + c] = col[r];
    }
    return 1;
}

/* The split problem's system (rtsid.ident.split.SplitProblem.of), shared by split_newest and
 * split_scan: the target (torque minus the k held terms), the free regressors' rows (rows[0],
 * rows[1]: offset and trend, computed in the sums; then the fitted derivatives, u last), X'r,
 * the inverse Gram matrix, its u entry gkk and the window's K. Returns 0 where
 * SplitProblem.of gives None (too few rows, singular, gkk <= 0). */
static int split_system(const double *regressors, const double *measured, Py_ssize_t n, int k,
                        const double *held, double *target, const double **rows, double *xr,
                        double *inv, double *gkk, double *k_hat)
{
    if (n < 2 * 3 + 4) return 0;
    const int p = 5 - k;
    for (Py_ssize_t t = 0; t < n; t++) {
        double v = measured[t];
        if (k >= 1) v -= held[0] * regressors[t];
        if (k >= 2) v -= held[1] * regressors[n + t];
        target[t] = v;
    }
    for (int j = 2; j < p - 1; j++) rows[j] = regressors + (Py_ssize_t)(k + j - 2) * n;
    rows[p - 1] = regressors + 2 * n;
    const double centre = (double)(n - 1) / 2.0;
    double gram[25];
    for (int a = 0; a < p; a++) {
        for (int b = a; b < p; b++) {
            double acc = 0.0;
            for (Py_ssize_t t = 0; t < n; t++) {
                double va = a == 0 ? 1.0 : (a == 1 ? (double)t - centre : rows[a][t]);
                double vb = b == 0 ? 1.0 : (b == 1 ? (double)t - centre : rows[b][t]);
                acc += va * vb;
            }
            gram[a * p + b] = gram[b * p + a] = acc;
        }
        double acc = 0.0;
        for (Py_ssize_t t = 0; t < n; t++) {
            double va = a == 0 ? 1.0 : (a == 1 ? (double)t - centre : rows[a][t]);
            acc += va * target[t];
        }
        xr[a] = acc;
    }
    if (!invert(gram, p, inv)) return 0;
    *gkk = inv[(p - 1) * p + (p - 1)];
    if (!(*gkk > 0.0)) return 0;
    double sum = 0.0;
    for (int a = 0; a < p; a++) sum += inv[(p - 1) * p + a] * xr[a];
    *k_hat = sum;
    return 1;
}

/* The weights w = G⁻¹c of the rows after a split, with c'w and x'r·w (split_newest, split_scan). */
static void split_weights(const double *inv, const double *c, const double *xr, int p, double *w,
                          double *cw, double *xw)
{
    double sum_c = 0.0, sum_x = 0.0;
    for (int a = 0; a < p; a++) {
        double acc = 0.0;
        for (int b = 0; b < p; b++) acc += inv[a * p + b] * c[b];
        w[a] = acc;
        sum_c += c[a] * acc;
        sum_x += xr[a] * acc;
    }
    *cw = sum_c;
    *xw = sum_x;
}

/* K of the newest rows `first` … n−1 of the window's split problem (rtsid.ident.split): the
 * free regressors offset, trend, the fitted derivatives (of the k held, none), u, over the
 * torque minus the held terms. out: K, its variance relative to σ_K², the rows' centre; NaN
 * when SplitProblem.of or newest gives None. */
static void split_newest(const double *regressors, const double *measured, Py_ssize_t n, int k,
                         const double *held, Py_ssize_t first, double *out, double *target)
{
    out[0] = out[1] = out[2] = NAN;
    const int p = 5 - k;
    const double *rows[5];
    double xr[5], inv[25], gkk, k_hat;
    if (!split_system(regressors, measured, n, k, held, target, rows, xr, inv, &gkk, &k_hat))
        return;
    const double centre = (double)(n - 1) / 2.0;
    if (first < 3) first = 3;
    if (n - first < 3) return;
    const double *u = rows[p - 1];
    double c[5], sr = 0.0, w[5];
    for (int a = 0; a < p; a++) {
        double acc = 0.0;
        for (Py_ssize_t t = first; t < n; t++) {
            double va = a == 0 ? 1.0 : (a == 1 ? (double)t - centre : rows[a][t]);
            acc += va * u[t];
        }
        c[a] = acc;
    }
    for (Py_ssize_t t = first; t < n; t++) sr += target[t] * u[t];
    double cw, xw;
    split_weights(inv, c, xr, p, w, &cw, &xw);
    const double pvv = c[p - 1] - cw;
    if (!(pvv > 1e-12 * c[p - 1])) return;
    const double delta = (sr - xw) / pvv, after_k = 1.0 - w[p - 1];
    out[0] = k_hat + delta * after_k;
    out[1] = 1.0 + after_k * after_k / (pvv * gkk);
    out[2] = 0.5 * (double)(first + n - 1);
}

static Py_ssize_t oe_window_tabled(const double *u, const double *y, Py_ssize_t m,
                                   const double *h, Py_ssize_t lag, double fs, int k,
                                   const double *held, int learn, int uncertainty,
                                   Py_ssize_t lags, const double *explained, double torque_slope,
                                   double position_slope, Py_ssize_t kmax, const double *tw_cos,
                                   const double *tw_sin, const double *table,
                                   Py_ssize_t newest_rows, double *regressors, double *projected,
                                   double *gram, double *model, double *out, double *work)
{
    const Py_ssize_t n = m - 8, edge = lag > 4 ? lag : 4;
    for (int i = 0; i < OW_SIZE; i++) out[i] = NAN;
    Py_ssize_t status = oe_design(u, y, m, fs, regressors, projected, gram);
    if (status != OE_OK) return status;
    double se[3], vaf = 0.0;
    if (learn && k > 0) {
        status = oe_fit(regressors, projected, gram, y + 4, n, 0, held, 0, lags, out + OW_WHOLE,
                        se, model, &vaf, work);
        if (status != OE_OK) return status;
        out[OW_WHOLE + 3] = vaf;
    }
    status = oe_fit(regressors, projected, gram, y + 4, n, k, held, uncertainty, lags,
                    out + OW_PARAMS, out + OW_SE, model, &vaf, work);
    if (status != OE_OK) return status;
    if (learn && k == 0) {
        for (int i = 0; i < 3; i++) out[OW_WHOLE + i] = out[OW_PARAMS + i];
        out[OW_WHOLE + 3] = vaf;
    }
    double vafs[3]; /* the model's torque over the stencil rows is oe_fit's, kept in model */
    irf_model_vafs(u, y, m, h, lag, fs, model, edge, work, vafs);
    out[OW_VAFS] = band_vaf_tabled(y, model, n, torque_slope, out[OW_PARAMS + 2] * position_slope,
                                   explained, kmax, tw_cos, tw_sin, table, work);
    out[OW_VAFS + 1] = vafs[1];
    out[OW_VAFS + 2] = vafs[2];
    if (newest_rows > 0) {
        split_newest(regressors, y + 4, n, k, held, n - newest_rows, out + OW_NEWEST, work);
    }
    return OE_OK;
}

/* oe_window as before (py_oe_window and compiled callers); oe_window_tabled also takes the
 * plan's band_table (NULL: not). */
__attribute__((unused)) static Py_ssize_t oe_window(const double *u, const double *y, Py_ssize_t m, const double *h,
                            Py_ssize_t lag, double fs, int k, const double *held, int learn,
                            int uncertainty, Py_ssize_t lags, const double *explained,
                            double torque_slope, double position_slope, Py_ssize_t kmax,
                            const double *tw_cos, const double *tw_sin, Py_ssize_t newest_rows,
                            double *regressors, double *projected, double *gram, double *model,
                            double *out, double *work)
{
    return oe_window_tabled(u, y, m, h, lag, fs, k, held, learn, uncertainty, lags, explained,
                            torque_slope, position_slope, kmax, tw_cos, tw_sin, NULL, newest_rows,
                            regressors, projected, gram, model, out, work);
}

/* oe_window's and (tabled) oe_window_tabled's argument handling: the latter takes one more
 * buffer, the plan's band_table, last. */
static PyObject *oe_window_entry(PyObject *args, int tabled)
{
    PyObject *objs[13], *out_objs[5], *table = NULL;
    double fs, torque_slope, position_slope;
    int k, learn, uncertainty;
    Py_ssize_t lags, kmax, newest_rows;
    if (!PyArg_ParseTuple(args, tabled ? "OOOdiOppnOddnOOnOOOOOO" : "OOOdiOppnOddnOOnOOOOO",
                          &objs[0], &objs[1], &objs[2], &fs, &k, &objs[3], &learn, &uncertainty,
                          &lags, &objs[4], &torque_slope, &position_slope, &kmax, &objs[5],
                          &objs[6], &newest_rows, &out_objs[0], &out_objs[1], &out_objs[2],
                          &out_objs[3], &out_objs[4], &table)) {
        return NULL;
    }
    /* read-only buffers first (the table, when given, after tw_sin), then the writable ones */
    const int w = tabled ? 8 : 7, count = w + 5; /* w: the first writable */
    if (tabled) objs[7] = table;
    for (int i = 0; i < 5; i++) objs[w + i] = out_objs[i];
    const char *names[13] = {"u", "y", "h", "held", "explained", "tw_cos", "tw_sin"};
    const char *out_names[5] = {"regressors", "projected", "gram", "model", "out"};
    names[7] = "table";
    for (int i = 0; i < 5; i++) names[w + i] = out_names[i];
    int has_explained = objs[4] != Py_None;
    if (!has_explained) objs[4] = objs[1]; /* a stand-in buffer, not read */
    Py_buffer b[13];
    if (get_buffers(objs, count, w, names, b) < 0) return NULL;
    Py_ssize_t m = b[0].len / 8, nh = b[2].len / 8, lag = (nh - 1) / 2, n = m - 8;
    Py_ssize_t edge = lag > 4 ? lag : 4, inner = m - 2 * edge;
    PyObject *result = NULL;
    if (b[1].len != b[0].len || nh % 2 != 1 || lag < 1 || inner < 2 || n < 2 || k < 0 ||
        k > 2 || b[3].len / 8 < 2 || b[4].len != b[0].len || b[5].len / 8 != n ||
        b[6].len / 8 != n || kmax < 0 || kmax > n / 2 || b[w].len / 8 != 3 * n ||
        b[w + 1].len / 8 != 4 * n || b[w + 2].len / 8 != 16 || b[w + 3].len / 8 != n ||
        b[w + 4].len / 8 != OW_SIZE || (tabled && b[7].len / 8 != BAND_TABLE_SIZE(n, kmax))) {
        PyErr_SetString(PyExc_ValueError, "oe_window: inconsistent sizes");
    } else {
        Py_ssize_t nl = lags < 1 ? 1 : (lags > n - 1 ? n - 1 : lags);
        Py_ssize_t size = 3 * inner + 2 * n + nl + 2;
        double *work = PyMem_Malloc(sizeof(double) * size);
        if (work == NULL) {
            PyErr_NoMemory();
        } else {
            Py_ssize_t status = oe_window_tabled(
                b[0].buf, b[1].buf, m, b[2].buf, lag, fs, k, b[3].buf, learn, uncertainty,
                lags, has_explained ? b[4].buf : NULL, torque_slope, position_slope, kmax,
                b[5].buf, b[6].buf, tabled ? b[7].buf : NULL, newest_rows, b[w].buf,
                b[w + 1].buf, b[w + 2].buf, b[w + 3].buf, b[w + 4].buf, work);
            PyMem_Free(work);
            result = PyLong_FromSsize_t(status);
        }
    }
    release_buffers(b, count);
    return result;
}

static PyObject *py_oe_window(PyObject *self, PyObject *args)
{
    return oe_window_entry(args, 0);
}

/* ------------------------------------------------------------------ the reflex decimator
 * sos_filtfilt: the zero-phase Chebyshev decimator of rtsid.ident.reflex.decimated (scipy's
 * sosfiltfilt: odd extension, steady state initial conditions, direct form II transposed
 * sections), what the slow lane's fit feeds the reflex IRF. O(n·sections).
 */
/* scipy's sosfilt (direct form II transposed, its _sosfilt loop's operations in its order, so
 * the same numbers bit for bit), in place, the states starting at zi·(first sample run). */
static void sos_run_exact4(const double *c, const double *zi, double *x, Py_ssize_t n,
                           int backwards);

static void sos_run_exact(const double *sos, const double *zi, Py_ssize_t ns, double *x,
                          Py_ssize_t n, int backwards)
{
    if (ns == 4) {
        sos_run_exact4(sos, zi, x, n, backwards);
        return;
    }
    double state[2 * 16];
    const double first = backwards ? x[n - 1] : x[0];
    for (Py_ssize_t s = 0; s < ns; s++) {
        state[2 * s] = zi[2 * s] * first;
        state[2 * s + 1] = zi[2 * s + 1] * first;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        Py_ssize_t at = backwards ? n - 1 - i : i;
        double cur = x[at];
        for (Py_ssize_t s = 0; s < ns; s++) {
            const double *c = sos + 6 * s;
            double out = c[0] * cur + state[2 * s];
            state[2 * s] = c[1] * cur - c[4] * out + state[2 * s + 1];
            state[2 * s + 1] = c[2] * cur - c[5] * out;
            cur = out;
        }
        x[at] = cur;
    }
}

/* sos_run_exact for four sections (the decimator's), the states in registers so that the
 * sections' chains of successive samples overlap: the same operations in the same order. */
#define EXACT_SECTION(q, s0, s1)                           \
    do {                                                   \
        const double out = c[6 * q] * cur + s0;            \
        s0 = c[6 * q + 1] * cur - c[6 * q + 4] * out + s1; \
        s1 = c[6 * q + 2] * cur - c[6 * q + 5] * out;      \
        cur = out;                                         \
    } while (0)

static void sos_run_exact4(const double *c, const double *zi, double *x, Py_ssize_t n,
                           int backwards)
{
    const double first = backwards ? x[n - 1] : x[0];
    double s00 = zi[0] * first, s01 = zi[1] * first, s10 = zi[2] * first, s11 = zi[3] * first;
    double s20 = zi[4] * first, s21 = zi[5] * first, s30 = zi[6] * first, s31 = zi[7] * first;
    const Py_ssize_t step = backwards ? -1 : 1;
    double *p = backwards ? x + n - 1 : x;
    for (Py_ssize_t i = 0; i < n; i++, p += step) {
        double cur = *p;
        EXACT_SECTION(0, s00, s01);
        EXACT_SECTION(1, s10, s11);
        EXACT_SECTION(2, s20, s21);
        EXACT_SECTION(3, s30, s31);
        *p = cur;
    }
}
#undef EXACT_SECTION

/* sos_filtfilt(sos, zi, x): scipy's sosfiltfilt on an already extended x, in place: forwards
 * from zi·x[0], then backwards from zi·(the last output), each pass scipy's sosfilt bit for
 * bit (rtsid.ident.reflex.decimated; its scipy code is the reference). O(n·sections). */
static PyObject *py_sos_filtfilt(PyObject *self, PyObject *args)
{
    PyObject *objs[3];
    if (!PyArg_ParseTuple(args, "OOO", &objs[0], &objs[1], &objs[2])) return NULL;
    const char *names[3] = {"sos", "zi", "x"};
    Py_buffer b[3];
    if (get_buffers(objs, 3, 2, names, b) < 0) return NULL;
    Py_ssize_t ns = b[0].len / 48, n = b[2].len / 8;
    PyObject *result = NULL;
    if (ns < 1 || ns > 16 || b[0].len != 48 * ns || b[1].len != 16 * ns || n < 1) {
        PyErr_SetString(PyExc_ValueError, "sos_filtfilt: inconsistent sizes");
    } else {
        sos_run_exact(b[0].buf, b[1].buf, ns, b[2].buf, n, 0);
        sos_run_exact(b[0].buf, b[1].buf, ns, b[2].buf, n, 1);
        Py_INCREF(Py_None);
        result = Py_None;
    }
    release_buffers(b, 3);
    return result;
}

/* band_limit(x, taps, factor, sign, out): sign·x with its mean removed, through the FIR over
 * the fully supported samples, every factor-th kept (rtsid.ident.front.scored_band's band
 * limiting of the torque explained elsewhere; its numpy code is the reference). O(N·T/factor). */
static PyObject *py_band_limit(PyObject *self, PyObject *args)
{
    PyObject *objs[3];
    Py_ssize_t factor;
    double sign;
    if (!PyArg_ParseTuple(args, "OOndO", &objs[0], &objs[1], &factor, &sign, &objs[2])) {
        return NULL;
    }
    const char *names[3] = {"x", "taps", "out"};
    Py_buffer b[3];
    if (get_buffers(objs, 3, 2, names, b) < 0) return NULL;
    Py_ssize_t n = b[0].len / 8, nt = b[1].len / 8, m = b[2].len / 8;
    PyObject *result = NULL;
    if (factor < 1 || nt < 1 || n < nt || m != (n - nt) / factor + 1) {
        PyErr_SetString(PyExc_ValueError, "band_limit: inconsistent sizes");
    } else {
        double *work = PyMem_Malloc(sizeof(double) * n);
        if (work == NULL) {
            PyErr_NoMemory();
        } else {
            (void)detrend_phases(b[0].buf, work, n, sign, 1, 0, factor); /* kern625 */
            fir_phases(work, n, b[1].buf, nt, factor, b[2].buf, m);
            PyMem_Free(work);
            Py_INCREF(Py_None);
            result = Py_None;
        }
    }
    release_buffers(b, 3);
    return result;
}

static PyObject *py_window_fit(PyObject *self, PyObject *args)
{
    PyObject *objs[10];
    double fs, power;
    int uncertainty;
    if (!PyArg_ParseTuple(args, "OOOOOOOddpOOO", &objs[0], &objs[1], &objs[2], &objs[3],
                          &objs[4], &objs[5], &objs[6], &fs, &power, &uncertainty, &objs[7],
                          &objs[8], &objs[9])) {
        return NULL;
    }
    const char *names[10] = {"u", "y", "h", "phi", "stacked", "f", "hann", "params", "sens", "out"};
    Py_buffer b[10];
    int got = 0;
    for (; got < 10; got++) {
        if (get_doubles(objs[got], &b[got], got >= 7, names[got]) < 0) break;
    }
    PyObject *result = NULL;
    if (got == 10) {
        Py_ssize_t m = b[0].len / 8, nh = b[2].len / 8, nf = b[5].len / 8, lag = (nh - 1) / 2;
        Py_ssize_t edge = lag > 4 ? lag : 4;
        if (b[1].len != b[0].len || nh % 2 != 1 || lag < 1 || b[3].len / 8 != nh ||
            b[4].len / 8 != 2 * nf * nh || b[6].len != b[0].len || b[7].len / 8 != 3 ||
            b[8].len / 8 != 3 * nh || b[9].len / 8 != 6 || nf < 3 || m - 2 * edge < 2 ||
            m < 2) {
            PyErr_SetString(PyExc_ValueError, "window_fit: inconsistent sizes");
        } else {
            /* base weights + max(periodogram scratch, fit scratch, predictions + SE scratch) */
            Py_ssize_t size = nf + 4 * m + 10 * nf + 3 * m + 8 * nh + 8;
            double *work = PyMem_Malloc(sizeof(double) * size);
            if (work == NULL) {
                PyErr_NoMemory();
            } else {
                Py_ssize_t status = window_fit(
                    b[0].buf, b[1].buf, m, b[2].buf, lag, b[3].buf, b[4].buf, b[5].buf, nf,
                    b[6].buf, fs, power, uncertainty, b[7].buf, b[8].buf, b[9].buf, work);
                PyMem_Free(work);
                result = PyLong_FromSsize_t(status);
            }
        }
    }
    for (int i = 0; i < got; i++) PyBuffer_Release(&b[i]);
    return result;
}

/* Slope of the least-squares line through sign·x, per sample (correlation.trend_slope). */
static double line_slope(const double *x, Py_ssize_t n, double sign)
{
    const double centre = (double)(n - 1) / 2.0;
    double tt = 0.0, tx = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        double t = (double)i - centre;
        tt += t * t;
        tx += t * sign * x[i];
    }
    return tt > 0.0 ? tx / tt : 0.0;
}

/* Population standard deviation of x (numpy.std). */
static double standard_deviation(const double *x, Py_ssize_t n)
{
    double mean = 0.0, ss = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) mean += x[i];
    mean /= (double)n;
    for (Py_ssize_t i = 0; i < n; i++) ss += (x[i] - mean) * (x[i] - mean);
    return sqrt(ss / (double)n);
}

static PyObject *py_window_irf(PyObject *self, PyObject *args)
{
    PyObject *po, *to, *tapso, *uo, *yo, *ho, *phio;
    Py_ssize_t factor, lag, sweeps;
    double sign, ridge, fs;
    int kind;
    if (!PyArg_ParseTuple(args, "OOOndinnddOOOO", &po, &to, &tapso, &factor, &sign, &kind, &lag,
                          &sweeps, &ridge, &fs, &uo, &yo, &ho, &phio)) {
        return NULL;
    }
    PyObject *objs[7] = {po, to, tapso, uo, yo, ho, phio};
    const char *names[7] = {"position", "torque", "taps", "u", "y", "h", "phi"};
    Py_buffer b[7];
    int got = 0;
    for (; got < 7; got++) {
        if (get_doubles(objs[got], &b[got], got >= 3, names[got]) < 0) break;
    }
    PyObject *result = NULL;
    if (got == 7) {
        Py_ssize_t n = b[0].len / 8, nt = b[2].len / 8, m = b[3].len / 8, nh = 2 * lag + 1;
        Py_ssize_t expect_m = n >= nt && factor > 0 ? (n - nt) / factor + 1 : -1;
        if (b[1].len != b[0].len || b[4].len != b[3].len || m != expect_m || lag < 1 ||
            b[5].len / 8 != nh || b[6].len / 8 != nh || m <= nh || sweeps < 0) {
            PyErr_SetString(PyExc_ValueError, "window_irf: inconsistent sizes");
        } else {
            double *work = PyMem_Malloc(sizeof(double) * WINDOW_IRF_WORK(n, nh));
            if (work == NULL) {
                PyErr_NoMemory();
            } else {
                double alpha = 0.0, slopes[2];
                Py_ssize_t status;
                /* Short (tens of µs): keep the GIL. Releasing it would let another thread
                 * take it for a whole switch interval before this one gets it back. The
                 * trends' slopes (line_slope's) come from the detrending's own pass. */
                status = window_irf_sloped(b[0].buf, b[1].buf, n, b[2].buf, nt, factor, sign,
                                           kind, lag, ridge, sweeps, fs, b[3].buf, b[4].buf, m,
                                           b[5].buf, b[6].buf, work, &alpha, slopes);
                PyMem_Free(work);
                result = Py_BuildValue("ndddd", status, alpha, standard_deviation(b[3].buf, m),
                                       slopes[0], slopes[1]);
            }
        }
    }
    for (int i = 0; i < got; i++) PyBuffer_Release(&b[i]);
    return result;
}

static PyObject *py_xcorr(PyObject *self, PyObject *args)
{
    PyObject *uo, *yo, *co;
    Py_ssize_t first, last;
    double norm;
    if (!PyArg_ParseTuple(args, "OOnndO", &uo, &yo, &first, &last, &norm, &co)) return NULL;
    Py_buffer u, y, c;
    if (get_doubles(uo, &u, 0, "u") < 0) return NULL;
    if (get_doubles(yo, &y, 0, "y") < 0) { PyBuffer_Release(&u); return NULL; }
    if (get_doubles(co, &c, 1, "c") < 0) { PyBuffer_Release(&u); PyBuffer_Release(&y); return NULL; }
    PyObject *result = NULL;
    Py_ssize_t n = u.len / 8;
    if (y.len != u.len || c.len / 8 != last - first + 1 || first > last || last >= n || -first >= n) {
        PyErr_SetString(PyExc_ValueError, "xcorr: inconsistent sizes");
    } else {
        xcorr(u.buf, y.buf, n, first, last, norm, c.buf);
        Py_INCREF(Py_None);
        result = Py_None;
    }
    PyBuffer_Release(&u); PyBuffer_Release(&y); PyBuffer_Release(&c);
    return result;
}

static PyObject *py_solve(PyObject *self, PyObject *args)
{
    PyObject *ro, *bo, *xo, *wo;
    if (!PyArg_ParseTuple(args, "OOOO", &ro, &bo, &xo, &wo)) {
        return NULL;
    }
    Py_buffer r, b, x, w;
    if (get_doubles(ro, &r, 0, "r") < 0) return NULL;
    if (get_doubles(bo, &b, 0, "b") < 0) { PyBuffer_Release(&r); return NULL; }
    if (get_doubles(xo, &x, 1, "x") < 0) { PyBuffer_Release(&r); PyBuffer_Release(&b); return NULL; }
    if (get_doubles(wo, &w, 1, "work") < 0) {
        PyBuffer_Release(&r); PyBuffer_Release(&b); PyBuffer_Release(&x); return NULL;
    }
    Py_ssize_t n = r.len / (Py_ssize_t)sizeof(double);
    PyObject *result = NULL;
    if (n < 1 || b.len != r.len || x.len != r.len || w.len < 2 * r.len) {
        PyErr_SetString(PyExc_ValueError, "need len(r) == len(b) == len(x) >= 1 and len(work) >= 2n");
    } else {
        double alpha = 0.0;
        Py_ssize_t status;
        double *work = (double *)w.buf;
        if (n >= RELEASE_GIL_ABOVE) {
            Py_BEGIN_ALLOW_THREADS
            status = eureka_solve((const double *)r.buf, (const double *)b.buf,
                                  (double *)x.buf, work, work + n, n, &alpha);
            Py_END_ALLOW_THREADS
        } else {
            status = eureka_solve((const double *)r.buf, (const double *)b.buf,
                                  (double *)x.buf, work, work + n, n, &alpha);
        }
        result = Py_BuildValue("nd", status, alpha);
    }
    PyBuffer_Release(&r);
    PyBuffer_Release(&b);
    PyBuffer_Release(&x);
    PyBuffer_Release(&w);
    return result;
}

/* ------------------------------------------------------------------ reflex stream (issue 22)
 * reflex_rect_hop: one hop of rtsid.ident.reflex.ReflexStream for the "rect" pathway (its numpy
 * code, reflex._hop, is the reference). Model sample m sits at data sample m·factor (absolute
 * indices). Its pathway input r(m) = Σ_j taps_j·max(v(m·factor − R + j), 0), v the 9-point
 * stencil's velocity of the position point-reflected beyond the segment's ends; its IRF output
 * y(m) = Σ_k g_k·r(m − k) (r = 0 before the first input the segment gives). Values kept from
 * earlier hops are used where they are; the others are formed. The window's torque is
 * y − mean(r)·Σg, linear between model samples and the last one held. With reuse, this hop's
 * final values (their stencils and taps within the segment) replace the kept ones.
 * O(hop + taps·reach/factor) per hop in the steady state.
 */
static Py_ssize_t floor_div(Py_ssize_t a, Py_ssize_t b)
{
    const Py_ssize_t q = a / b;
    return (a % b != 0 && ((a < 0) != (b < 0))) ? q - 1 : q;
}

/* r(m) for m = m_from … m_to into out; x: scratch of (m_to − m_from)·factor + ntaps + 8 */
static void rect_rates(const double *pos, Py_ssize_t n, Py_ssize_t first, double fs,
                       const double *taps, Py_ssize_t ntaps, Py_ssize_t factor,
                       Py_ssize_t m_from, Py_ssize_t m_to, double *out, double *x)
{
    const Py_ssize_t reach = (ntaps - 1) / 2;
    const Py_ssize_t nu = (m_to - m_from) * factor + ntaps;
    const Py_ssize_t low = m_from * factor - reach - 4 - first; /* relative to the segment */
    for (Py_ssize_t i = 0; i < nu + 8; i++) {
        const Py_ssize_t at = low + i;
        x[i] = at < 0 ? 2 * pos[0] - pos[-at]
               : at > n - 1 ? 2 * pos[n - 1] - pos[2 * (n - 1) - at]
                            : pos[at];
    }
    double *u = x; /* the velocity overwrites the positions it no longer needs */
    for (Py_ssize_t i = 0; i < nu; i++) {
        double acc = 0.0;
        for (int s = 0; s < 9; s++) acc += x[i + s] * STENCIL_D1[s];
        const double v = acc * fs;
        u[i] = (v > 0.0 || v != v) ? v : 0.0; /* NaN stays, as np.maximum */
    }
    for (Py_ssize_t k = 0; k <= m_to - m_from; k++) {
        out[k] = dot_unrolled(taps, u + k * factor, ntaps);
    }
}

/* y(m) for m = m_from … m_to into out, from r at model samples r_low … */
static void irf_outputs(const double *r, Py_ssize_t r_low, const double *g, Py_ssize_t ng,
                        Py_ssize_t m_from, Py_ssize_t m_to, double *out)
{
    for (Py_ssize_t m = m_from; m <= m_to; m++) {
        const Py_ssize_t top = m - r_low < ng - 1 ? m - r_low : ng - 1;
        double acc = 0.0;
        for (Py_ssize_t k = 0; k <= top; k++) acc += g[k] * r[m - k - r_low];
        out[m - m_from] = acc;
    }
}

static PyObject *py_reflex_rect_hop(PyObject *self, PyObject *args)
{
    PyObject *objs[6];
    Py_ssize_t first, factor, in_first, in_count, out_first, out_count;
    double fs;
    int reuse;
    if (!PyArg_ParseTuple(args, "OndOnOiOnnOnnO", &objs[0], &first, &fs, &objs[1], &factor,
                          &objs[2], &reuse, &objs[3], &in_first, &in_count, &objs[4],
                          &out_first, &out_count, &objs[5])) {
        return NULL;
    }
    const char *names[6] = {"position", "taps", "g", "inputs", "outputs", "out"};
    Py_buffer b[6];
    if (get_buffers(objs, 6, 3, names, b) < 0) return NULL;
    const double *pos = b[0].buf, *taps = b[1].buf, *g = b[2].buf;
    double *kept_r = b[3].buf, *kept_y = b[4].buf, *out = b[5].buf;
    const Py_ssize_t n = b[0].len / 8, ntaps = b[1].len / 8, ng = b[2].len / 8;
    const Py_ssize_t cap_r = b[3].len / 8, cap_y = b[4].len / 8, n_last = b[5].len / 8;
    const Py_ssize_t lags = ng - 1, reach = (ntaps - 1) / 2 + 4;
    if (factor < 1 || ntaps % 2 != 1 || ng < 1 || n < reach + 1 || n_last < 1 || n_last > n ||
        in_count < 0 || in_count > cap_r || out_count < 0 || out_count > cap_y) {
        PyErr_SetString(PyExc_ValueError, "reflex_rect_hop: inconsistent sizes");
        release_buffers(b, 6);
        return NULL;
    }
    const Py_ssize_t end = first + n - 1;
    const Py_ssize_t last = floor_div(end, factor);
    const Py_ssize_t window_first = floor_div(end - n_last + 1, factor);
    const Py_ssize_t first_model = -floor_div(-first, factor);
    const Py_ssize_t low = window_first - lags > first_model ? window_first - lags : first_model;
    const Py_ssize_t final_low = -floor_div(-(first + reach), factor);
    const Py_ssize_t final_high = floor_div(end - reach, factor);
    const Py_ssize_t nr = last - low + 1, ny = last - window_first + 1;
    if (!reuse) in_count = out_count = 0;
    if (nr > cap_r || ny > cap_y) {
        PyErr_SetString(PyExc_ValueError, "reflex_rect_hop: kept buffers too small");
        release_buffers(b, 6);
        return NULL;
    }
    double *work = PyMem_Malloc(sizeof(double) * (nr + ny + (nr + 1) * factor + ntaps + 8));
    if (work == NULL) {
        release_buffers(b, 6);
        return PyErr_NoMemory();
    }
    double *r = work, *y = work + nr, *x = work + nr + ny;
    /* the inputs: kept where kept, formed elsewhere */
    /* a kept value is used only where this segment would form it final too */
    Py_ssize_t a = in_first > final_low ? in_first : final_low;
    if (a < low) a = low;
    Py_ssize_t z = in_first + in_count - 1 < last ? in_first + in_count - 1 : last;
    if (in_count == 0 || a > z) {
        a = last + 1;
        z = last;
    } else {
        memcpy(r + (a - low), kept_r + (a - in_first), sizeof(double) * (z - a + 1));
    }
    if (low < a) rect_rates(pos, n, first, fs, taps, ntaps, factor, low, a - 1, r, x);
    if (z < last && z + 1 >= low) {
        rect_rates(pos, n, first, fs, taps, ntaps, factor, z + 1, last, r + (z + 1 - low), x);
    }
    /* the outputs, likewise */
    const Py_ssize_t first_output =
        final_low + lags > window_first ? final_low + lags : window_first;
    a = out_first > first_output ? out_first : first_output;
    z = out_first + out_count - 1 < last ? out_first + out_count - 1 : last;
    if (out_count == 0 || a > z) {
        a = last + 1;
        z = last;
    } else {
        memcpy(y + (a - window_first), kept_y + (a - out_first), sizeof(double) * (z - a + 1));
    }
    if (window_first < a) irf_outputs(r, low, g, ng, window_first, a - 1, y);
    if (z < last && z + 1 >= window_first) {
        irf_outputs(r, low, g, ng, z + 1, last, y + (z + 1 - window_first));
    }
    /* the window's torque */
    double sum_r = 0.0, sum_g = 0.0;
    for (Py_ssize_t i = 0; i < nr; i++) sum_r += r[i];
    for (Py_ssize_t k = 0; k < ng; k++) sum_g += g[k];
    const double offset = sum_r / (double)nr * sum_g;
    double *zz = x; /* y − offset, scratch */
    for (Py_ssize_t j = 0; j < ny; j++) zz[j] = y[j] - offset;
    Py_ssize_t j = 0, phase = end - n_last + 1 - window_first * factor; /* no division per sample */
    for (Py_ssize_t q = 0; q < n_last; q++, phase++) {
        if (phase == factor) {
            phase = 0;
            j++;
        }
        if (j >= ny - 1) {
            out[q] = zz[ny - 1];
        } else {
            const double t = (double)phase / (double)factor;
            out[q] = zz[j] + (zz[j + 1] - zz[j]) * t;
        }
    }
    /* keep this hop's final values */
    if (reuse) {
        a = final_low > low ? final_low : low;
        z = final_high < last ? final_high : last;
        in_first = a;
        in_count = z >= a ? z - a + 1 : 0;
        if (in_count > 0) memcpy(kept_r, r + (a - low), sizeof(double) * in_count);
        a = first_output;
        out_first = a;
        out_count = z >= a ? z - a + 1 : 0;
        if (out_count > 0) memcpy(kept_y, y + (a - window_first), sizeof(double) * out_count);
    }
    PyMem_Free(work);
    release_buffers(b, 6);
    return Py_BuildValue("nnnn", in_first, in_count, out_first, out_count);
}
static PyObject *py_json_array(PyObject *self, PyObject *args); /* sample batches, below */

/* ------------------------------------------------------------------ the tracker's split scan
 * split_scan: every split of one window's K into a value before and a value after, what
 * rtsid.ident.split.SplitProblem.of and .scan compute in numpy (their tested reference): the
 * free regressors offset, trend, the fitted derivatives (of the k held, none) and u over the
 * torque minus the held terms, (XᵀX)⁻¹ and the unsplit K̂; then, from the last row back, the
 * suffix sums c_s = Xᵀv_s and v_sᵀr (summed in numpy's cumsum order) and each split's K_after,
 * K_before, z ratio and relative variance, and the most significant usable split. O(n·p²).
 */
enum {
    SS_OFFSETS = 0,   /* each row's time before the window's last sample, s */
    SS_K_AFTER = 1,   /* K fitted to the rows from this one on */
    SS_K_BEFORE = 2,  /* K fitted to the rows before it */
    SS_Z_RATIO = 3,   /* Δ over its standard error relative to K̂'s */
    SS_AFTER_VAR = 4, /* var K_after / σ_K² */
    SS_USABLE = 5,    /* 1.0: at least 3 rows on each side, 0.0: not */
    SS_ROWS = 6,      /* out holds SS_ROWS rows of n */
    SS_NO_PROBLEM = -2, /* SplitProblem.of gives None (too few rows, singular, gkk <= 0) */
    SS_NONE_USABLE = -1,
};

static Py_ssize_t split_scan(const double *regressors, const double *measured, Py_ssize_t n,
                             int k, const double *held, double factor, double delay,
                             double window_samples, double fs, double *out, double *target)
{
    const int p = 5 - k;
    const double *rows[5];
    double xr[5], inv[25], gkk, k_hat;
    if (!split_system(regressors, measured, n, k, held, target, rows, xr, inv, &gkk, &k_hat))
        return SS_NO_PROBLEM;
    const double *u = rows[p - 1];
    const double centre = (double)(n - 1) / 2.0;
    double total = 0.0; /* Σ u² over every row, summed from the last (numpy's c[-1, 0]) */
    for (Py_ssize_t t = n - 1; t >= 0; t--) total += u[t] * u[t];
    double *offsets = out + SS_OFFSETS * n, *k_after = out + SS_K_AFTER * n;
    double *k_before = out + SS_K_BEFORE * n, *z_ratio = out + SS_Z_RATIO * n;
    double *after_var = out + SS_AFTER_VAR * n, *usable = out + SS_USABLE * n;
    double c[5] = {0.0, 0.0, 0.0, 0.0, 0.0}, sr = 0.0, best_z = -1.0;
    Py_ssize_t best = SS_NONE_USABLE, first_nan = -1;
    for (Py_ssize_t s = n - 1; s >= 0; s--) {
        const double us = u[s];
        for (int a = 0; a < p; a++) {
            double va = a == 0 ? 1.0 : (a == 1 ? (double)s - centre : rows[a][s]);
            c[a] += va * us;
        }
        sr += target[s] * us;
        double w[5], cw, xw;
        split_weights(inv, c, xr, p, w, &cw, &xw);
        const double pvv = c[p - 1] - cw, pvr = sr - xw, after_k = 1.0 - w[p - 1];
        const int ok = s >= 3 && s <= n - 3 && pvv > 1e-12 * total;
        const double safe = ok ? pvv : 1.0, delta = ok ? pvr / safe : 0.0;
        offsets[s] = (window_samples - 1.0 - (((double)s + 4.0) * factor + delay)) / fs;
        k_after[s] = k_hat + delta * after_k;
        k_before[s] = k_after[s] - delta;
        z_ratio[s] = delta * sqrt(safe * gkk);
        after_var[s] = 1.0 + after_k * after_k / (safe * gkk);
        usable[s] = ok ? 1.0 : 0.0;
        if (ok) { /* numpy's argmax: the first largest, or the first NaN */
            const double z = fabs(z_ratio[s]);
            if (z != z) {
                first_nan = s;
            } else if (z >= best_z) {
                best_z = z;
                best = s;
            }
        }
    }
    return first_nan >= 0 ? first_nan : best;
}

static PyObject *py_split_scan(PyObject *self, PyObject *args)
{
    PyObject *objs[4];
    int k;
    double factor, delay, window_samples, fs;
    if (!PyArg_ParseTuple(args, "OOiOddddO", &objs[0], &objs[1], &k, &objs[2], &factor, &delay,
                          &window_samples, &fs, &objs[3])) {
        return NULL;
    }
    const char *names[4] = {"regressors", "measured", "held", "out"};
    Py_buffer b[4];
    if (get_buffers(objs, 4, 3, names, b) < 0) return NULL;
    Py_ssize_t n = b[1].len / 8;
    PyObject *result = NULL;
    if (k < 0 || k > 2 || b[0].len / 8 != 3 * n || b[2].len / 8 < 2 ||
        b[3].len / 8 != SS_ROWS * n || !(fs > 0.0)) {
        PyErr_SetString(PyExc_ValueError, "split_scan: inconsistent sizes");
    } else {
        double *target = PyMem_Malloc(sizeof(double) * (n > 0 ? n : 1));
        if (target == NULL) {
            PyErr_NoMemory();
        } else {
            Py_ssize_t best = split_scan(b[0].buf, b[1].buf, n, k, b[2].buf, factor, delay,
                                         window_samples, fs, b[3].buf, target);
            PyMem_Free(target);
            result = PyLong_FromSsize_t(best);
        }
    }
    release_buffers(b, 4);
    return result;
}

/* ------------------------------------------------------------------ the window's check sums
 * window_sums(position, torque) -> (Σ position, Σ torque, Σ position²): what
 * rtsid.ident.check.window_sums computes with numpy (its tested reference) in one pass over
 * a window instead of three reductions, for the checks of finite samples and excitation.
 */
static PyObject *py_window_sums(PyObject *self, PyObject *args)
{
    PyObject *objs[2];
    if (!PyArg_ParseTuple(args, "OO", &objs[0], &objs[1])) return NULL;
    const char *names[2] = {"position", "torque"};
    Py_buffer b[2];
    if (get_buffers(objs, 2, 2, names, b) < 0) return NULL;
    PyObject *result = NULL;
    if (b[0].len != b[1].len) {
        PyErr_SetString(PyExc_ValueError, "window_sums: position and torque differ in length");
    } else {
        const double *p = b[0].buf, *t = b[1].buf;
        const Py_ssize_t n = b[0].len / 8;
        double sp = 0.0, st = 0.0, spp = 0.0;
        for (Py_ssize_t i = 0; i < n; i++) {
            sp += p[i];
            st += t[i];
            spp += p[i] * p[i];
        }
        result = Py_BuildValue("(ddd)", sp, st, spp);
    }
    release_buffers(b, 2);
    return result;
}
static PyObject *py_evidence_gains(PyObject *self, PyObject *args);
static PyObject *py_band_table(PyObject *self, PyObject *args);       /* kern625, end of file */
static PyObject *py_oe_window_tabled(PyObject *self, PyObject *args); /* kern625, end of file */
static PyObject *py_low_pass_slopes(PyObject *self, PyObject *args);
static PyObject *py_zero_phase_rows(PyObject *self, PyObject *args);
static PyObject *py_savgol_pair(PyObject *self, PyObject *args);
static PyObject *py_ankle_frames(PyObject *self, PyObject *args); /* socketcand frames, end */
static PyObject *py_reflex_dynamics_fit(PyObject *self, PyObject *args); /* lanesums */
static PyObject *py_onecall_window(PyObject *self, PyObject *args); /* onecall, end */
static PyObject *py_causal_convolve(PyObject *self, PyObject *args); /* lanesums2 */
static PyObject *py_xcorr_lags(PyObject *self, PyObject *args); /* fits4 */
static PyObject *py_evidence_gains_lanes(PyObject *self, PyObject *args); /* fits4 */
static PyObject *py_stencil_correlate(PyObject *self, PyObject *args); /* fits4 */
static PyObject *py_samples_into(PyObject *self, PyObject *args); /* readrest, end */
static PyObject *py_estimate_json(PyObject *self, PyObject *const *args, Py_ssize_t nargs); /* readrest */
static PyObject *py_crc32(PyObject *self, PyObject *args); /* rest7, end */
static PyObject *py_round12(PyObject *self, PyObject *const *args, Py_ssize_t nargs); /* glue7 */
static PyObject *py_savgol_range(PyObject *self, PyObject *args); /* fits6, end */
static PyObject *py_all_finite(PyObject *self, PyObject *args); /* fits6, end */
static PyObject *py_window_scan(PyObject *self, PyObject *const *args, Py_ssize_t nargs); /* eval8 */
static PyObject *py_finite_dict(PyObject *self, PyObject *const *args, Py_ssize_t nargs); /* eval8 */
static PyObject *py_mdl_decompose(PyObject *self, PyObject *args); /* fits7, end */
static PyObject *py_mdl_rank(PyObject *self, PyObject *args); /* fits7, end */
static PyObject *py_median_new(PyObject *self, PyObject *args); /* stream8, end */
static PyObject *py_stream_window(PyObject *self, PyObject *const *args, Py_ssize_t nargs); /* stream8 */
static PyObject *py_tracker_step(PyObject *self, PyObject *const *args, Py_ssize_t nargs); /* stream8 */
static PyObject *py_window_flags(PyObject *self, PyObject *args); /* stream8 */

static PyMethodDef methods[] = {
    {"solve", py_solve, METH_VARARGS,
     "solve(r, b, x, work) -> (status, alpha): symmetric Toeplitz R x = b by EUREKA."},
    {"window_irf", py_window_irf, METH_VARARGS,
     "window_irf(position, torque, taps, factor, sign, detrend, lag, sweeps, ridge, fs, u, y, h, "
     "phi) -> (status, alpha, std(u), position slope, signed torque slope): detrend, "
     "FIR-decimate, correlate, EUREKA and refine one window."},
    {"window_fit", py_window_fit, METH_VARARGS,
     "window_fit(u, y, h, phi, stacked, f, hann, fs, power, uncertainty, params, sens, out) -> "
     "status: linear fit, predictions, VAFs and standard errors of one window."},
    {"oe_design", py_oe_design, METH_VARARGS,
     "oe_design(u, y, fs, regressors, projected, gram) -> status: the output-error design."},
    {"oe_fit", py_oe_fit, METH_VARARGS,
     "oe_fit(regressors, projected, gram, y, k, held, uncertainty, lags, params, se, model) -> "
     "(status, vaf): the output-error fit with the first k parameters held."},
    {"oe_vafs", py_oe_vafs, METH_VARARGS,
     "oe_vafs(u, y, h, params, model, fs, explained, torque_slope, k_position_slope, kmax, "
     "tw_cos, tw_sin) -> (vaf, vaf_irf, vaf_fit) of an output-error fit."},
    {"oe_window", py_oe_window, METH_VARARGS,
     "oe_window(u, y, h, fs, k, held, learn, uncertainty, lags, explained, torque_slope, "
     "position_slope, kmax, tw_cos, tw_sin, newest_rows, regressors, projected, gram, model, "
     "out) -> status: a stream window's output-error back end (OW_* index out)."},
    {"band_table", py_band_table, METH_VARARGS, "band_table(tw_cos, tw_sin, kmax, table): a plan's published-VAF twiddles for oe_window_tabled (((kmax + 3) // 4) * n * 8 doubles)."},
    {"oe_window_tabled", py_oe_window_tabled, METH_VARARGS, "oe_window_tabled(..., out, table) -> status: oe_window with the plan's band_table last, the same numbers."},
    {"band_limit", py_band_limit, METH_VARARGS,
     "band_limit(x, taps, factor, sign, out): sign·x, mean removed, FIR-decimated."},
    {"sos_filtfilt", py_sos_filtfilt, METH_VARARGS,
     "sos_filtfilt(sos, zi, x): scipy's sosfiltfilt passes over an extended x, in place."},
    {"xcorr", py_xcorr, METH_VARARGS,
     "xcorr(u, y, first, last, norm, c): c[k-first] = sum_t u[t] y[t+k] / norm."},
    {"reflex_rect_hop", py_reflex_rect_hop, METH_VARARGS, "reflex_rect_hop(position, first, fs, taps, factor, g, reuse, inputs, in_first, in_count, outputs, out_first, out_count, out) -> (in_first, in_count, out_first, out_count): one hop of the rect reflex stream."},
    {"json_array", py_json_array, METH_VARARGS, "json_array(data, start, stop, kind, out): compact JSON array items into out."},
    {"window_sums", py_window_sums, METH_VARARGS, "window_sums(position, torque) -> (sum of position, sum of torque, sum of position squared)."},
    {"split_scan", py_split_scan, METH_VARARGS, "split_scan(regressors, measured, k, held, factor, delay, window_samples, fs, out) -> best row (-1: none usable, -2: no problem): every split of a window's K (SS_* rows of out)."},
    {"evidence_gains", py_evidence_gains, METH_VARARGS, "evidence_gains(torque, regressors, extra, starts, n, out): slow-lane evidence windows' VAF gains."},
    {"low_pass_slopes", py_low_pass_slopes, METH_VARARGS, "low_pass_slopes(t, wn, zeta, h, slopes): the reflex dynamics' low-pass and its derivatives."},
    {"zero_phase_rows", py_zero_phase_rows, METH_VARARGS, "zero_phase_rows(sos, zi, rows, n, edge, factor, out): scipy's sosfiltfilt of each row, every factor-th sample into out."},
    {"savgol_pair", py_savgol_pair, METH_VARARGS, "savgol_pair(x, taps1, taps2, d1, d2): ndimage.convolve1d(x, taps, mode='constant') of two filters."},
    {"ankle_frames", py_ankle_frames, METH_VARARGS, "ankle_frames(data, ident, position_scale, torque_scale, counter, position, torque, status, bus_time) -> n (< 0: not the common case): socketcand state frames of the built-in protocol."},
    {"reflex_dynamics_fit", py_reflex_dynamics_fit, METH_VARARGS, "reflex_dynamics_fit(g, lags, start, low, high, scale, tolerance, max_evaluations, x) -> cost (< 0: singular): the reflex dynamics fit in one call."},
    {"onecall_window", py_onecall_window, METH_VARARGS, "onecall_window(position, torque, explained, h, arrays, consts, state) -> status (0: done, else declined): a stream's window from its checks to its back end (section onecall)."},
    {"causal_convolve", py_causal_convolve, METH_VARARGS, "causal_convolve(r, g, scale, out): out[t] = sum_k (g[k] / scale) r[t-k], the first len(r) samples of numpy.convolve(r, g / scale)."},
    {"xcorr_lags", py_xcorr_lags, METH_VARARGS, "xcorr_lags(u, y, first, last, norm, c): xcorr bit for bit, sixteen lags at a time (section fits4)."},
    {"evidence_gains_lanes", py_evidence_gains_lanes, METH_VARARGS, "evidence_gains_lanes(torque, regressors, extra, starts, n, out): evidence_gains bit for bit, four windows at a time (section fits4)."},
    {"stencil_correlate", py_stencil_correlate, METH_VARARGS, "stencil_correlate(x, taps, scale, out): numpy.correlate(x, taps, 'valid') * scale bit for bit (section fits4)."},
    {"samples_into", py_samples_into, METH_VARARGS, "samples_into(data, position, torque, valid, status, offset) -> (first_index, fs_hz, rows) or None: a compact samples payload into preallocated columns (section readrest)."},
    {"estimate_json", (PyCFunction)(void (*)(void))py_estimate_json, METH_FASTCALL, "estimate_json(message, keys, prefixes) -> bytes or None: an estimate message as json.dumps writes it (section readrest)."},
    {"crc32", py_crc32, METH_VARARGS, "crc32(data, value=0) -> int: zlib.crc32(data, value), sixteen bytes at a time (section rest7)."},
    {"round12", (PyCFunction)(void (*)(void))py_round12, METH_FASTCALL, "round12(*values) -> tuple: round(value, 12) of each float, as Python gives it (section glue7)."},
    {"savgol_range", py_savgol_range, METH_VARARGS, "savgol_range(x, taps1, taps2, lo, hi, d1, d2): savgol_pair's interior outputs lo … hi − 1 only (section fits6)."},
    {"all_finite", py_all_finite, METH_VARARGS, "all_finite(x, y) -> bool: no NaN nor infinity in x nor y (section fits6)."},
    {"window_scan", (PyCFunction)(void (*)(void))py_window_scan, METH_FASTCALL, "window_scan(position, torque, valid, status, start, stop) -> (status bits raised, all valid, sums finite) or None (section eval8)."},
    {"finite_dict", (PyCFunction)(void (*)(void))py_finite_dict, METH_FASTCALL, "finite_dict(names, values) -> dict of names to values, non-finite floats as None (section eval8)."},
    {"mdl_decompose", py_mdl_decompose, METH_VARARGS, "mdl_decompose(phi_rr) -> bytes: a symmetric Toeplitz matrix's halves tridiagonalised, their eigenvalues and QL rotations, for mdl_rank (section fits7)."},
    {"mdl_rank", py_mdl_rank, METH_VARARGS, "mdl_rank(decomposition, full, power_e, n_samples, out) -> rank: reflex.mdl_projection's rank and projected solution (into out) without eigenvectors (section fits7)."},
    {"median_new", py_median_new, METH_VARARGS, "median_new(horizon, min_count) -> a running median (add, median): rtsid.ident.stream.RunningMedian compiled (section stream8)."},
    {"stream_window", (PyCFunction)(void (*)(void))py_stream_window, METH_FASTCALL, "stream_window(position, torque, explained, h, work, consts, state, out, excitation, inertia, damping, context) -> None or (estimate, learned, newest): onecall_window and the stream's bookkeeping (section stream8)."},
    {"tracker_step", (PyCFunction)(void (*)(void))py_tracker_step, METH_FASTCALL, "tracker_step(tracker, t_s, z, se, newest, split, record) -> TrackEstimate or None: ParameterTracker.step of a calm window, read and written in the instance dictionaries (section stream8)."},
    {"window_flags", py_window_flags, METH_VARARGS, "window_flags(params, se, vafs, low_vaf_percent, flags) -> tuple: stream_window's flags, rtsid.ident.assess.window_flags compiled (section stream8)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_eureka", "Compiled EUREKA / Levinson kernel.", -1, methods,
};

/* window_fit's status codes, exported so that Python reads them from here (one source). */
PyMODINIT_FUNC PyInit__eureka(void)
{
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) return NULL;
    if (PyModule_AddIntConstant(m, "FIT_OK", FIT_OK) < 0 ||
        PyModule_AddIntConstant(m, "FIT_FIRST_SINGULAR", FIT_FIRST_SINGULAR) < 0 ||
        PyModule_AddIntConstant(m, "FIT_FINAL_SINGULAR", FIT_FINAL_SINGULAR) < 0 ||
        PyModule_AddIntConstant(m, "FIT_NOT_PD", FIT_NOT_PD) < 0 ||
        PyModule_AddIntConstant(m, "FIT_ZERO_RESPONSE", FIT_ZERO_RESPONSE) < 0 ||
        PyModule_AddIntConstant(m, "OE_OK", OE_OK) < 0 ||
        PyModule_AddIntConstant(m, "OE_ZERO_TORQUE", OE_ZERO_TORQUE) < 0 ||
        PyModule_AddIntConstant(m, "OE_INSEPARABLE", OE_INSEPARABLE) < 0 ||
        PyModule_AddIntConstant(m, "OW_WHOLE", OW_WHOLE) < 0 ||
        PyModule_AddIntConstant(m, "OW_PARAMS", OW_PARAMS) < 0 ||
        PyModule_AddIntConstant(m, "OW_SE", OW_SE) < 0 ||
        PyModule_AddIntConstant(m, "OW_VAFS", OW_VAFS) < 0 ||
        PyModule_AddIntConstant(m, "OW_NEWEST", OW_NEWEST) < 0 ||
        PyModule_AddIntConstant(m, "OW_SIZE", OW_SIZE) < 0 ||
        PyModule_AddIntConstant(m, "SS_ROWS", SS_ROWS) < 0 ||
        PyModule_AddIntConstant(m, "SS_NO_PROBLEM", SS_NO_PROBLEM) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}


/* ------------------------------------------------------------------ sample batches (replay)
 * json_array(data, start, stop, kind, out) -> None: the items of a compact JSON array,
 * data[start:stop] (between its brackets, no whitespace: what rtsid's sample logger writes),
 * into out:
 *   kind 0  numbers or null (NaN) -> float64; a number is converted by Python's own
 *           correctly rounded conversion (PyOS_string_to_double, as float() and json.loads
 *           do), so the doubles are json.loads's bit for bit;
 *   kind 1  true / false -> bool (one byte each);
 *   kind 2  integers -> int64.
 * Anything else (whitespace, another token, an integer in a float column, an integer beyond
 * int64, more or fewer items than len(out)) raises ValueError: rtsid.io.schemas then reads
 * the payload with json.loads, the reference, which accepts it or says what is wrong.
 */
#define JSON_NUMBER_MAX 64

/* End of the JSON number at s[i] (before stop), or -1; *integer: no fraction, no exponent. */
static Py_ssize_t json_number_end(const char *s, Py_ssize_t i, Py_ssize_t stop, int *integer)
{
    Py_ssize_t k = i, d;
    *integer = 1;
    if (k < stop && s[k] == '-') k++;
    if (k >= stop) return -1;
    if (s[k] == '0') {
        k++;
    } else if (s[k] >= '1' && s[k] <= '9') {
        while (k < stop && s[k] >= '0' && s[k] <= '9') k++;
    } else {
        return -1;
    }
    if (k < stop && s[k] == '.') {
        *integer = 0;
        d = ++k;
        while (k < stop && s[k] >= '0' && s[k] <= '9') k++;
        if (k == d) return -1;
    }
    if (k < stop && (s[k] == 'e' || s[k] == 'E')) {
        *integer = 0;
        k++;
        if (k < stop && (s[k] == '+' || s[k] == '-')) k++;
        d = k;
        while (k < stop && s[k] >= '0' && s[k] <= '9') k++;
        if (k == d) return -1;
    }
    return k;
}

static int json_literal(const char *s, Py_ssize_t i, Py_ssize_t stop, const char *word)
{
    Py_ssize_t n = (Py_ssize_t)strlen(word);
    return stop - i >= n && memcmp(s + i, word, (size_t)n) == 0 ? (int)n : 0;
}

/* The number s[i:k] (JSON grammar checked) by one correctly rounded extended-precision
 * operation, digits (< 2^64, exact) times or over a power of ten (10^0..10^27: exact in a
 * 64-bit significand), then rounded to double. Rounding twice can differ from rounding once
 * only when the extended result lies exactly halfway between two doubles; then, and for
 * anything else this does not cover (more digits, a larger exponent, a subnormal result, a
 * long double that is not x87's), returns 0 and the caller uses PyOS_string_to_double. */
static int decimal_fast(const char *s, Py_ssize_t i, Py_ssize_t k, double *out)
{
#if LDBL_MANT_DIG == 64
    static const long double pow10[28] = {
        1e0L, 1e1L, 1e2L, 1e3L, 1e4L, 1e5L, 1e6L, 1e7L, 1e8L, 1e9L, 1e10L, 1e11L, 1e12L, 1e13L,
        1e14L, 1e15L, 1e16L, 1e17L, 1e18L, 1e19L, 1e20L, 1e21L, 1e22L, 1e23L, 1e24L, 1e25L,
        1e26L, 1e27L};
    int negative = s[i] == '-';
    unsigned long long w = 0;
    long scale = 0, exponent = 0;
    Py_ssize_t j = i + negative;
    for (; j < k && s[j] >= '0' && s[j] <= '9'; j++) {
        if (w > (ULLONG_MAX - 9) / 10) return 0;
        w = w * 10 + (unsigned)(s[j] - '0');
    }
    if (j < k && s[j] == '.') {
        for (j++; j < k && s[j] >= '0' && s[j] <= '9'; j++) {
            if (w > (ULLONG_MAX - 9) / 10) return 0;
            w = w * 10 + (unsigned)(s[j] - '0');
            scale--;
        }
    }
    if (j < k) { /* e / E, sign, digits */
        int minus = 0;
        j++;
        if (s[j] == '+' || s[j] == '-') minus = s[j++] == '-';
        for (; j < k; j++) {
            if (exponent > 1000) return 0;
            exponent = exponent * 10 + (s[j] - '0');
        }
        scale += minus ? -exponent : exponent;
    }
    if (w == 0) {
        *out = negative ? -0.0 : 0.0;
        return 1;
    }
    if (scale < -27 || scale > 27) return 0;
    long double r = (long double)w;
    r = scale < 0 ? r / pow10[-scale] : r * pow10[scale];
    double d = (double)r;
    if ((long double)d != r) {
        double other = r > (long double)d ? nextafter(d, INFINITY) : nextafter(d, -INFINITY);
        if (((long double)d + (long double)other) * 0.5L == r) return 0; /* halfway */
    }
    if (!(d >= DBL_MIN && d <= DBL_MAX)) return 0;
    *out = negative ? -d : d;
    return 1;
#else
    (void)s; (void)i; (void)k; (void)out;
    return 0;
#endif
}

/* One item at s[i]; returns its end or -1. */
static Py_ssize_t json_item(const char *s, Py_ssize_t i, Py_ssize_t stop, int kind, char *out)
{
    int integer, n;
    Py_ssize_t k;
    if (kind == 1) {
        if ((n = json_literal(s, i, stop, "true")) > 0) { *(unsigned char *)out = 1; return i + n; }
        if ((n = json_literal(s, i, stop, "false")) > 0) { *(unsigned char *)out = 0; return i + n; }
        return -1;
    }
    if (kind == 0 && (n = json_literal(s, i, stop, "null")) > 0) {
        *(double *)out = NAN;
        return i + n;
    }
    k = json_number_end(s, i, stop, &integer);
    if (k < 0 || k - i >= JSON_NUMBER_MAX) return -1;
    if (kind == 2) {
        if (!integer) return -1;
        long long value = 0;
        int negative = s[i] == '-';
        for (Py_ssize_t j = i + negative; j < k; j++) {
            int digit = s[j] - '0';
            if (value > (LLONG_MAX - digit) / 10) return -1; /* beyond int64: the reference says */
            value = value * 10 + digit;
        }
        *(long long *)out = negative ? -value : value;
        return k;
    }
    if (integer) return -1; /* json.loads makes an int of it ("-0" is +0.0): the reference */
    if (decimal_fast(s, i, k, (double *)out)) return k;
    char token[JSON_NUMBER_MAX];
    memcpy(token, s + i, (size_t)(k - i));
    token[k - i] = '\0';
    char *end = NULL;
    double value = PyOS_string_to_double(token, &end, NULL);
    if (end != token + (k - i)) {
        PyErr_Clear();
        return -1;
    }
    *(double *)out = value;
    return k;
}

static PyObject *py_json_array(PyObject *self, PyObject *args)
{
    Py_buffer data, out;
    Py_ssize_t start, stop;
    int kind;
    if (!PyArg_ParseTuple(args, "y*nniw*", &data, &start, &stop, &kind, &out)) return NULL;
    const Py_ssize_t size = kind == 1 ? 1 : 8;
    const Py_ssize_t count = out.len / size;
    const char *s = (const char *)data.buf;
    char *o = (char *)out.buf;
    Py_ssize_t i = start, items = 0;
    int ok = kind >= 0 && kind <= 2 && out.len % size == 0 && 0 <= start && start <= stop &&
             stop <= data.len;
    while (ok && i < stop) {
        if (items > 0) {
            if (s[i] != ',') { ok = 0; break; }
            i++;
        }
        if (items >= count) { ok = 0; break; }
        i = json_item(s, i, stop, kind, o + items * size);
        ok = i >= 0;
        items++;
    }
    PyBuffer_Release(&data);
    PyBuffer_Release(&out);
    if (!ok || items != count) {
        PyErr_SetString(PyExc_ValueError, "json_array: not a compact JSON array of this kind");
        return NULL;
    }
    Py_RETURN_NONE;
}


/* ------------------------------------------------------------------ slow lane's reflex fit
 * (issue 22, fits2) The slow lane's evidence check, many small steps in numpy:
 *
 * evidence_gains(torque, regressors, extra, starts, n, out): for each window [a, a + n) with
 *   a in starts, the VAF that counting `extra` as part of the model adds to the window's own
 *   least-squares (θ̈, θ̇, θ, offset, trend) fit on the window VAF basis; the numpy reference
 *   is rtsid.ident.yardstick.WindowVafBasis.least_squares_vaf_gains (the same steps: centred
 *   regressors scaled to unit norm, the 4 × 4 normal equations with both right-hand sides).
 *   O(windows·n).
 * low_pass_slopes(t, wn, zeta, h, slopes): the reflex dynamics fit's delayed low-pass and its
 *   derivatives by t, ωn and ζ at every step of the fit (rtsid.ident.reflex._low_pass_and_slopes).
 */
static int get_indices(PyObject *obj, Py_buffer *view, const char *name)
{
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) != 0) return -1;
    if (view->itemsize != 8 || view->format == NULL ||
        (strcmp(view->format, "q") != 0 && strcmp(view->format, "l") != 0)) {
        PyErr_Format(PyExc_TypeError, "%s must be a contiguous int64 buffer", name);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

/* One evidence window: x the window's torque, r the three regressor rows at its start (row
 * stride `stride`), e the extra torque; the VAF gain, percentage points. */
static double evidence_gain(const double *x, const double *r, Py_ssize_t stride, const double *e,
                            Py_ssize_t n)
{
    double mean[5] = {0.0, 0.0, 0.0, 0.0, 0.0}; /* θ̈, θ̇, θ, torque, extra */
    for (Py_ssize_t i = 0; i < n; i++) {
        mean[0] += r[i];
        mean[1] += r[stride + i];
        mean[2] += r[2 * stride + i];
        mean[3] += x[i];
        mean[4] += e[i];
    }
    for (int k = 0; k < 5; k++) mean[k] /= (double)n;
    const double step = 2.0 / (double)(n - 1);
    /* Gram of the centred columns (θ̈, θ̇, θ, trend) and their products with the two targets
     * (measured − added, measured), unscaled; scaled to unit-norm columns below */
    double gram[16] = {0.0}, rhs[8] = {0.0}, power = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        const double col[4] = {r[i] - mean[0], r[stride + i] - mean[1],
                               r[2 * stride + i] - mean[2],
                               i == n - 1 ? 1.0 : (double)i * step - 1.0};
        const double measured = x[i] - mean[3], added = e[i] - mean[4];
        for (int a = 0; a < 4; a++) {
            for (int b = a; b < 4; b++) gram[4 * a + b] += col[a] * col[b];
            rhs[2 * a] += col[a] * (measured - added);
            rhs[2 * a + 1] += col[a] * measured;
        }
        power += measured * measured;
    }
    double scale[4];
    for (int a = 0; a < 4; a++) scale[a] = sqrt(gram[5 * a]);
    for (int a = 0; a < 4; a++) {
        for (int b = a; b < 4; b++) {
            gram[4 * a + b] /= scale[a] * scale[b];
            gram[4 * b + a] = gram[4 * a + b];
        }
    }
    int piv[4];
    lu_factor(gram, 4, piv);
    double p[2][4];
    for (int j = 0; j < 2; j++) {
        for (int a = 0; a < 4; a++) p[j][a] = rhs[2 * a + j] / scale[a];
        lu_solve(gram, 4, piv, p[j]);
        for (int a = 0; a < 3; a++) p[j][a] /= scale[a]; /* per unscaled centred column */
    }
    double left[2] = {0.0, 0.0};
    for (Py_ssize_t i = 0; i < n; i++) {
        const double c0 = r[i] - mean[0], c1 = r[stride + i] - mean[1];
        const double c2 = r[2 * stride + i] - mean[2];
        const double measured = x[i] - mean[3], added = e[i] - mean[4];
        const double with = measured - (p[0][0] * c0 + p[0][1] * c1 + p[0][2] * c2) - added;
        const double without = measured - (p[1][0] * c0 + p[1][1] * c1 + p[1][2] * c2);
        left[0] += with * with;
        left[1] += without * without;
    }
    return 100.0 * (1.0 - left[0] / power) - 100.0 * (1.0 - left[1] / power);
}

static PyObject *evidence_entry(PyObject *args, const char *name, int lanes);

static PyObject *py_evidence_gains(PyObject *self, PyObject *args)
{
    return evidence_entry(args, "evidence_gains", 0);
}

/* low_pass_slopes(t, wn, zeta, h, slopes): the reflex dynamics fit's delayed low-pass
 * h(t) = Re A·(e^{p1 t} − e^{p2 t}) (ωn²/(s² + 2ζωn s + ωn²), 0 for t ≤ 0) and its derivatives
 * by t, ωn and ζ into slopes (3 rows of n); rtsid.ident.reflex._low_pass_and_slopes's numpy
 * code is the reference (the same complex formulas; equal to rounding, tested). O(n). */
#include <complex.h>
#undef I /* complex.h's macros would clash with names in later sections (I, inertia) */
#undef complex
/* The low-pass and its slopes at the n times t (h: n values, s: 3 rows of n). */
static void low_pass_slopes_at(const double *t, Py_ssize_t n, double w, double z, double *h,
                               double *s)
{
    if (fabs(z - 1.0) < 1e-6) z = 1.0 + 1e-6;
    const double _Complex root = csqrt(z * z - 1.0 + 0.0 * _Complex_I);
    const double _Complex p1 = w * (-z + root), p2 = w * (-z - root);
    const double _Complex scale = w * w / (p1 - p2);
    const double _Complex c1 = -1.0 + z / root, c2 = -1.0 - z / root;
    const double _Complex by_z = -scale * z / (root * root);
    for (Py_ssize_t i = 0; i < n; i++) {
        if (!(t[i] > 0.0)) {
            h[i] = s[i] = s[n + i] = s[2 * n + i] = 0.0;
            continue;
        }
        const double _Complex e1 = cexp(p1 * t[i]), e2 = cexp(p2 * t[i]);
        h[i] = creal(scale * (e1 - e2));
        s[i] = creal(scale * (p1 * e1 - p2 * e2));
        s[n + i] = (h[i] + t[i] * s[i]) / w;
        s[2 * n + i] = creal(by_z * (e1 - e2) + scale * w * t[i] * (c1 * e1 - c2 * e2));
    }
}

static PyObject *py_low_pass_slopes(PyObject *self, PyObject *args)
{
    PyObject *objs[3];
    double w, z;
    if (!PyArg_ParseTuple(args, "OddOO", &objs[0], &w, &z, &objs[1], &objs[2])) return NULL;
    const char *names[3] = {"t", "h", "slopes"};
    Py_buffer b[3];
    if (get_buffers(objs, 3, 1, names, b) < 0) return NULL;
    const Py_ssize_t n = b[0].len / 8;
    PyObject *result = NULL;
    if (b[1].len != b[0].len || b[2].len != 3 * b[0].len || !(w > 0.0)) {
        PyErr_SetString(PyExc_ValueError, "low_pass_slopes: inconsistent sizes or wn <= 0");
    } else {
        low_pass_slopes_at(b[0].buf, n, w, z, b[1].buf, b[2].buf);
        Py_INCREF(Py_None);
        result = Py_None;
    }
    release_buffers(b, 3);
    return result;
}

/* ------------------------------------------------------------------ slow lane's fits, third pass
 * (branch fits3, issue 22)
 *
 * zero_phase_rows(sos, zi, rows, n, edge, factor, out): scipy's sosfiltfilt (default padding:
 * odd extension by edge samples at each end, steady-state initial conditions zi times the
 * first sample of each pass, direct form II transposed sections) of each of rows (a sequence
 * of contiguous float64 arrays of n samples: no stacking copy), every factor-th sample of the result written to out (rows of ceil(n / factor)):
 * rtsid.ident.reflex.decimated (factor > 1) and zero_phase_rows (factor 1) of several rows
 * in one call. Each row's numbers are scipy's bit for bit: the operations of sos_run_exact
 * in its order, on four rows at once (one in each lane of a four-double vector: lane by lane
 * the same IEEE operations as the scalar code, and no fused multiply-add: the AVX2 clone
 * enables neither FMA nor contraction; missing rows of a last group repeat its last row).
 * The extension is built in an interleaved buffer, so no array is copied in Python.
 * O(rows·(n + 2·edge)·sections).
 */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__ELF__)
#define LANES_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define LANES_CLONES
#endif
#define LANES 4
typedef double lanes_t __attribute__((vector_size(8 * LANES)));

/* The rows' forward and backward passes over the interleaved extension buf (m samples). */
static inline __attribute__((always_inline)) void lanes_filtfilt(const double *sos,
                                                                 const double *zi, const int ns,
                                  lanes_t *buf, Py_ssize_t m)
{
    lanes_t c[16][6], st[16][2];
    for (int s = 0; s < ns; s++)
        for (int k = 0; k < 6; k++) c[s][k] = (lanes_t){0} + sos[6 * s + k];
    for (int backwards = 0; backwards < 2; backwards++) {
        const lanes_t first = backwards ? buf[m - 1] : buf[0];
        for (int s = 0; s < ns; s++) {
            st[s][0] = ((lanes_t){0} + zi[2 * s]) * first;
            st[s][1] = ((lanes_t){0} + zi[2 * s + 1]) * first;
        }
        const Py_ssize_t step = backwards ? -1 : 1;
        lanes_t *p = backwards ? buf + m - 1 : buf;
        for (Py_ssize_t i = 0; i < m; i++, p += step) {
            lanes_t cur = *p;
            for (int s = 0; s < ns; s++) {
                const lanes_t out = c[s][0] * cur + st[s][0];
                st[s][0] = c[s][1] * cur - c[s][4] * out + st[s][1];
                st[s][1] = c[s][2] * cur - c[s][5] * out;
                cur = out;
            }
            *p = cur;
        }
    }
}

/* lanes_filtfilt with the section count known to the compiler (the decimator's four, the
 * window VAF basis's two), so that the sections' loop unrolls and their states stay in
 * registers; an AVX2 clone where the processor has it (the same numbers). */
LANES_CLONES static void lanes_filtfilt_any(const double *sos, const double *zi, int ns,
                                            lanes_t *buf, Py_ssize_t m)
{
    if (ns == 4)
        lanes_filtfilt(sos, zi, 4, buf, m);
    else if (ns == 2)
        lanes_filtfilt(sos, zi, 2, buf, m);
    else
        lanes_filtfilt(sos, zi, ns, buf, m);
}

/* fits5 (section at the end of this file): the rows into and out of the interleaved buffer */
static void lanes_extend(const double *const *row, Py_ssize_t n, Py_ssize_t e, lanes_t *buf);
static void lanes_read_out(const lanes_t *buf, Py_ssize_t kept, Py_ssize_t factor,
                           double *const *out);

/* The rows of a sequence of float64 arrays of n samples each: their buffers (rows[r].buf),
 * or NULL with an error set (a row not a contiguous float64 array of n samples). */
static Py_buffer *row_buffers(PyObject *seq, Py_ssize_t rows, Py_ssize_t n)
{
    Py_buffer *b = PyMem_Calloc((size_t)rows, sizeof(Py_buffer));
    if (b == NULL) return (Py_buffer *)PyErr_NoMemory();
    for (Py_ssize_t r = 0; r < rows; r++) {
        if (get_doubles(PySequence_Fast_GET_ITEM(seq, r), &b[r], 0, "each row") < 0 ||
            b[r].len != 8 * n) {
            if (!PyErr_Occurred())
                PyErr_SetString(PyExc_ValueError, "zero_phase_rows: inconsistent sizes");
            for (Py_ssize_t q = 0; q < r + (b[r].obj != NULL); q++) PyBuffer_Release(&b[q]);
            PyMem_Free(b);
            return NULL;
        }
    }
    return b;
}

static PyObject *py_zero_phase_rows(PyObject *self, PyObject *args)
{
    PyObject *objs[3], *given;
    Py_ssize_t n, edge, factor;
    if (!PyArg_ParseTuple(args, "OOOnnnO", &objs[0], &objs[1], &given, &n, &edge, &factor,
                          &objs[2]))
        return NULL;
    PyObject *seq = PySequence_Fast(given, "zero_phase_rows: x must be a sequence of rows");
    if (seq == NULL) return NULL;
    const char *names[3] = {"sos", "zi", "out"};
    Py_buffer b[3];
    if (get_buffers(objs, 3, 2, names, b) < 0) {
        Py_DECREF(seq);
        return NULL;
    }
    const Py_ssize_t ns = b[0].len / 48, rows = PySequence_Fast_GET_SIZE(seq);
    const Py_ssize_t kept = factor > 0 ? (n + factor - 1) / factor : 0;
    PyObject *result = NULL;
    lanes_t *buf = NULL;
    Py_buffer *rb = NULL;
    if (ns < 1 || ns > 16 || b[0].len != 48 * ns || b[1].len != 16 * ns || n < 2 ||
        edge < 1 || edge >= n || factor < 1 || rows < 1 || b[2].len != 8 * kept * rows) {
        PyErr_SetString(PyExc_ValueError, "zero_phase_rows: inconsistent sizes");
    } else if ((rb = row_buffers(seq, rows, n)) == NULL) {
        /* the error is set */
    } else if ((buf = aligned_alloc(sizeof(lanes_t), sizeof(lanes_t) * (size_t)(n + 2 * edge))) ==
               NULL) {
        PyErr_NoMemory();
    } else {
        double *out = b[2].buf;
        for (Py_ssize_t r = 0; r < rows; r += LANES) {
            const double *row[LANES];
            Py_ssize_t at[LANES];
            for (int q = 0; q < LANES; q++) {
                at[q] = r + q < rows ? r + q : rows - 1; /* a short last group: its last row */
                row[q] = rb[at[q]].buf;
            }
            lanes_extend(row, n, edge, buf);
            lanes_filtfilt_any(b[0].buf, b[1].buf, (int)ns, buf, n + 2 * edge);
            double *rows_out[LANES];
            for (int q = 0; q < LANES; q++) rows_out[q] = out + at[q] * kept;
            lanes_read_out(buf + edge, kept, factor, rows_out);
        }
        Py_INCREF(Py_None);
        result = Py_None;
    }
    free(buf);
    if (rb != NULL) {
        for (Py_ssize_t r = 0; r < rows; r++) PyBuffer_Release(&rb[r]);
        PyMem_Free(rb);
    }
    release_buffers(b, 3);
    Py_DECREF(seq);
    return result;
}

/* savgol_pair(x, taps1, taps2, d1, d2): scipy.ndimage.convolve1d(x, taps, mode="constant")
 * for two filters of the same odd length at once (rtsid.ident.yardstick.savgol_derivatives'
 * first and second derivative; its ndimage call is the reference): each output is ndimage's
 * correlation with the reversed taps in its order of operations — for taps symmetric (or
 * antisymmetric) within DBL_EPSILON, the centre tap's product and then, from the outermost
 * pair inwards, (x[i+j] ± x[i−j])·w[j] added; otherwise every product from the first tap
 * on after the last one's — so the same numbers bit for bit (tested). Zero outside x.
 * O(n·taps). */
static int ndimage_symmetry(const double *fw, Py_ssize_t half)
{
    /* fw: the correlation taps centred (fw[-half … half]); 1 symmetric, -1 antisymmetric */
    int symmetric = 1;
    for (Py_ssize_t j = 1; j <= half; j++)
        if (fabs(fw[j] - fw[-j]) > DBL_EPSILON) {
            symmetric = 0;
            break;
        }
    if (symmetric) return 1;
    for (Py_ssize_t j = 1; j <= half; j++)
        if (fabs(fw[j] + fw[-j]) > DBL_EPSILON) return 0;
    return -1;
}

static inline double ndimage_point(const double *x, Py_ssize_t n, Py_ssize_t i, const double *fw,
                                   Py_ssize_t half, int symmetry, int inside)
{
#define AT(k) (inside || (i + (k) >= 0 && i + (k) < n) ? x[i + (k)] : 0.0)
    double out;
    if (symmetry > 0) {
        out = AT(0) * fw[0];
        for (Py_ssize_t j = -half; j < 0; j++) out += (AT(j) + AT(-j)) * fw[j];
    } else if (symmetry < 0) {
        out = AT(0) * fw[0];
        for (Py_ssize_t j = -half; j < 0; j++) out += (AT(j) - AT(-j)) * fw[j];
    } else {
        out = AT(half) * fw[half];
        for (Py_ssize_t j = -half; j < half; j++) out += AT(j) * fw[j];
    }
    return out;
#undef AT
}

/* ndimage_point at LANES consecutive interior outputs i … i+LANES−1 at once, lane by lane the
 * same operations (an AVX2 clone where the processor has it). */
typedef double lanes_u __attribute__((vector_size(8 * LANES), aligned(8))); /* unaligned loads */

LANES_CLONES static Py_ssize_t ndimage_interior(const double *x, Py_ssize_t n, const double *fw,
                                                Py_ssize_t half, int symmetry, double *out)
{
    Py_ssize_t i = half;
    for (; i + LANES <= n - half; i += LANES) {
        const double *c = x + i;
        lanes_t acc;
        if (symmetry > 0) {
            acc = *(const lanes_u *)c * fw[0];
            for (Py_ssize_t j = -half; j < 0; j++)
                acc += (*(const lanes_u *)(c + j) + *(const lanes_u *)(c - j)) * fw[j];
        } else if (symmetry < 0) {
            acc = *(const lanes_u *)c * fw[0];
            for (Py_ssize_t j = -half; j < 0; j++)
                acc += (*(const lanes_u *)(c + j) - *(const lanes_u *)(c - j)) * fw[j];
        } else {
            acc = *(const lanes_u *)(c + half) * fw[half];
            for (Py_ssize_t j = -half; j < half; j++) acc += *(const lanes_u *)(c + j) * fw[j];
        }
        *(lanes_u *)(out + i) = acc;
    }
    return i; /* the first interior output not formed */
}

static void ndimage_convolve(const double *x, Py_ssize_t n, const double *taps, Py_ssize_t size,
                             double *out)
{
    double reversed[64];
    for (Py_ssize_t k = 0; k < size; k++) reversed[k] = taps[size - 1 - k];
    const Py_ssize_t half = size / 2;
    const double *fw = reversed + half;
    const int symmetry = ndimage_symmetry(fw, half);
    const Py_ssize_t formed = n > 2 * half ? ndimage_interior(x, n, fw, half, symmetry, out) : 0;
    const Py_ssize_t head = half < n ? half : n; /* then the interior left over and the tail */
    for (Py_ssize_t i = 0; i < head; i++) out[i] = ndimage_point(x, n, i, fw, half, symmetry, 0);
    for (Py_ssize_t i = formed > head ? formed : head; i < n; i++) {
        const int inside = i >= half && i < n - half;
        out[i] = ndimage_point(x, n, i, fw, half, symmetry, inside);
    }
}

static PyObject *py_savgol_pair(PyObject *self, PyObject *args)
{
    PyObject *objs[5];
    if (!PyArg_ParseTuple(args, "OOOOO", &objs[0], &objs[1], &objs[2], &objs[3], &objs[4]))
        return NULL;
    const char *names[5] = {"x", "taps1", "taps2", "d1", "d2"};
    Py_buffer b[5];
    if (get_buffers(objs, 5, 3, names, b) < 0) return NULL;
    const Py_ssize_t n = b[0].len / 8, size = b[1].len / 8;
    PyObject *result = NULL;
    if (size < 1 || size > 63 || size % 2 == 0 || b[2].len != b[1].len || b[3].len != b[0].len ||
        b[4].len != b[0].len) {
        PyErr_SetString(PyExc_ValueError, "savgol_pair: inconsistent sizes");
    } else {
        ndimage_convolve(b[0].buf, n, b[1].buf, size, b[3].buf);
        ndimage_convolve(b[0].buf, n, b[2].buf, size, b[4].buf);
        Py_INCREF(Py_None);
        result = Py_None;
    }
    release_buffers(b, 5);
    return result;
}
#undef LANES
#undef LANES_CLONES

/* ------------------------------------------------------------------ the window path at a full-rate plan (issue 22)
 * At the plant's plan (2500 Hz analysis, ±50 lags, M = 750) a window's compiled work is sums
 * of products over lags: the refinement sweeps' predictions and gradients and the front end's
 * correlations (O(M·L)), the IRF's prediction in the back end (O(M·L)) and the sandwich's
 * smoothing (O(M·lags)). Written one output at a time, each sum is a chain of dependent
 * additions that waits on the adder and reloads its operands per output. These loops compute
 * BLOCK outputs at a time instead: every output still sums the same products in the same order
 * (so the numbers are bit for bit those of the loops they replace, and the pinned numbers hold),
 * but BLOCK independent chains share each load and fill the vector registers.
 *
 * The refinement sweeps no longer sum over the window: a sweep's gradient is X'y − (X'X)·h/fs
 * on the rows' Gram matrix (branch gram, the section "the sweeps on a Gram matrix" below).
 */
#define BLOCK 8 /* outputs per block: four pairs of lanes */

#if defined(__GNUC__) || defined(__clang__)
/* Two doubles per register (SSE2, the x86-64 baseline; NEON on arm64): each lane does the
 * scalar loop's IEEE multiply and add, so a lane's sum is the scalar sum bit for bit. */
typedef double lane_pair __attribute__((vector_size(16)));
#define LANE_PAIRS 1
static inline lane_pair pair_at(const double *p)
{
    lane_pair v;
    memcpy(&v, p, sizeof v);
    return v;
}
static inline lane_pair pair_of(double x)
{
    lane_pair v = {x, x};
    return v;
}
#endif

/* out[t] = Σ_{j=0}^{nh−1} h[j]·u[t + lag − j] (in j order) for t = t0 … t1−1. */
static void lagged_predict(const double *h, const double *u, Py_ssize_t nh, Py_ssize_t lag,
                           Py_ssize_t t0, Py_ssize_t t1, double *out)
{
    Py_ssize_t t = t0;
#ifdef G7_QUADS
    t = g7_predict_rows(h, u, nh, lag, t0, t1, out); /* glue7, then the rest */
#endif
#ifdef LANE_PAIRS
    for (; t + BLOCK <= t1; t += BLOCK) {
        lane_pair a0 = pair_of(0.0), a1 = a0, a2 = a0, a3 = a0;
        for (Py_ssize_t j = 0; j < nh; j++) {
            const lane_pair hj = pair_of(h[j]);
            const double *src = u + t + lag - j;
            a0 += hj * pair_at(src);
            a1 += hj * pair_at(src + 2);
            a2 += hj * pair_at(src + 4);
            a3 += hj * pair_at(src + 6);
        }
        memcpy(out + t, &a0, 16);
        memcpy(out + t + 2, &a1, 16);
        memcpy(out + t + 4, &a2, 16);
        memcpy(out + t + 6, &a3, 16);
    }
#endif
    for (; t < t1; t++) {
        double acc = 0.0;
        for (Py_ssize_t j = 0; j < nh; j++) acc += h[j] * u[t + lag - j];
        out[t] = acc;
    }
}

/* xcorr's c[k − first] = Σ_t u[t]·y[t + k] / norm (t ascending over the overlap), BLOCK lags
 * at a time: each lag's own first samples, the block's common span, then its own last ones. */
static void xcorr_blocked(const double *u, const double *y, Py_ssize_t n, Py_ssize_t first,
                          Py_ssize_t last, double norm, double *c)
{
    Py_ssize_t k0 = first;
#ifdef LANE_PAIRS
    for (; k0 + BLOCK - 1 <= last; k0 += BLOCK) {
        double acc[BLOCK] = {0.0};
        Py_ssize_t lo[BLOCK], hi[BLOCK], common_lo = 0, common_hi = n;
        for (int b = 0; b < BLOCK; b++) {
            const Py_ssize_t k = k0 + b;
            lo[b] = k < 0 ? -k : 0;
            hi[b] = k > 0 ? n - k : n;
            if (lo[b] > common_lo) common_lo = lo[b];
            if (hi[b] < common_hi) common_hi = hi[b];
        }
        if (common_hi < common_lo) common_hi = common_lo;
        for (int b = 0; b < BLOCK; b++) {
            for (Py_ssize_t t = lo[b]; t < common_lo && t < hi[b]; t++) acc[b] += u[t] * y[t + k0 + b];
        }
        lane_pair a0 = pair_at(acc), a1 = pair_at(acc + 2), a2 = pair_at(acc + 4),
              a3 = pair_at(acc + 6);
        for (Py_ssize_t t = common_lo; t < common_hi; t++) {
            const lane_pair ut = pair_of(u[t]);
            const double *src = y + t + k0;
            a0 += ut * pair_at(src);
            a1 += ut * pair_at(src + 2);
            a2 += ut * pair_at(src + 4);
            a3 += ut * pair_at(src + 6);
        }
        memcpy(acc, &a0, 16);
        memcpy(acc + 2, &a1, 16);
        memcpy(acc + 4, &a2, 16);
        memcpy(acc + 6, &a3, 16);
        for (int b = 0; b < BLOCK; b++) {
            Py_ssize_t t = common_hi > lo[b] ? common_hi : lo[b];
            if (common_lo >= hi[b]) t = hi[b]; /* all of this lag's span was its own head */
            for (; t < hi[b]; t++) acc[b] += u[t] * y[t + k0 + b];
            c[k0 + b - first] = acc[b] / norm;
        }
    }
#endif
    if (k0 <= last) xcorr(u, y, n, k0, last, norm, c + (k0 - first));
}

/* The sandwich's smoothing, smoothed[t] = Σ_{j=lo}^{hi} row[j]·r[|t − j|] (j ascending, lo and
 * hi the band of `lags` either side clipped to 0 … n−1), BLOCK rows at a time over the row
 * padded with `lags` zeros each side: a padded term adds +0 or −0 to the sum, which leaves it
 * as it was (a sum that is itself zero may change the sign of its zero). */
static void band_smooth(const double *row, const double *r, Py_ssize_t n, Py_ssize_t lags,
                        double *smoothed)
{
    Py_ssize_t t = 0;
#ifdef LANE_PAIRS
    /* the padded row, then r mirrored (mirror[lags + e] = r[|e|], kern625) */
    /* winpath: on the stack when it fits (a stream window's always does), zeroed as calloc's */
    const size_t padded_size = (size_t)(n + 4 * lags + 1);
    double stack[1024];
    double *padded = padded_size <= 1024 ? stack : PyMem_RawCalloc(padded_size, sizeof(double));
    if (padded == stack) memset(stack, 0, sizeof(double) * padded_size);
    if (padded != NULL) {
        memcpy(padded + lags, row, sizeof(double) * (size_t)n);
        double *mirror = padded + n + 2 * lags;
        for (Py_ssize_t e = -lags; e <= lags; e++) mirror[lags + e] = r[e < 0 ? -e : e];
#ifdef G7_QUADS
        t = g7_smooth_rows(padded, mirror, n, lags, smoothed); /* glue7, then the rest */
#endif
        /* kern625: 2·BLOCK rows at a time while they last (the same sums, fewer broadcasts);
         * the rows that were padded before still are, so every output is the same */
        for (; t + 2 * BLOCK <= n; t += 2 * BLOCK) {
            lane_pair a[8];
            for (int b = 0; b < 8; b++) a[b] = pair_of(0.0);
            for (Py_ssize_t e = -lags; e <= lags; e++) {
                const lane_pair re = pair_of(mirror[lags + e]);
                const double *src = padded + lags + t + e;
                for (int b = 0; b < 8; b++) a[b] += pair_at(src + 2 * b) * re;
            }
            memcpy(smoothed + t, a, sizeof a);
        }
        for (; t + BLOCK <= n; t += BLOCK) {
            lane_pair a0 = pair_of(0.0), a1 = a0, a2 = a0, a3 = a0;
            for (Py_ssize_t e = -lags; e <= lags; e++) {
                const lane_pair re = pair_of(r[e < 0 ? -e : e]);
                const double *src = padded + lags + t + e;
                a0 += pair_at(src) * re;
                a1 += pair_at(src + 2) * re;
                a2 += pair_at(src + 4) * re;
                a3 += pair_at(src + 6) * re;
            }
            memcpy(smoothed + t, &a0, 16);
            memcpy(smoothed + t + 2, &a1, 16);
            memcpy(smoothed + t + 4, &a2, 16);
            memcpy(smoothed + t + 6, &a3, 16);
        }
        if (padded != stack) PyMem_RawFree(padded);
    }
#endif
    for (; t < n; t++) {
        Py_ssize_t lo = t - lags < 0 ? 0 : t - lags, hi = t + lags >= n ? n - 1 : t + lags;
        double acc = 0.0;
        for (Py_ssize_t j = lo; j <= hi; j++) acc += row[j] * r[t > j ? t - j : j - t];
        smoothed[t] = acc;
    }
}

/* dot_unrolled's four running sums s0 … s3 (s0 over i ≡ 0 mod 4, …) as two pairs of lanes, the
 * remainder into s0, then (s0 + s1) + (s2 + s3): its result bit for bit. *done = 0 without
 * lanes (dot_unrolled then runs its scalar loop). */
static double dot_lanes(const double *u, const double *v, Py_ssize_t n, int *done)
{
#ifdef LANE_PAIRS
    lane_pair s01 = pair_of(0.0), s23 = s01;
    Py_ssize_t i = 0;
    for (; i + 4 <= n; i += 4) {
        s01 += pair_at(u + i) * pair_at(v + i);
        s23 += pair_at(u + i + 2) * pair_at(v + i + 2);
    }
    double s[4];
    memcpy(s, &s01, 16);
    memcpy(s + 2, &s23, 16);
    for (; i < n; i++) s[0] += u[i] * v[i];
    *done = 1;
    return (s[0] + s[1]) + (s[2] + s[3]);
#else
    (void)u, (void)v, (void)n;
    *done = 0;
    return 0.0;
#endif
}

/* band_vaf's sums over the DFT bins 1 … kmax, four bins at a time: per bin the measured and
 * residual spectra's real parts (one pair of lanes) and imaginary parts (another) accumulate
 * over t in order, and each bin's power adds to total and left in bin order, as band_vaf's own
 * loop. Returns the first bin left for that loop (kmax + 1 when none). */
static Py_ssize_t band_powers(const double *meas, const double *err, Py_ssize_t n,
                              Py_ssize_t kmax, const double *tw_cos, const double *tw_sin,
                              double *total, double *left)
{
    Py_ssize_t k = 1;
#ifdef LANE_PAIRS
    enum { BINS = 4 };
    for (; k + BINS - 1 <= kmax; k += BINS) {
        lane_pair re[BINS], im[BINS]; /* {measured, residual} */
        Py_ssize_t idx[BINS];
        for (int b = 0; b < BINS; b++) {
            re[b] = im[b] = pair_of(0.0);
            idx[b] = 0;
        }
        for (Py_ssize_t t = 0; t < n; t++) {
            const lane_pair x = {meas[t], err[t]};
            for (int b = 0; b < BINS; b++) {
                re[b] += x * pair_of(tw_cos[idx[b]]);
                im[b] -= x * pair_of(tw_sin[idx[b]]);
                idx[b] += k + b;
                if (idx[b] >= n) idx[b] -= n;
            }
        }
        for (int b = 0; b < BINS; b++) {
            double r2[2], i2[2];
            memcpy(r2, &re[b], 16);
            memcpy(i2, &im[b], 16);
            *total += r2[0] * r2[0] + i2[0] * i2[0];
            *left += r2[1] * r2[1] + i2[1] * i2[1];
        }
    }
#else
    (void)meas, (void)err, (void)n, (void)kmax, (void)tw_cos, (void)tw_sin, (void)total,
        (void)left;
#endif
    return k;
}

/* eureka_solve's recursion for R alone (first column r): the prediction-error filter a_k of each
 * step k stored reversed (filters + k(k+1)/2, k + 1 values: a_k[k], …, a_k[0]) with its error
 * variance alphas[k], and rr (r reversed) as eureka_solve forms it; the same status and alpha.
 * eureka_apply then solves R x = b for any b with eureka_solve's arithmetic, bit for bit, without
 * the filter's half of the work: the refinement sweeps solve with one R four times. */
GLUE7_CLONES static Py_ssize_t eureka_filters(const double *r, double *rr, double *filters, double *alphas,
                                 Py_ssize_t n, double *alpha_out)
{
    for (Py_ssize_t j = 0; j < n; j++) rr[j] = r[n - 1 - j];
    double alpha = r[0];
    *alpha_out = alpha;
    if (!(alpha > 0.0)) return 0;
    /* a_k is updated in the last filter's slot (n values), each step's copied out reversed */
    double *cur = filters + n * (n + 1) / 2 - n;
    cur[0] = 1.0;
    filters[0] = 1.0;
    alphas[0] = alpha;
    for (Py_ssize_t k = 1; k < n; k++) {
        const double *rk = rr + (n - 1 - k);
        double refl = -WINDOW_DOT(cur, rk, k) / alpha;
        cur[k] = 0.0;
        Py_ssize_t i = 0, j = k;
        for (; i < j; i++, j--) {
            double ai = cur[i], aj = cur[j];
            cur[i] = ai + refl * aj;
            cur[j] = aj + refl * ai;
        }
        if (i == j) cur[i] += refl * cur[i];
        alpha *= (1.0 - refl * refl);
        *alpha_out = alpha;
        if (!(alpha > 0.0)) return k;
        alphas[k] = alpha;
        if (k < n - 1) { /* the last step's filter is cur itself, stored reversed below */
            double *rev = filters + k * (k + 1) / 2;
            for (Py_ssize_t m = 0; m <= k; m++) rev[m] = cur[k - m];
        }
    }
    if (n > 1) { /* reverse the last filter in place */
        for (Py_ssize_t i = 0, j = n - 1; i < j; i++, j--) {
            double tmp = cur[i];
            cur[i] = cur[j];
            cur[j] = tmp;
        }
    }
    return -1;
}

GLUE7_CLONES static void eureka_apply(const double *rr, const double *filters, const double *alphas,
                         const double *b, double *x, Py_ssize_t n)
{
    x[0] = b[0] / alphas[0];
    for (Py_ssize_t k = 1; k < n; k++) {
        const double *rk = rr + (n - 1 - k), *rev = filters + k * (k + 1) / 2;
        const double mu = (b[k] - WINDOW_DOT(x, rk, k)) / alphas[k];
        x[k] = 0.0;
        for (Py_ssize_t m = 0; m <= k; m++) x[m] += mu * rev[m];
    }
}

/* ------------------------------------------------------------------ socketcand frames (acq4)
 * (issue 22, acq4) The acquisition thread's common case over socketcand: a read holding only
 * the built-in ankle protocol's state frames, in the format socketcand prints them,
 *     < frame ID SEC.USEC HHHHHHHHHHHHHHHH >
 * (ID as given, USEC six digits, the 8 data bytes as 16 hex digits), their counters following
 * one another. The Python reference is rtsid.link.socketcand.parse_records and
 * rtsid.link.mapping.AnkleDecoder.decode_words (held equal by tests/link/test_socketcand.py).
 *
 * ankle_frames(data, ident, position_scale, torque_scale, counter, position, torque, status,
 *   bus_time) -> n: decodes every record of data into the n first items of the five arrays
 *   (int64, float64, float64, uint8, float64): the counter, position = raw · position_scale,
 *   torque = raw · torque_scale, the status nibble, and the timestamp (SEC·10^6 + USEC) / 10^6,
 *   which is float("SEC.USEC") exactly (both the correctly rounded quotient) while it is
 *   below 2^53 µs. Returns -1 when any record is not in that form (or there are more than
 *   the arrays hold), -2 when a checksum fails (the XOR of the 16 nibbles is not 0xA), -3
 *   when the counters do not follow one another (mod 4096): the caller then takes the
 *   frames one by one. O(len(data)).
 */
static int hex_digit(unsigned char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    return -1;
}

/* One record at s[i..]: its fields into the outputs at k; the index after it, or -1/-2. */
static Py_ssize_t ankle_record(const unsigned char *s, Py_ssize_t i, Py_ssize_t len,
                               const char *ident, Py_ssize_t ident_len, double pscale,
                               double tscale, long long *counter, double *pos, double *trq,
                               unsigned char *status, double *stamp)
{
    static const char head[] = "< frame ";
    const Py_ssize_t head_len = 8;
    if (len - i < head_len + ident_len + 1 + 1 + 1 + 6 + 1 + 16 + 2) return -1;
    if (memcmp(s + i, head, (size_t)head_len) != 0) return -1;
    i += head_len;
    if (memcmp(s + i, ident, (size_t)ident_len) != 0 || s[i + ident_len] != ' ') return -1;
    i += ident_len + 1;
    long long micros = 0;
    int digits = 0;
    while (i < len && s[i] >= '0' && s[i] <= '9' && digits < 11) {
        micros = micros * 10 + (s[i] - '0');
        i++;
        digits++;
    }
    if (digits == 0 || digits > 10 || i >= len || s[i] != '.') return -1;
    i++;
    if (len - i < 6 + 1 + 16 + 2) return -1;
    for (int d = 0; d < 6; d++, i++) {
        if (s[i] < '0' || s[i] > '9') return -1;
        micros = micros * 10 + (s[i] - '0');
    }
    if (s[i] != ' ' || micros > (1LL << 53)) return -1;
    i++;
    unsigned long long word = 0;
    int fold = 0;
    for (int b = 0; b < 8; b++) {
        const int hi = hex_digit(s[i + 2 * b]), lo = hex_digit(s[i + 2 * b + 1]);
        if (hi < 0 || lo < 0) return -1;
        fold ^= hi ^ lo;
        word |= (unsigned long long)(hi << 4 | lo) << (8 * b);
    }
    i += 16;
    if (s[i] != ' ' || s[i + 1] != '>') return -1;
    if (fold != 0xA) return -2;
    long long p = (long long)(word & 0xFFFFFFULL), t = (long long)((word >> 24) & 0xFFFFFULL);
    if (p & 0x800000LL) p -= 0x1000000LL;
    if (t & 0x80000LL) t -= 0x100000LL;
    *counter = (long long)((word >> 44) & 0xFFFULL);
    *pos = (double)p * pscale;
    *trq = (double)t * tscale;
    *status = (unsigned char)((word >> 56) & 0xFULL);
    *stamp = (double)micros / 1e6;
    return i + 2;
}

static PyObject *py_ankle_frames(PyObject *self, PyObject *args)
{
    Py_buffer data, out[5];
    const char *ident;
    Py_ssize_t ident_len;
    double pscale, tscale;
    if (!PyArg_ParseTuple(args, "y*y#ddw*w*w*w*w*", &data, &ident, &ident_len, &pscale, &tscale,
                          &out[0], &out[1], &out[2], &out[3], &out[4]))
        return NULL;
    const Py_ssize_t cap = out[0].len / 8;
    Py_ssize_t n = 0, i = 0, result = 0;
    if (out[1].len / 8 < cap || out[2].len / 8 < cap || out[3].len < cap ||
        out[4].len / 8 < cap) {
        result = -1;
    }
    const unsigned char *s = (const unsigned char *)data.buf;
    long long *counter = out[0].buf;
    while (result == 0 && i < data.len) {
        if (n >= cap) {
            result = -1;
            break;
        }
        const Py_ssize_t next =
            ankle_record(s, i, data.len, ident, ident_len, pscale, tscale, counter + n,
                         (double *)out[1].buf + n, (double *)out[2].buf + n,
                         (unsigned char *)out[3].buf + n, (double *)out[4].buf + n);
        if (next < 0) {
            result = next;
            break;
        }
        if (n > 0 && counter[n] != ((counter[n - 1] + 1) & 0xFFF)) result = -3;
        i = next;
        n++;
    }
    PyBuffer_Release(&data);
    for (int k = 0; k < 5; k++) PyBuffer_Release(&out[k]);
    return PyLong_FromSsize_t(result < 0 ? result : n);
}

/* ------------------------------------------------------------------ the sweeps on a Gram matrix (branch gram, issue 22)
 * The refinement sweeps of window_irf, O(L²) each instead of O(M·L). A sweep adds R⁻¹·g·fs to the
 * IRF h, with g the correlation of the input with the prediction error over the fully supported
 * rows t = L … M−L−1, less the ridge's share: g = X'(y − X·h/fs)/inner − loading·h/fs, X the
 * lagged matrix (row t: u(t − k), k = −L … L; inner = M − 2L rows). That is
 * g = (X'y − (X'X)·h/fs)/inner − loading·h/fs: X'X (the rows' Gram matrix) and X'y are formed
 * once per window from the whole-window correlation sums the front end has computed (each entry
 * is such a sum less the few products of the 2L samples at either end that the rows leave out:
 * O(L²) in all), after which a sweep is one (2L+1)² product and one EUREKA application.
 * Algebraically the residual form of rtsid.ident.irf.estimate_irf's earlier sweeps; its sums
 * taken in another order move the IRF by ~1e-11 of its scale (R_uu's condition amplifies the
 * rounding). rtsid.ident.irf.estimate_irf forms the same matrices in numpy (the reference).
 */

/* The Gram matrix G = X'X (nh × nh, row-major) of the lagged rows, X[r][j] = u[r + 2L − j]
 * (r = 0 … m − 2L − 1): from auto_sums[d] = Σ_s u[s]·u[s + d] over the whole window (d = 0 …
 * 2L), each diagonal's first entry is that sum less its head, and each later entry the one
 * before it with one product added at the head end and one dropped at the tail end. */
static void lagged_gram(const double *u, Py_ssize_t m, Py_ssize_t lag, const double *auto_sums,
                        double *gram)
{
    const Py_ssize_t nh = 2 * lag + 1;
    for (Py_ssize_t d = 0; d < nh; d++) {
        double head = 0.0; /* the rows start at s = 2L − d on the diagonal's first entry */
        for (Py_ssize_t s = 0; s < 2 * lag - d; s++) head += u[s] * u[s + d];
        double g = auto_sums[d] - head;
        gram[d] = gram[d * nh] = g;
        for (Py_ssize_t i = 0; i + d + 1 < nh; i++) {
            const Py_ssize_t j = i + d; /* (i, j) → (i + 1, j + 1): the rows move one sample back */
            g += u[2 * lag - j - 1] * u[2 * lag - j - 1 + d] - u[m - 1 - j] * u[m - 1 - j + d];
            gram[(i + 1) * nh + (j + 1)] = gram[(j + 1) * nh + (i + 1)] = g;
        }
    }
}

/* X'y (nh) of the lagged rows against y[L … m−L−1]: from cross_sums[j] = Σ_s u[s]·y[s + j − L]
 * over the whole window, less the products outside the rows (s < 2L − j or s > m − 1 − j). */
static void lagged_cross(const double *u, const double *y, Py_ssize_t m, Py_ssize_t lag,
                         const double *cross_sums, double *xy)
{
    const Py_ssize_t nh = 2 * lag + 1;
    for (Py_ssize_t j = 0; j < nh; j++) {
        const Py_ssize_t k = j - lag, lo = k < 0 ? -k : 0, hi = k > 0 ? m - k : m;
        double head = 0.0, tail = 0.0;
        for (Py_ssize_t s = lo; s < 2 * lag - j; s++) head += u[s] * y[s + k];
        for (Py_ssize_t s = m - j; s < hi; s++) tail += u[s] * y[s + k];
        xy[j] = cross_sums[j] - head - tail;
    }
}

/* sweeps refinement sweeps of h (nh = 2L + 1 values, × fs) with R's EUREKA filters (rr, filters,
 * alphas from eureka_filters): each adds R⁻¹·g·fs with g = (X'y − G·h/fs)/inner − loading·h/fs.
 * work: GRAM_SWEEPS_WORK(nh) doubles. */
GLUE7_CLONES static void gram_sweeps(const double *u, const double *y, Py_ssize_t m, Py_ssize_t lag,
                        const double *auto_sums, const double *cross_sums, double loading,
                        Py_ssize_t sweeps, double fs, const double *rr, const double *filters,
                        const double *alphas, double *h, double *work)
{
    if (sweeps <= 0) return;
    const Py_ssize_t nh = 2 * lag + 1;
    const double inner = (double)(m - 2 * lag);
    double *gram = work, *xy = gram + nh * nh, *scaled = xy + nh, *g = scaled + nh, *delta = g + nh;
    lagged_gram(u, m, lag, auto_sums, gram);
    lagged_cross(u, y, m, lag, cross_sums, xy);
    for (Py_ssize_t s = 0; s < sweeps; s++) {
        for (Py_ssize_t j = 0; j < nh; j++) scaled[j] = h[j] / fs;
        for (Py_ssize_t j = 0; j < nh; j++)
            g[j] = (xy[j] - WINDOW_DOT(gram + j * nh, scaled, nh)) / inner - loading * scaled[j];
        eureka_apply(rr, filters, alphas, g, delta, nh);
        for (Py_ssize_t j = 0; j < nh; j++) h[j] += delta[j] * fs;
    }
}

/* ------------------------------------------------------------------ branch lanesums (issue 22)
 * reflex_dynamics_fit(g, lags, start, low, high, scale, tolerance, max_evaluations, x) -> cost
 *   (a negative cost: a damped system was singular): the reflex dynamics fit's projected
 *   Levenberg–Marquardt (rtsid.ident.reflex.bounded_least_squares on the residual and Jacobian
 *   of rtsid.ident.reflex._DelayedLowPass, the numpy reference) in one call: the same steps,
 *   tests and damping rule; sums in another order, so equal to rounding along the way and to
 *   the solver's tolerance at its end (tested). x (3) receives the solution. O(iterations·n).
 */
#define LM_K 3

typedef struct {
    const double *g, *lags;
    Py_ssize_t n;
    double *t, *h, *slopes; /* n, n, 3n: the low-pass at the point last evaluated */
} LowPassFit;

/* r = G·h − g at x (G solved linearly), with h and its slopes kept for the Jacobian. */
static void low_pass_residual(LowPassFit *f, const double *x, double *r)
{
    const Py_ssize_t n = f->n;
    for (Py_ssize_t i = 0; i < n; i++) f->t[i] = f->lags[i] - x[0];
    low_pass_slopes_at(f->t, n, 2 * M_PI * x[1], x[2], f->h, f->slopes);
    double energy = 0.0, hg = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        energy += f->h[i] * f->h[i];
        hg += f->h[i] * f->g[i];
    }
    const double gain = energy > 0 ? hg / energy : 0.0;
    for (Py_ssize_t i = 0; i < n; i++) r[i] = gain * f->h[i] - f->g[i];
}

/* ∂r/∂x (n × 3, row-major) at the point low_pass_residual last evaluated. */
static void low_pass_jacobian(const LowPassFit *f, double *j)
{
    const Py_ssize_t n = f->n;
    const double *h = f->h, *g = f->g;
    double energy = 0.0, hg = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        energy += h[i] * h[i];
        hg += h[i] * g[i];
    }
    if (!(energy > 0)) {
        memset(j, 0, (size_t)(n * LM_K) * sizeof(double));
        return;
    }
    const double gain = hg / energy, sign[LM_K] = {-1.0, 2 * M_PI, 1.0};
    double gain_by[LM_K];
    for (int k = 0; k < LM_K; k++) {
        const double *s = f->slopes + k * n;
        double sg = 0.0, sh = 0.0;
        for (Py_ssize_t i = 0; i < n; i++) {
            sg += s[i] * g[i];
            sh += s[i] * h[i];
        }
        gain_by[k] = sign[k] * (sg - 2.0 * gain * sh) / energy;
    }
    for (Py_ssize_t i = 0; i < n; i++)
        for (int k = 0; k < LM_K; k++)
            j[i * LM_K + k] = gain * sign[k] * f->slopes[k * n + i] + gain_by[k] * h[i];
}

static double sum_of_squares(const double *r, Py_ssize_t n)
{
    double s = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) s += r[i] * r[i];
    return s;
}

/* bounded_least_squares' loop; r, trial_r: n; j: 3n. Returns the cost, or −1 when a damped
 * system is singular (numpy.linalg.solve raises there). */
static double lm_bounded(LowPassFit *f, double *x, const double *low, const double *high,
                         const double *scale, double tol, Py_ssize_t limit, double *r,
                         double *r_trial, double *j)
{
    const Py_ssize_t n = f->n;
    double weight[LM_K];
    for (int k = 0; k < LM_K; k++) {
        x[k] = x[k] < low[k] ? low[k] : (x[k] > high[k] ? high[k] : x[k]);
        weight[k] = 1.0 / (scale[k] * scale[k]);
    }
    low_pass_residual(f, x, r);
    double cost = 0.5 * sum_of_squares(r, n), damping = -1.0, growth = 2.0;
    Py_ssize_t evaluations = 1;
    while (evaluations < limit) {
        low_pass_jacobian(f, j);
        double gradient[LM_K] = {0}, normal[LM_K * LM_K] = {0};
        for (Py_ssize_t i = 0; i < n; i++)
            for (int a = 0; a < LM_K; a++) {
                gradient[a] += j[i * LM_K + a] * r[i];
                for (int b = 0; b < LM_K; b++) normal[a * LM_K + b] += j[i * LM_K + a] * j[i * LM_K + b];
            }
        double scaled = 0.0;
        int free[LM_K], nfree = 0;
        for (int k = 0; k < LM_K; k++) {
            const double v = gradient[k] < 0 ? high[k] - x[k] : (gradient[k] > 0 ? x[k] - low[k] : 1.0);
            scaled = fmax(scaled, fabs(gradient[k] * v));
            if (!((x[k] <= low[k] && gradient[k] > 0) || (x[k] >= high[k] && gradient[k] < 0)))
                free[nfree++] = k;
        }
        if (scaled < tol) break;
        if (damping < 0) {
            double largest = -INFINITY;
            for (int k = 0; k < LM_K; k++) largest = fmax(largest, normal[k * LM_K + k] / weight[k]);
            damping = 1e-3 * largest;
        }
        int stop = 0;
        while (evaluations < limit) {
            double system[LM_K * LM_K], rhs[LM_K], step[LM_K] = {0}, trial[LM_K], moved[LM_K];
            int piv[LM_K];
            for (int a = 0; a < nfree; a++) {
                for (int b = 0; b < nfree; b++) system[a * nfree + b] = normal[free[a] * LM_K + free[b]];
                system[a * nfree + a] += damping * weight[free[a]];
                rhs[a] = -gradient[free[a]];
            }
            if (nfree > 0) {
                lu_factor(system, nfree, piv);
                for (int a = 0; a < nfree; a++)
                    if (system[a * nfree + a] == 0.0) return -1.0;
                lu_solve(system, nfree, piv, rhs);
                for (int a = 0; a < nfree; a++) step[free[a]] = rhs[a];
            }
            double predicted = 0.0, curvature = 0.0, step_norm = 0.0, size = 0.0;
            for (int k = 0; k < LM_K; k++) {
                const double v = x[k] + step[k];
                trial[k] = v < low[k] ? low[k] : (v > high[k] ? high[k] : v);
                moved[k] = trial[k] - x[k];
            }
            for (int a = 0; a < LM_K; a++) {
                predicted -= gradient[a] * moved[a];
                for (int b = 0; b < LM_K; b++) curvature += moved[a] * normal[a * LM_K + b] * moved[b];
                step_norm += moved[a] * moved[a];
                size += x[a] * x[a];
            }
            predicted -= 0.5 * curvature;
            low_pass_residual(f, trial, r_trial);
            evaluations++;
            int finite = 1;
            for (Py_ssize_t i = 0; i < n && finite; i++) finite = isfinite(r_trial[i]);
            const double cost_trial = finite ? 0.5 * sum_of_squares(r_trial, n) : INFINITY;
            const double reduction = cost - cost_trial;
            const double ratio = predicted > 0 ? reduction / predicted : 0.0;
            stop = (reduction < tol * cost && ratio > 0.25) || sqrt(step_norm) < tol * (tol + sqrt(size));
            if (reduction > 0) {
                memcpy(x, trial, sizeof(trial));
                memcpy(r, r_trial, (size_t)n * sizeof(double));
                cost = cost_trial;
                const double c = 2.0 * ratio - 1.0;
                damping *= fmax(1.0 / 3.0, 1.0 - c * c * c);
                growth = 2.0;
                break;
            }
            if (stop) break;
            damping *= growth;
            growth *= 2.0;
        }
        if (stop) break; /* else a step was taken: low_pass_residual last ran at x */
    }
    return cost;
}

static PyObject *py_reflex_dynamics_fit(PyObject *self, PyObject *args)
{
    PyObject *objs[7];
    double tol;
    Py_ssize_t limit;
    if (!PyArg_ParseTuple(args, "OOOOOOdnO", &objs[0], &objs[1], &objs[2], &objs[3], &objs[4],
                          &objs[5], &tol, &limit, &objs[6]))
        return NULL;
    const char *names[7] = {"g", "lags", "start", "low", "high", "scale", "x"};
    Py_buffer b[7];
    if (get_buffers(objs, 7, 6, names, b) < 0) return NULL;
    const Py_ssize_t n = b[0].len / 8;
    PyObject *result = NULL;
    int ok = n > 0 && b[1].len == b[0].len && limit > 0;
    for (int i = 2; i < 7; i++) ok = ok && b[i].len == LM_K * 8;
    double *work = ok ? PyMem_Malloc((size_t)(10 * n) * sizeof(double)) : NULL;
    if (!ok) {
        PyErr_SetString(PyExc_ValueError, "reflex_dynamics_fit: inconsistent sizes");
    } else if (work == NULL) {
        PyErr_NoMemory();
    } else {
        LowPassFit f = {b[0].buf, b[1].buf, n, work, work + n, work + 2 * n};
        double *x = b[6].buf;
        memcpy(x, b[2].buf, LM_K * sizeof(double));
        const double cost = lm_bounded(&f, x, b[3].buf, b[4].buf, b[5].buf, tol, limit,
                                       work + 5 * n, work + 6 * n, work + 7 * n);
        result = PyFloat_FromDouble(cost);
    }
    PyMem_Free(work);
    release_buffers(b, 7);
    return result;
}

/* ================================================================== onecall
 * onecall_window: a stream's whole window in one call, what rtsid.ident.stream.WindowStream
 * does step by step for a window without lost samples once its plan is known (the reference,
 * still run for the stream's first window, for lost samples and for every window this call
 * declines): the checks of rtsid.ident.check (finite samples, excitation: the sums as
 * window_sums), the analysis length, the front end (window_irf), the band-limited level and
 * its checks (absolute, and relative to the stream's typical level), the trend slopes, the
 * reflex torque band-limited (as band_limit), and the back end (oe_window); the caller forms
 * the estimate's flags (rtsid.ident.assess.window_flags). The same C functions
 * in the same order as the separate calls, so the numbers are theirs bit for bit.
 *
 * onecall_window(position, torque, explained, h, work, consts, state) -> status
 *   work    one float64 buffer holding a stream's arrays for one plan (glue7: one buffer to
 *           acquire a window instead of thirteen), in this order: taps, tw_cos, tw_sin, u, y,
 *           phi, extra, regressors, projected, gram, model, out, table (the plan's band_table
 *           or empty); out holds OW_SIZE values, then OC_LEVEL;
 *   consts  OC_CONSTS doubles per plan (OC_FACTOR ...), then each array's (offset, length)
 *           in work, in doubles (OC_ARRAYS pairs);
 *   state   (k, held inertia, held damping, typical level or NaN): per window.
 * status 0: done; anything else: the window is declined (a check withholds it, or a fit
 * fails): the caller runs the step-by-step path, which says why with its own error.
 */
enum {
    OC_FACTOR = 0, OC_SIGN, OC_DETREND, OC_LAG, OC_SWEEPS, OC_RIDGE, OC_FS, OC_MIN_EXCITATION,
    OC_MIN_RELATIVE, OC_UNCERTAINTY, OC_NOISE_LAGS, OC_KMAX, OC_NEWEST_ROWS, OC_CONSTS,
};
enum { OC_LEVEL = OW_SIZE, OC_OUT_SIZE };
enum { OC_ARRAYS = 13 };
enum { OC_DONE = 0, OC_DECLINED = 1 };
/* The window's checks, front end and back end; b: position, torque, explained (or NULL), h,
 * then the arrays in order. */
static int onecall(const double *pos, const double *trq, const double *explained, Py_ssize_t n,
                   double *h, Py_ssize_t nh, Py_buffer *a, const double *c, const double *state,
                   double *work)
{
    const double *taps = a[0].buf, *tw_cos = a[1].buf, *tw_sin = a[2].buf;
    double *u = a[3].buf, *y = a[4].buf, *phi = a[5].buf, *extra = a[6].buf;
    double *out = a[11].buf;
    const Py_ssize_t nt = a[0].len / 8, factor = (Py_ssize_t)c[OC_FACTOR];
    const Py_ssize_t lag = (Py_ssize_t)c[OC_LAG];
    const double sign = c[OC_SIGN], min_excitation = c[OC_MIN_EXCITATION];
    /* 1. check (rtsid.ident.check.check_window: the window_sums loop) */
    double sp = 0.0, st = 0.0, spp = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        sp += pos[i];
        st += trq[i];
        spp += pos[i] * pos[i];
    }
    if (!(isfinite(sp) && isfinite(st))) return OC_DECLINED;
    const double mean = sp / (double)n, spread = spp / (double)n - mean * mean;
    if (sqrt(spread > 0.0 ? spread : 0.0) < min_excitation) return OC_DECLINED;
    /* 3. front end (rtsid.ident.front._front_end) */
    const Py_ssize_t m = n >= nt ? (n - nt) / factor + 1 : 0;
    if (m <= (4 * lag + 1 > 16 ? 4 * lag + 1 : 16) || m != a[3].len / 8) return OC_DECLINED;
    double alpha = 0.0;
    const int kind = (int)c[OC_DETREND];
    double slopes[2] = {0.0, 0.0}; /* line_slope's, from the detrending's own pass */
    if (window_irf_sloped(pos, trq, n, taps, nt, factor, sign, kind, lag, c[OC_RIDGE],
                          (Py_ssize_t)c[OC_SWEEPS], c[OC_FS], u, y, m, h, phi, work, &alpha,
                          kind == 2 ? slopes : NULL) >= 0) {
        return OC_DECLINED;
    }
    const double level = standard_deviation(u, m);
    if (level < min_excitation) return OC_DECLINED;
    /* the stream's relative check (check_relative_excitation; NaN: no typical level yet) */
    const double typical = state[3];
    if (!isnan(typical) && level < c[OC_MIN_RELATIVE] * typical) return OC_DECLINED;
    /* scored band (front.scored_band): the trends at the analysis rate, the reflex torque */
    double position_slope = 0.0, torque_slope = 0.0;
    if (kind == 2) {
        position_slope = slopes[0] * (double)factor;
        torque_slope = slopes[1] * (double)factor;
    }
    if (explained != NULL) {
        detrend_into(explained, work, n, sign, 1);
        fir_decimate(work, n, taps, nt, factor, extra, m);
    }
    /* 4-5. back end (oe_window) */
    const double held[2] = {state[1], state[2]};
    const double *table = a[12].len > 0 ? a[12].buf : NULL;
    if (oe_window_tabled(u, y, m, h, lag, c[OC_FS], (int)state[0], held, 1,
                         (int)c[OC_UNCERTAINTY], (Py_ssize_t)c[OC_NOISE_LAGS],
                         explained != NULL ? extra : NULL, torque_slope, position_slope,
                         (Py_ssize_t)c[OC_KMAX], tw_cos, tw_sin, table,
                         (Py_ssize_t)c[OC_NEWEST_ROWS], a[7].buf, a[8].buf, a[9].buf, a[10].buf,
                         out, work) != OE_OK) {
        return OC_DECLINED;
    }
    out[OC_LEVEL] = level;
    (void)nh;
    return OC_DONE;
}

static PyObject *py_onecall_window(PyObject *self, PyObject *args)
{
    PyObject *objs[6], *explained;
    if (!PyArg_ParseTuple(args, "OOOOOOO", &objs[0], &objs[1], &explained, &objs[2], &objs[5],
                          &objs[3], &objs[4])) {
        return NULL;
    }
    static const char *names[6] = {"position", "torque", "h", "consts", "state", "work"};
    Py_buffer b[7], a[OC_ARRAYS];
    if (get_buffers(objs, 6, 2, names, b) < 0) return NULL;
    int has_explained = explained != Py_None, got = 6;
    if (has_explained && get_doubles(explained, &b[got++], 0, "explained") < 0) {
        release_buffers(b, 6);
        return NULL;
    }
    /* the arrays as views of work (glue7): only .buf and .len are read below */
    const double *layout = (const double *)b[3].buf + OC_CONSTS;
    const Py_ssize_t work_len = b[5].len / 8;
    int laid_out = b[3].len / 8 == OC_CONSTS + 2 * OC_ARRAYS;
    for (int i = 0; laid_out && i < OC_ARRAYS; i++) {
        const double at = layout[2 * i], len = layout[2 * i + 1];
        laid_out = at >= 0.0 && len >= 0.0 && at == floor(at) && len == floor(len) &&
                   at + len <= (double)work_len;
        if (laid_out) {
            a[i].buf = (double *)b[5].buf + (Py_ssize_t)at;
            a[i].len = (Py_ssize_t)len * 8;
        }
    }
    if (!laid_out) {
        PyErr_SetString(PyExc_ValueError, "onecall_window: consts must end with the arrays' "
                                          "(offset, length) pairs within work");
        release_buffers(b, got);
        return NULL;
    }
    PyObject *result = NULL;
    const Py_ssize_t n = b[0].len / 8, nh = b[2].len / 8, m = a[3].len / 8, nn = m - 8;
    const double *c = b[3].buf;
    if (b[4].len / 8 < 4 || a[11].len / 8 != OC_OUT_SIZE) {
        PyErr_SetString(PyExc_ValueError, "onecall_window: inconsistent sizes");
    } else if (b[0].ndim != 1 || b[1].ndim != 1 || b[1].len != b[0].len ||
               (has_explained && b[6].len != b[0].len) || c[OC_FACTOR] < 1 || c[OC_LAG] < 1 ||
               nh != 2 * (Py_ssize_t)c[OC_LAG] + 1 || a[0].len / 8 < 1 || n < 16 ||
               n < a[0].len / 8 || a[4].len != a[3].len || a[5].len / 8 != nh ||
               a[6].len != a[3].len || nn < 2 || a[1].len / 8 != nn || a[2].len / 8 != nn ||
               c[OC_KMAX] < 0 || c[OC_KMAX] > nn / 2 || a[7].len / 8 != 3 * nn ||
               a[8].len / 8 != 4 * nn || a[9].len / 8 != 16 || a[10].len / 8 != nn ||
               (a[12].len > 0 && a[12].len / 8 != ((Py_ssize_t)c[OC_KMAX] + 3) / 4 * nn * 8)) {
        result = PyLong_FromLong(OC_DECLINED); /* not a window this call fits: the reference */
    } else {
        const Py_ssize_t lag = (nh - 1) / 2, edge = lag > 4 ? lag : 4, inner = m - 2 * edge;
        const Py_ssize_t lags = (Py_ssize_t)c[OC_NOISE_LAGS];
        const Py_ssize_t nl = lags < 1 ? 1 : (lags > nn - 1 ? nn - 1 : lags);
        Py_ssize_t size = WINDOW_IRF_WORK(n, nh), back = 3 * inner + 2 * nn + nl + 2;
        if (size < back) size = back;
        double *work = inner < 2 ? NULL : PyMem_Malloc(sizeof(double) * size);
        if (inner < 2) {
            result = PyLong_FromLong(OC_DECLINED);
        } else if (work == NULL) {
            PyErr_NoMemory();
        } else {
            int status = onecall(b[0].buf, b[1].buf, has_explained ? b[6].buf : NULL, n,
                                 b[2].buf, nh, a, c, b[4].buf, work);
            PyMem_Free(work);
            result = PyLong_FromLong(status);
        }
    }
    release_buffers(b, got);
    return result;
}

/* The tracker's calm step: rtsid.ident.tracker.ParameterTracker.step for a calm window, the one
 * most windows are (the tracker started, no change mode, the interval one the filters' cached
 * transitions know, no significant split in the window's scan, the window within change_gate;
 * or a window without a usable estimate: the prediction only). Its entry point is tracker_step
 * (section stream8, which replaced this section's tracker_calm); below, the names it reads and
 * writes and its arithmetic, the same operations in the same order as the Python step. */
enum { TC_X0, TC_X1, TC_P00, TC_P01, TC_P11, TC_LAG, TC_OVERLAP, TC_RATE_Q, TC_TAU, TC_FIELDS };
static const char *const TC_FILTER_NAMES[TC_FIELDS] = {"x0", "x1", "p00", "p01", "p11",
                                                         "lag", "overlap", "rate_q", "tau"};
enum {
    TS_T, TS_HOP, TS_ALPHA, TS_SCALE2, TS_SE_REF, TS_CUSUM, TS_FORGET, TS_THRESHOLD, TS_GATE,
    TS_OVERLAP, TS_FAST_CUSUM, TS_FAST_SCALE2, TS_SPLIT_GATE, TS_DOUBLES,
};
static const char *const TS_DOUBLE_NAMES[TS_DOUBLES] = {
    "t_s", "hop_s", "alpha", "scale2", "se_ref", "cusum", "forget", "switch_threshold", "gate",
    "overlap", "fast_cusum", "fast_scale2", "split_gate"};
enum { TI_CHANGE, TI_CALM_AFTER, TI_UPDATES, TI_FAST_SCORED, TI_FAST_HOPS, TI_END_HOPS, TI_INTS };
static const char *const TS_INT_NAMES[TI_INTS] = {"change_hops", "calm_after", "updates",
                                                   "fast_scored", "_fast_hops", "end_hops"};
/* the tracker's constants of rtsid.ident.tracker */
static const double TC_SCALE_CAP = 9.0, TC_PREGATE = 2.0, TC_SE_SWELL = 1.25;
static const double TC_FAST_LLR_CAP = 2.0, TC_FAST_DF = 4.0;
static const long TC_FAST_CONFIRM_HOPS = 2, TC_FAST_WARM_UP = 2;

/* The attribute names, interned once (a read by a C string would make and hash a new string
 * each time). */
enum {
    TN_SPLITTING, TN_TRENDING, TN_ALL, TN_LAST, TN_BY_DT, TN_HOP_RECENT, TN_RECENT, TN_HISTORY,
    TN_FAST_ON, TN_CANDIDATE, TN_OUTLIER, TN_K, TN_VAR, TN_CENTRE, TN_Z_RATIO, TN_BEST,
    TN_APPEND, TN_COUNT,
};
static const char *const TN_NAMES[TN_COUNT] = {
    "splitting", "trending", "_all", "_last", "_by_dt", "_hop_recent", "_recent", "_history",
    "fast_on", "_candidate", "_outlier", "k", "var", "centre_s", "z_ratio", "best", "append"};
static PyObject *tn[TN_COUNT], *tn_filter[TC_FIELDS], *tn_double[TS_DOUBLES], *tn_int[TI_INTS];

static int tc_intern(PyObject **out, const char *const *names, int count)
{
    for (int i = 0; i < count; i++) {
        if (out[i] == NULL && (out[i] = PyUnicode_InternFromString(names[i])) == NULL) return -1;
    }
    return 0;
}

static int tc_names(void)
{
    if (tn[TN_COUNT - 1] != NULL && tn_int[TI_INTS - 1] != NULL) return 0;
    if (tc_intern(tn_filter, TC_FILTER_NAMES, TC_FIELDS) < 0 ||
        tc_intern(tn_double, TS_DOUBLE_NAMES, TS_DOUBLES) < 0 ||
        tc_intern(tn_int, TS_INT_NAMES, TI_INTS) < 0 || tc_intern(tn, TN_NAMES, TN_COUNT) < 0) {
        return -1;
    }
    return 0;
}

/* _LevelRateFilter.predict(dt) with its transition (b, a, q00, q01, q11) */
static void tc_predict(double *x, const double *s)
{
    const double b = s[0], a = s[1], p00 = x[TC_P00], p01 = x[TC_P01], p11 = x[TC_P11];
    x[TC_X0] += b * x[TC_X1];
    x[TC_X1] *= a;
    x[TC_P00] = p00 + 2.0 * b * p01 + b * b * p11 + s[2];
    x[TC_P01] = a * (p01 + b * p11) + s[3];
    x[TC_P11] = a * a * p11 + s[4];
}

/* _LevelRateFilter.update(z, sigma2): the innovation and H·P·Hᵀ */
static void tc_update(double *x, double z, double sigma2, double *nu_out, double *hph_out)
{
    const double c = x[TC_LAG];
    const double ph0 = x[TC_P00] - c * x[TC_P01];
    const double ph1 = x[TC_P01] - c * x[TC_P11];
    const double hph = ph0 - c * ph1;
    const double nu = z - (x[TC_X0] - c * x[TC_X1]);
    const double s = hph + x[TC_OVERLAP] * sigma2;
    const double g0 = ph0 / s, g1 = ph1 / s;
    x[TC_X0] += g0 * nu;
    x[TC_X1] += g1 * nu;
    x[TC_P00] -= g0 * ph0;
    x[TC_P01] -= g0 * ph1;
    x[TC_P11] -= g1 * ph1;
    *nu_out = nu;
    *hph_out = hph;
}

static double tc_max(double a, double b) { return b > a ? b : a; } /* Python's max(a, b) */
static double tc_min(double a, double b) { return b < a ? b : a; } /* Python's min(a, b) */

/* (t, a, b) triples of a recent-values tuple: its count (0-2), -1 when malformed */
static int tc_recent(PyObject *recent, double (*out)[3])
{
    if (!PyTuple_Check(recent) || PyTuple_GET_SIZE(recent) > 2) return -1;
    int count = (int)PyTuple_GET_SIZE(recent);
    for (int i = 0; i < count; i++) {
        PyObject *item = PyTuple_GET_ITEM(recent, i);
        if (!PyTuple_Check(item) || PyTuple_GET_SIZE(item) != 3) return -1;
        for (int j = 0; j < 3; j++) out[i][j] = PyFloat_AsDouble(PyTuple_GET_ITEM(item, j));
    }
    return PyErr_Occurred() ? -1 : count;
}

/* (*recent[-1:], (t, a, b)) */
static PyObject *tc_pushed(PyObject *recent, int count, double t, double a, double b)
{
    PyObject *item = Py_BuildValue("(ddd)", t, a, b);
    if (item == NULL) return NULL;
    if (count == 0) return Py_BuildValue("(N)", item);
    PyObject *out = PyTuple_Pack(2, PyTuple_GET_ITEM(recent, count - 1), item);
    Py_DECREF(item);
    return out;
}

static PyObject *empty_tuple(void)
{
    static PyObject *empty = NULL;
    if (empty == NULL) empty = PyTuple_New(0);
    return empty;
}

/* The window's split scan (split(): a SplitScan or None) has no split beyond split_gate
 * calm standard errors (ref), as ParameterTracker._split_update reads it outside a change
 * mode: 1 none (the window stays calm), 0 one (the Python step reads it), -1 an error. */
static int tc_no_split(PyObject *split, double ref, double split_gate)
{
    PyObject *scan = PyObject_CallNoArgs(split);
    if (scan == NULL) return -1;
    if (scan == Py_None) {
        Py_DECREF(scan);
        return 1;
    }
    int quiet = -1;
    PyObject *row = PyObject_CallMethodNoArgs(scan, tn[TN_BEST]);
    if (row == Py_None) {
        quiet = 1;
    } else if (row != NULL) {
        PyObject *ratios = PyObject_GetAttr(scan, tn[TN_Z_RATIO]);
        PyObject *ratio = ratios != NULL ? PyObject_GetItem(ratios, row) : NULL;
        double z = ratio != NULL ? PyFloat_AsDouble(ratio) : -1.0;
        if (ratio != NULL && !(z == -1.0 && PyErr_Occurred())) quiet = fabs(z) <= split_gate * ref;
        Py_XDECREF(ratio);
        Py_XDECREF(ratios);
    }
    Py_XDECREF(row);
    Py_DECREF(scan);
    return quiet;
}

/* ================================================================== kern625 (issue 22)
 * The window's kernels at the 625 Hz plan (±12 lags, M ≈ 178 analysis samples), where a window's
 * cost was fixed per-call work rather than O(M·L) sums: the FIR decimation of both signals
 * (≈ 2·M·T products, T = 39 taps, computed one output at a time), three passes of detrending
 * with the trend slopes then formed again from the raw samples, and the back end's stencils and
 * model torque formed a second time for the VAFs. Each function gives the numbers of the loop it
 * replaces bit for bit (same products, each sum in the same order).
 */

/* Σ_i (i − (n − 1)/2)² over i = 0 … n − 1, as the loop in sample order sums it: for n < 2^17
 * each term and each partial sum is a multiple of 1/4 below 2^51, so that loop is exact and
 * equals n(n² − 1)/12, itself formed exactly here (n(n² − 1) < 2^53, the quotient a multiple of
 * 1/4). Longer windows sum the loop. */
static double centred_squares(Py_ssize_t n)
{
    if (n < ((Py_ssize_t)1 << 17)) {
        const double nn = (double)n;
        return nn * (nn * nn - 1.0) / 12.0;
    }
    const double centre = (double)(n - 1) / 2.0;
    double tt = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        const double t = (double)i - centre;
        tt += t * t;
    }
    return tt;
}

/* detrend_into's result (n samples of sign·x less its mean, and less its line when kind == 2)
 * in two passes instead of three: the mean's sum and the slope's (independent accumulators, each
 * in sample order, as detrend_into's separate loops) share one pass. The samples are written in
 * phases of `factor` for fir_phases: phase p (samples p, p + factor, …) from out + phase_start(p)
 * (factor 1: in order). Returns the slope of sign·x per sample (line_slope's value) when
 * kind == 2 or want_slope, else 0. */
static double detrend_phases(const double *x, double *out, Py_ssize_t n, double sign, int kind,
                             int want_slope, Py_ssize_t factor)
{
    const double centre = (double)(n - 1) / 2.0;
    double mean = 0.0, tt = 0.0, tx = 0.0, slope = 0.0;
    if (kind == 2 || want_slope) {
        tt = centred_squares(n);
        double t = -centre; /* (double)i − centre, exactly: steps of 1 between half-integers */
        if (sign == 1.0) { /* sign·x[i] is x[i], (t·sign)·x[i] is t·x[i] */
            for (Py_ssize_t i = 0; i < n; i++, t += 1.0) {
                mean += x[i];
                tx += t * x[i];
            }
        } else if (sign == -1.0) { /* a + (−b) is a − b, and (−t)·x is −(t·x), bit for bit */
            for (Py_ssize_t i = 0; i < n; i++, t += 1.0) {
                mean -= x[i];
                tx -= t * x[i];
            }
        } else {
            for (Py_ssize_t i = 0; i < n; i++, t += 1.0) {
                mean += sign * x[i];
                tx += t * sign * x[i];
            }
        }
        slope = tt > 0.0 ? tx / tt : 0.0;
    } else {
        for (Py_ssize_t i = 0; i < n; i++) mean += sign * x[i];
    }
    mean /= (double)n;
    const double off = kind >= 1 ? mean : 0.0, line = kind == 2 ? slope : 0.0;
    for (Py_ssize_t p = 0; p < factor && p < n; p++) {
        double *phase = out + phase_start(p, n, factor);
        if (kind == 2) {
            phase_minus_line(x, p, n, factor, sign, off, line, (double)p - centre, phase);
        } else if (kind == 1) {
            for (Py_ssize_t i = p; i < n; i += factor) *phase++ = sign * x[i] - off;
        } else {
            for (Py_ssize_t i = p; i < n; i += factor) *phase++ = sign * x[i];
        }
    }
    return slope;
}

static double detrend_sloped(const double *x, double *out, Py_ssize_t n, double sign, int kind,
                             int want_slope)
{
    return detrend_phases(x, out, n, sign, kind, want_slope, 1);
}

/* fir_decimate's outputs from the samples in phases (detrend_phases): out[k] = Σ_j taps[j]·
 * x[k·factor + nt − 1 − j], j ascending. Sample k·factor + d is phase d mod factor's item
 * k + d div factor, so for each tap the outputs k, k + 1, … read consecutive values: 16 outputs
 * at a time in pairs of lanes, each lane's sum the one-output loop's, product by product. */
static void fir_phases(const double *phases, Py_ssize_t n, const double *taps, Py_ssize_t nt,
                       Py_ssize_t factor, double *out, Py_ssize_t m)
{
    Py_ssize_t stack[128];
    Py_ssize_t *at = nt <= 128 ? stack : PyMem_RawMalloc(sizeof(Py_ssize_t) * (size_t)nt);
    if (at == NULL) { /* no memory for the table: each sample's place found as it is read */
        for (Py_ssize_t k = 0; k < m; k++) {
            double acc = 0.0;
            for (Py_ssize_t j = 0; j < nt; j++) {
                const Py_ssize_t i = k * factor + nt - 1 - j;
                acc += taps[j] * phases[phase_start(i % factor, n, factor) + i / factor];
            }
            out[k] = acc;
        }
        return;
    }
    for (Py_ssize_t j = 0; j < nt; j++) { /* where output 0's sample for tap j lies */
        const Py_ssize_t d = nt - 1 - j;
        at[j] = phase_start(d % factor, n, factor) + d / factor;
    }
    Py_ssize_t k = 0;
#ifdef G7_QUADS
    k = g7_fir_rows(phases, at, taps, nt, m, out); /* four lanes wide (glue7), then the rest */
#endif
#ifdef LANE_PAIRS
    for (; k + 2 * BLOCK <= m; k += 2 * BLOCK) {
        lane_pair a[8] = {{0.0, 0.0}};
        for (int b = 1; b < 8; b++) a[b] = a[0];
        for (Py_ssize_t j = 0; j < nt; j++) {
            const lane_pair tj = pair_of(taps[j]);
            const double *s = phases + at[j] + k;
            for (int b = 0; b < 8; b++) a[b] += tj * pair_at(s + 2 * b);
        }
        memcpy(out + k, a, sizeof a);
    }
#endif
    for (; k < m; k++) {
        double acc = 0.0;
        for (Py_ssize_t j = 0; j < nt; j++) acc += taps[j] * phases[at[j] + k];
        out[k] = acc;
    }
    if (at != stack) PyMem_RawFree(at);
}

/* fir_decimate's outputs out[k] = Σ_j taps[j]·x[k·factor + nt − 1 − j] (j ascending), BLOCK
 * outputs at a time in pairs of lanes: a lane's sum is the one-output loop's, product by product.
 * The pairs' samples lie factor apart (two loads each) unless factor is 1. Returns the first
 * output left for the scalar loop (m when none). */
static Py_ssize_t fir_decimate_lanes(const double *x, const double *taps, Py_ssize_t nt,
                                     Py_ssize_t factor, double *out, Py_ssize_t m)
{
    Py_ssize_t k = 0;
#ifdef LANE_PAIRS
    const Py_ssize_t f = factor;
    for (; k + BLOCK <= m; k += BLOCK) {
        const double *seg = x + k * f + nt - 1; /* output k's newest sample */
        lane_pair a0 = pair_of(0.0), a1 = a0, a2 = a0, a3 = a0;
        if (f == 1) {
            for (Py_ssize_t j = 0; j < nt; j++) {
                const lane_pair tj = pair_of(taps[j]);
                const double *s = seg - j;
                a0 += tj * pair_at(s);
                a1 += tj * pair_at(s + 2);
                a2 += tj * pair_at(s + 4);
                a3 += tj * pair_at(s + 6);
            }
        } else {
            for (Py_ssize_t j = 0; j < nt; j++) {
                const lane_pair tj = pair_of(taps[j]);
                const double *s = seg - j;
                const lane_pair x0 = {s[0], s[f]}, x1 = {s[2 * f], s[3 * f]},
                                x2 = {s[4 * f], s[5 * f]}, x3 = {s[6 * f], s[7 * f]};
                a0 += tj * x0;
                a1 += tj * x1;
                a2 += tj * x2;
                a3 += tj * x3;
            }
        }
        memcpy(out + k, &a0, 16);
        memcpy(out + k + 2, &a1, 16);
        memcpy(out + k + 4, &a2, 16);
        memcpy(out + k + 6, &a3, 16);
    }
#else
    (void)x, (void)taps, (void)nt, (void)factor, (void)out, (void)m;
#endif
    return k;
}

/* oe_window's VAFs as predictions() + three_vafs() give them, without forming the model's
 * torque again: predictions' model torque at sample t (edge ≤ t < m − edge) is
 * params[0]·(d2·fs²) + params[1]·(d1·fs) + params[2]·u[t] with the same 9-point stencil sums as
 * oe_design's regressor rows, so it is model[t − 4] of the published oe_fit bit for bit; only the
 * IRF's prediction (into by_irf, m − 2·edge values) is formed here. */
static void irf_model_vafs(const double *u, const double *y, Py_ssize_t m, const double *h,
                           Py_ssize_t lag, double fs, const double *model, Py_ssize_t edge,
                           double *by_irf, double *vafs)
{
    const Py_ssize_t inner = m - 2 * edge;
    lagged_predict(h, u, 2 * lag + 1, lag, edge, m - edge, by_irf - edge);
    for (Py_ssize_t i = 0; i < inner; i++) by_irf[i] = by_irf[i] / fs;
    three_vafs(y + edge, by_irf, model + (edge - 4), inner, vafs);
}

/* window_irf with the trends' slopes (line_slope's values of the position and the signed
 * torque, from the detrending's own pass) into slopes[0], slopes[1] unless slopes is NULL. */
static Py_ssize_t window_irf_sloped(const double *pos, const double *trq, Py_ssize_t n,
                                    const double *taps, Py_ssize_t nt, Py_ssize_t factor,
                                    double sign, int kind, Py_ssize_t lag, double ridge,
                                    Py_ssize_t sweeps, double fs, double *u, double *y,
                                    Py_ssize_t m, double *h, double *phi, double *work,
                                    double *alpha, double *slopes)
{
    const Py_ssize_t nh = 2 * lag + 1;
    double *dp = work, *dt = work + n;              /* detrended, n each */
    double *rr = dt + n;                            /* R reversed, nh */
    double *sums = rr + nh;                         /* whole-window sums: auto, then cross */
    double *filters = sums + 2 * nh, *alphas = filters + nh * (nh + 1) / 2; /* EUREKA's, kept */
    double *rest = filters + FILTERS_SIZE(nh);      /* the sweeps' scratch */
    const int want = slopes != NULL;
    const double position_slope = detrend_phases(pos, dp, n, 1.0, kind, want, factor);
    const double torque_slope = detrend_phases(trq, dt, n, sign, kind, want, factor);
    if (slopes != NULL) {
        slopes[0] = position_slope;
        slopes[1] = torque_slope;
    }
    fir_phases(dp, n, taps, nt, factor, u, m);
    fir_phases(dt, n, taps, nt, factor, y, m);
    /* the sums themselves are kept for the sweeps' Gram matrix; sums / m is what
     * xcorr_blocked(..., m, ...) gives, bit for bit */
    xcorr_lanes(u, u, m, 0, nh - 1, 1.0, sums); /* xcorr_blocked's sums, sixteen lags at a time */
    for (Py_ssize_t k = 0; k < nh; k++) phi[k] = sums[k] / (double)m;
    const double loading = ridge * phi[0];
    phi[0] += loading;
    /* phi_uy(k) = sum_t u(t-k) y(t) / m  =  sum_s u(s) y(s+k) / m */
    double *g = rest; /* the first solve's right-hand side, before the sweeps use rest */
    xcorr_lanes(u, y, m, -lag, lag, 1.0, sums + nh);
    for (Py_ssize_t k = 0; k < nh; k++) g[k] = sums[nh + k] / (double)m;
    /* the four solves share R: its prediction-error filters are formed once */
    Py_ssize_t status = eureka_filters(phi, rr, filters, alphas, nh, alpha);
    if (status >= 0) return status;
    eureka_apply(rr, filters, alphas, g, h, nh);
    for (Py_ssize_t k = 0; k < nh; k++) h[k] *= fs;
    gram_sweeps(u, y, m, lag, sums, sums + nh, loading, sweeps, fs, rr, filters, alphas, h, rest);
    return -1;
}

/* The plan's band table (BAND_TABLE_SIZE(n, kmax) doubles) from tw_cos, tw_sin (cos, sin of
 * 2πj/n): group g, sample t holds cos and sin of bins 4g + 1 … 4g + 4 at t, the twiddles
 * band_powers reads (index b·t mod n), 0 past kmax. */
static void band_table_fill(const double *tw_cos, const double *tw_sin, Py_ssize_t n,
                            Py_ssize_t kmax, double *table)
{
    for (Py_ssize_t g = 0; g < (kmax + 3) / 4; g++) {
        for (int b = 0; b < 4; b++) {
            const Py_ssize_t bin = 4 * g + 1 + b;
            double *at = table + g * n * 8 + b;
            Py_ssize_t idx = 0;
            for (Py_ssize_t t = 0; t < n; t++, at += 8) {
                at[0] = bin <= kmax ? tw_cos[idx] : 0.0;
                at[4] = bin <= kmax ? tw_sin[idx] : 0.0;
                idx += bin;
                if (idx >= n) idx %= n;
            }
        }
    }
}

/* band_powers' sums from the band table: per group of 4 bins the measured spectrum's real and
 * imaginary parts in two pairs of lanes each (a lane per bin), the residual's likewise; over t in
 * order with band_powers' products, so each bin's sums are its; the powers are added to total
 * and left in bin order. Returns kmax + 1 (no bin left). */
static Py_ssize_t band_powers_table(const double *meas, const double *err, Py_ssize_t n,
                                    Py_ssize_t kmax, const double *table, double *total,
                                    double *left)
{
#ifdef G7_QUADS
    g7_band_powers(meas, err, n, kmax, table, total, left); /* the bins in four lanes (glue7) */
    return kmax + 1;
#endif
    for (Py_ssize_t g = 0; g < (kmax + 3) / 4; g++) {
        const double *at = table + g * n * 8;
#ifdef LANE_PAIRS
        lane_pair mr0 = pair_of(0.0), mr1 = mr0, mi0 = mr0, mi1 = mr0, er0 = mr0, er1 = mr0,
                  ei0 = mr0, ei1 = mr0;
        for (Py_ssize_t t = 0; t < n; t++, at += 8) {
            const lane_pair m = pair_of(meas[t]), e = pair_of(err[t]);
            const lane_pair c0 = pair_at(at), c1 = pair_at(at + 2), s0 = pair_at(at + 4),
                            s1 = pair_at(at + 6);
            mr0 += m * c0;
            mr1 += m * c1;
            mi0 -= m * s0;
            mi1 -= m * s1;
            er0 += e * c0;
            er1 += e * c1;
            ei0 -= e * s0;
            ei1 -= e * s1;
        }
        double mr[4], mi[4], er[4], ei[4];
        memcpy(mr, &mr0, 16), memcpy(mr + 2, &mr1, 16), memcpy(mi, &mi0, 16);
        memcpy(mi + 2, &mi1, 16), memcpy(er, &er0, 16), memcpy(er + 2, &er1, 16);
        memcpy(ei, &ei0, 16), memcpy(ei + 2, &ei1, 16);
#else
        double mr[4] = {0.0}, mi[4] = {0.0}, er[4] = {0.0}, ei[4] = {0.0};
        for (Py_ssize_t t = 0; t < n; t++, at += 8) {
            for (int b = 0; b < 4; b++) {
                mr[b] += meas[t] * at[b];
                mi[b] -= meas[t] * at[4 + b];
                er[b] += err[t] * at[b];
                ei[b] -= err[t] * at[4 + b];
            }
        }
#endif
        for (int b = 0; b < 4 && 4 * g + 1 + b <= kmax; b++) {
            *total += mr[b] * mr[b] + mi[b] * mi[b];
            *left += er[b] * er[b] + ei[b] * ei[b];
        }
    }
    return kmax + 1;
}

static PyObject *py_band_table(PyObject *self, PyObject *args)
{
    PyObject *objs[3];
    Py_ssize_t kmax;
    if (!PyArg_ParseTuple(args, "OOnO", &objs[0], &objs[1], &kmax, &objs[2])) return NULL;
    const char *names[3] = {"tw_cos", "tw_sin", "table"};
    Py_buffer b[3];
    if (get_buffers(objs, 3, 2, names, b) < 0) return NULL;
    const Py_ssize_t n = b[0].len / 8;
    PyObject *result = NULL;
    if (b[1].len != b[0].len || kmax < 0 || kmax > n / 2 ||
        b[2].len / 8 != BAND_TABLE_SIZE(n, kmax)) {
        PyErr_SetString(PyExc_ValueError, "band_table: inconsistent sizes");
    } else {
        band_table_fill(b[0].buf, b[1].buf, n, kmax, b[2].buf);
        Py_INCREF(Py_None);
        result = Py_None;
    }
    release_buffers(b, 3);
    return result;
}

static PyObject *py_oe_window_tabled(PyObject *self, PyObject *args)
{
    return oe_window_entry(args, 1);
}

/* ------------------------------------------------------------------ branch lanesums2 (issue 22)
 * causal_convolve(r, g, scale, out): out[t] = sum_{k=0}^{min(t, m-1)} (g[k] / scale) * r[t-k]
 *   for t < n (r of n samples, g of m taps): rtsid.ident.reflex.convolve_causal, the first n
 *   samples of numpy.convolve(r, g / scale). numpy sums each output by BLAS dots in blocks;
 *   here each output is summed over k in increasing order (no fused multiply-add), so the two
 *   agree to rounding (tested to 1e-12 of the largest output). The loop over t inside the loop
 *   over k vectorises; no output beyond n is formed (numpy forms m - 1 more). O(n·m).
 */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__ELF__)
__attribute__((target_clones("avx2", "default")))
#endif
static void causal_convolve_run(const double *r, Py_ssize_t n, const double *g, Py_ssize_t m,
                                double scale, double *out)
{
    for (Py_ssize_t t = 0; t < n; t++) out[t] = 0.0;
    for (Py_ssize_t k = 0; k < m && k < n; k++) {
        const double tap = g[k] / scale;
        const double *src = r - k;
        for (Py_ssize_t t = k; t < n; t++) out[t] += tap * src[t];
    }
}

static PyObject *py_causal_convolve(PyObject *self, PyObject *args)
{
    PyObject *objs[3];
    double scale;
    if (!PyArg_ParseTuple(args, "OOdO", &objs[0], &objs[1], &scale, &objs[2])) return NULL;
    const char *names[3] = {"r", "g", "out"};
    Py_buffer b[3];
    if (get_buffers(objs, 3, 2, names, b) < 0) return NULL;
    const Py_ssize_t n = b[0].len / 8, m = b[1].len / 8;
    PyObject *result = NULL;
    if (b[2].len != b[0].len || m < 1) {
        PyErr_SetString(PyExc_ValueError, "causal_convolve: out must have r's size, g a tap");
    } else {
        causal_convolve_run(b[0].buf, n, b[1].buf, m, scale, b[2].buf);
        result = Py_None;
        Py_INCREF(result);
    }
    release_buffers(b, 3);
    return result;
}

/* ------------------------------------------------------------------ branch fits4 (issue 22)
 * The slow lane's fits, sixth pass: the same numbers bit for bit, fewer instructions.
 *
 * xcorr_lags(u, y, first, last, norm, c): xcorr's c[k − first] = Σ_t u[t]·y[t + k] / norm,
 *   sixteen lags at a time in four four-double vectors (the last few by xcorr_blocked), each
 *   lag's sum over t ascending: xcorr bit for bit. rtsid.ident.correlation's direct sums (the reflex IRF's 101-lag
 *   autocorrelation and right-hand side, the cascade's intrinsic IRF); O(n·lags).
 */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__ELF__)
#define FITS4_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define FITS4_CLONES
#endif
typedef double xcorr_lanes_t __attribute__((vector_size(32), aligned(8))); /* unaligned loads */
#define XCORR_BLOCK 16 /* lags per block: four vectors of four */

/* xcorr's sums XCORR_BLOCK lags at a time (the rest by xcorr_blocked): each lag's own first
 * samples, the block's common span with the lags in the lanes, then its own last ones — every
 * lag's sum over t ascending, as xcorr's. */
FITS4_CLONES static void xcorr_lanes(const double *u, const double *y, Py_ssize_t n,
                                     Py_ssize_t first, Py_ssize_t last, double norm, double *c)
{
    Py_ssize_t k0 = first;
    for (; k0 + XCORR_BLOCK - 1 <= last; k0 += XCORR_BLOCK) {
        double acc[XCORR_BLOCK] = {0.0};
        Py_ssize_t lo[XCORR_BLOCK], hi[XCORR_BLOCK], common_lo = 0, common_hi = n;
        for (int b = 0; b < XCORR_BLOCK; b++) {
            const Py_ssize_t k = k0 + b;
            lo[b] = k < 0 ? -k : 0;
            hi[b] = k > 0 ? n - k : n;
            if (lo[b] > common_lo) common_lo = lo[b];
            if (hi[b] < common_hi) common_hi = hi[b];
        }
        if (common_hi < common_lo) common_hi = common_lo;
        for (int b = 0; b < XCORR_BLOCK; b++)
            for (Py_ssize_t t = lo[b]; t < common_lo && t < hi[b]; t++)
                acc[b] += u[t] * y[t + k0 + b];
        xcorr_lanes_t a[4];
        memcpy(a, acc, sizeof a);
        for (Py_ssize_t t = common_lo; t < common_hi; t++) {
            const xcorr_lanes_t ut = (xcorr_lanes_t){0.0, 0.0, 0.0, 0.0} + u[t];
            const double *src = y + t + k0;
            a[0] += ut * *(const xcorr_lanes_t *)src;
            a[1] += ut * *(const xcorr_lanes_t *)(src + 4);
            a[2] += ut * *(const xcorr_lanes_t *)(src + 8);
            a[3] += ut * *(const xcorr_lanes_t *)(src + 12);
        }
        memcpy(acc, a, sizeof a);
        for (int b = 0; b < XCORR_BLOCK; b++) {
            Py_ssize_t t = common_hi > lo[b] ? common_hi : lo[b];
            if (common_lo >= hi[b]) t = hi[b]; /* all of this lag's span was its own head */
            for (; t < hi[b]; t++) acc[b] += u[t] * y[t + k0 + b];
            c[k0 + b - first] = acc[b] / norm;
        }
    }
    if (k0 <= last) xcorr_blocked(u, y, n, k0, last, norm, c + (k0 - first));
}

static PyObject *py_xcorr_lags(PyObject *self, PyObject *args)
{
    PyObject *objs[3];
    Py_ssize_t first, last;
    double norm;
    if (!PyArg_ParseTuple(args, "OOnndO", &objs[0], &objs[1], &first, &last, &norm, &objs[2]))
        return NULL;
    const char *names[3] = {"u", "y", "c"};
    Py_buffer b[3];
    if (get_buffers(objs, 3, 2, names, b) < 0) return NULL;
    const Py_ssize_t n = b[0].len / 8;
    PyObject *result = NULL;
    if (b[1].len != b[0].len || b[2].len / 8 != last - first + 1 || first > last || last >= n ||
        -first >= n) {
        PyErr_SetString(PyExc_ValueError, "xcorr_lags: inconsistent sizes");
    } else {
        xcorr_lanes(b[0].buf, b[1].buf, n, first, last, norm, b[2].buf);
        Py_INCREF(Py_None);
        result = Py_None;
    }
    release_buffers(b, 3);
    return result;
}

/* evidence_gains_lanes(torque, regressors, extra, starts, n, out): evidence_gains' windows four
 *   at a time, one window in each lane of a four-double vector: each lane's operations are
 *   evidence_gain's in its order (the sums over the window's samples ascending, the small
 *   system per window solved by the same scalar steps), so the gains are evidence_gains' bit
 *   for bit (tested); a short last group repeats its last window. The slow lane's evidence
 *   (rtsid.ident.yardstick.WindowVafBasis.least_squares_vaf_gains). O(windows·n).
 */
typedef double evidence_lanes __attribute__((vector_size(32)));
#define EVIDENCE_LANES 4

/* evidence_gain's small system of one window: the unscaled Gram (gram, 16) and right-hand
 * sides (rhs, 8) in, the two solutions per unscaled centred column out (p). */
static void evidence_solve(double *gram, const double *rhs, double p[2][4])
{
    double scale[4];
    for (int a = 0; a < 4; a++) scale[a] = sqrt(gram[5 * a]);
    for (int a = 0; a < 4; a++) {
        for (int b = a; b < 4; b++) {
            gram[4 * a + b] /= scale[a] * scale[b];
            gram[4 * b + a] = gram[4 * a + b];
        }
    }
    int piv[4];
    lu_factor(gram, 4, piv);
    for (int j = 0; j < 2; j++) {
        for (int a = 0; a < 4; a++) p[j][a] = rhs[2 * a + j] / scale[a];
        lu_solve(gram, 4, piv, p[j]);
        for (int a = 0; a < 3; a++) p[j][a] /= scale[a]; /* per unscaled centred column */
    }
}

#define EVIDENCE_GATHER(base, offset) \
    ((evidence_lanes){(base)[at[0] + (offset)], (base)[at[1] + (offset)], \
                      (base)[at[2] + (offset)], (base)[at[3] + (offset)]})

FITS4_CLONES static void evidence_group(const double *x, const double *r, Py_ssize_t stride,
                                              const double *e, const Py_ssize_t *at, Py_ssize_t n,
                                              double *gains)
{
    const double *r1 = r + stride, *r2 = r + 2 * stride;
    evidence_lanes mean[5] = {{0}, {0}, {0}, {0}, {0}}; /* θ̈, θ̇, θ, torque, extra */
    for (Py_ssize_t i = 0; i < n; i++) {
        mean[0] += EVIDENCE_GATHER(r, i);
        mean[1] += EVIDENCE_GATHER(r1, i);
        mean[2] += EVIDENCE_GATHER(r2, i);
        mean[3] += EVIDENCE_GATHER(x, i);
        mean[4] += EVIDENCE_GATHER(e, i);
    }
    for (int k = 0; k < 5; k++) mean[k] /= (double)n;
    const double step = 2.0 / (double)(n - 1);
    evidence_lanes gram[16] = {{0}}, rhs[8] = {{0}}, power = {0};
    for (Py_ssize_t i = 0; i < n; i++) {
        const double trend = i == n - 1 ? 1.0 : (double)i * step - 1.0;
        const evidence_lanes col[4] = {EVIDENCE_GATHER(r, i) - mean[0],
                                       EVIDENCE_GATHER(r1, i) - mean[1],
                                       EVIDENCE_GATHER(r2, i) - mean[2],
                                       (evidence_lanes){0} + trend};
        const evidence_lanes measured = EVIDENCE_GATHER(x, i) - mean[3];
        const evidence_lanes added = EVIDENCE_GATHER(e, i) - mean[4];
        for (int a = 0; a < 4; a++) {
            for (int b = a; b < 4; b++) gram[4 * a + b] += col[a] * col[b];
            rhs[2 * a] += col[a] * (measured - added);
            rhs[2 * a + 1] += col[a] * measured;
        }
        power += measured * measured;
    }
    evidence_lanes pv[2][3];
    for (int q = 0; q < EVIDENCE_LANES; q++) {
        double g[16], h[8], p[2][4];
        for (int k = 0; k < 16; k++) g[k] = gram[k][q];
        for (int k = 0; k < 8; k++) h[k] = rhs[k][q];
        evidence_solve(g, h, p);
        for (int j = 0; j < 2; j++)
            for (int a = 0; a < 3; a++) pv[j][a][q] = p[j][a];
    }
    evidence_lanes left[2] = {{0}, {0}};
    for (Py_ssize_t i = 0; i < n; i++) {
        const evidence_lanes c0 = EVIDENCE_GATHER(r, i) - mean[0];
        const evidence_lanes c1 = EVIDENCE_GATHER(r1, i) - mean[1];
        const evidence_lanes c2 = EVIDENCE_GATHER(r2, i) - mean[2];
        const evidence_lanes measured = EVIDENCE_GATHER(x, i) - mean[3];
        const evidence_lanes added = EVIDENCE_GATHER(e, i) - mean[4];
        const evidence_lanes with =
            measured - (pv[0][0] * c0 + pv[0][1] * c1 + pv[0][2] * c2) - added;
        const evidence_lanes without = measured - (pv[1][0] * c0 + pv[1][1] * c1 + pv[1][2] * c2);
        left[0] += with * with;
        left[1] += without * without;
    }
    for (int q = 0; q < EVIDENCE_LANES; q++)
        gains[q] = 100.0 * (1.0 - left[0][q] / power[q]) - 100.0 * (1.0 - left[1][q] / power[q]);
}
#undef EVIDENCE_GATHER

/* evidence_gains and evidence_gains_lanes: the same arguments and checks, one window at a
 * time (lanes 0: evidence_gain, the reference) or four at a time (evidence_group). */
static PyObject *evidence_entry(PyObject *args, const char *name, int lanes)
{
    PyObject *objs[4], *starts_obj, *out_obj;
    Py_ssize_t n;
    if (!PyArg_ParseTuple(args, "OOOOnO", &objs[0], &objs[1], &objs[2], &starts_obj, &n, &out_obj))
        return NULL;
    objs[3] = out_obj;
    const char *names[4] = {"torque", "regressors", "extra", "out"};
    Py_buffer b[4], s;
    if (get_buffers(objs, 4, 3, names, b) < 0) return NULL;
    if (get_indices(starts_obj, &s, "starts") < 0) {
        release_buffers(b, 4);
        return NULL;
    }
    const Py_ssize_t total = b[0].len / 8, windows = s.len / 8;
    const long long *starts = (const long long *)s.buf;
    int ok = n >= 3 && b[1].len == 3 * b[0].len && b[2].len == b[0].len && b[3].len == s.len;
    for (Py_ssize_t w = 0; ok && w < windows; w++) ok = starts[w] >= 0 && starts[w] + n <= total;
    PyObject *result = NULL;
    if (!ok) {
        PyErr_Format(PyExc_ValueError, "%s: inconsistent sizes", name);
    } else {
        if (!lanes) {
            const double *x = b[0].buf, *r = b[1].buf, *e = b[2].buf;
            double *out = b[3].buf;
            for (Py_ssize_t w = 0; w < windows; w++) {
                const Py_ssize_t a = (Py_ssize_t)starts[w];
                out[w] = evidence_gain(x + a, r + a, total, e + a, n);
            }
        } else {
            double *out = b[3].buf;
            for (Py_ssize_t w = 0; w < windows; w += EVIDENCE_LANES) {
                Py_ssize_t at[EVIDENCE_LANES];
                double gains[EVIDENCE_LANES];
                for (int q = 0; q < EVIDENCE_LANES; q++)
                    at[q] = (Py_ssize_t)starts[w + q < windows ? w + q : windows - 1];
                evidence_group(b[0].buf, b[1].buf, total, b[2].buf, at, n, gains);
                for (int q = 0; q < EVIDENCE_LANES && w + q < windows; q++) out[w + q] = gains[q];
            }
        }
        Py_INCREF(Py_None);
        result = Py_None;
    }
    PyBuffer_Release(&s);
    release_buffers(b, 4);
    return result;
}

static PyObject *py_evidence_gains_lanes(PyObject *self, PyObject *args)
{
    return evidence_entry(args, "evidence_gains_lanes", 1);
}

/* stencil_correlate(x, taps, scale, out): out[i] = (Σ_j x[i + j]·taps[j])·scale for the
 *   len(x) − len(taps) + 1 fully supported samples, each sum from 0 over j ascending: numpy's
 *   correlate(x, taps, "valid") (its small_correlate loop for up to 11 taps) times scale, bit
 *   for bit (tested), eight outputs at a time in two four-double vectors (each lane's sum
 *   over the taps in order, in registers). rtsid.ident.filters.stencil_velocity (the slow
 *   lane's stretch velocity over a 20 s horizon). O(n·taps).
 */
typedef double stencil_lanes __attribute__((vector_size(32), aligned(8))); /* unaligned loads */

FITS4_CLONES static void stencil_correlate_run(const double *x, Py_ssize_t n, const double *taps,
                                               Py_ssize_t nt, double scale, double *out)
{
    const Py_ssize_t m = n - nt + 1;
    Py_ssize_t i = 0;
    /* eight outputs at a time, their sums in two vectors in registers over the taps */
    for (; i + 8 <= m; i += 8) {
        stencil_lanes a = {0.0, 0.0, 0.0, 0.0}, b = {0.0, 0.0, 0.0, 0.0};
        for (Py_ssize_t j = 0; j < nt; j++) {
            const stencil_lanes tap = (stencil_lanes){0.0, 0.0, 0.0, 0.0} + taps[j];
            a += *(const stencil_lanes *)(x + i + j) * tap;
            b += *(const stencil_lanes *)(x + i + j + 4) * tap;
        }
        a *= scale;
        b *= scale;
        memcpy(out + i, &a, sizeof a);
        memcpy(out + i + 4, &b, sizeof b);
    }
    for (; i < m; i++) {
        double acc = 0.0;
        for (Py_ssize_t j = 0; j < nt; j++) acc += x[i + j] * taps[j];
        out[i] = acc * scale;
    }
}

static PyObject *py_stencil_correlate(PyObject *self, PyObject *args)
{
    PyObject *objs[3];
    double scale;
    if (!PyArg_ParseTuple(args, "OOdO", &objs[0], &objs[1], &scale, &objs[2])) return NULL;
    const char *names[3] = {"x", "taps", "out"};
    Py_buffer b[3];
    if (get_buffers(objs, 3, 2, names, b) < 0) return NULL;
    const Py_ssize_t n = b[0].len / 8, nt = b[1].len / 8;
    PyObject *result = NULL;
    if (nt < 1 || nt > n || b[2].len / 8 != n - nt + 1) {
        PyErr_SetString(PyExc_ValueError, "stencil_correlate: out must have len(x) - len(taps) + 1");
    } else {
        stencil_correlate_run(b[0].buf, n, b[1].buf, nt, scale, b[2].buf);
        Py_INCREF(Py_None);
        result = Py_None;
    }
    release_buffers(b, 3);
    return result;
}

/* ================================================================== readrest (issue 22)
 * Replay's own work around the windows, one call per message instead of a dozen Python steps:
 * reading a recording's /samples payloads and writing its /estimate payloads.
 *
 * samples_into(data, position, torque, valid, status, offset) -> (first_index, fs_hz, rows)
 *   or None: a samples payload in the logger's compact layout (rtsid.io.schemas.encode_samples:
 *   {"first_index":I,"fs_hz":F,"t_first_s":T,"position_rad":[…],"torque_nm":[…],"valid":[…],
 *   "status":[…]}, no whitespace) decoded straight into rows offset … offset + rows − 1 of
 *   preallocated columns (float64, float64, bool, int64, one length). Its numbers are
 *   json_array's (the same doubles as json.loads, bit for bit: the same correctly rounded
 *   conversions), their digits read eight at a time. None: another layout (fs_hz an integer
 *   or null, say), columns of different lengths, more rows than the columns hold after offset,
 *   or anything json_array refuses; the caller then reads the payload by the reference
 *   (rtsid.io.schemas.decode_samples), which accepts it or says what is wrong. Rows after
 *   offset may have been written when it declines.
 *
 * estimate_json(message, keys, prefixes) -> bytes or None: an estimate message (a dict whose
 *   keys are `keys`, in that order) as json.dumps(separators=(",", ":")) writes it: prefixes[k]
 *   (`{"robot":`, `,"joint":`, …) then the value, a number by Python's own repr (float's
 *   shortest round trip, PyOS_double_to_string 'r' as float.__repr__; int's decimal), texts
 *   and lists of texts as json's ASCII encoder writes them (escapes included). None (the
 *   caller encodes it the Python way, rtsid.io.schemas.estimate_payload) for anything else:
 *   another key order, a non-finite number (null in the reference), a value of another type
 *   (numpy integers, mappings, nested lists).
 */

/* The eight bytes at v are all ASCII digits (fast_float's test, little-endian). */
static inline int rr_eight_digits(uint64_t v)
{
    return !(((v + 0x4646464646464646ULL) | (v - 0x3030303030303030ULL)) & 0x8080808080808080ULL);
}

/* The value of eight ASCII digits, the first the most significant (little-endian load). */
static inline uint64_t rr_parse_eight(uint64_t v)
{
    const uint64_t mask = 0x000000FF000000FFULL;
    const uint64_t mul1 = 0x000F424000000064ULL; /* 100 + (1000000 << 32) */
    const uint64_t mul2 = 0x0000271000000001ULL; /* 1 + (10000 << 32) */
    v -= 0x3030303030303030ULL;
    v = (v * 10) + (v >> 8);
    return (((v & mask) * mul1) + (((v >> 16) & mask) * mul2)) >> 32;
}

/* A run of digits from s[j]: accumulated into *w while it stays below 2^64 (*overflow set
 * otherwise); returns the index after the run. Eight digits at a time while w·10^8 + 99999999
 * fits in 64 bits, then four while w·10^4 + 9999 does (exact: the same w as one digit at a
 * time), then one at a time. */
static inline Py_ssize_t rr_digits(const char *s, Py_ssize_t j, Py_ssize_t stop,
                                   unsigned long long *w, int *overflow)
{
    unsigned long long acc = *w;
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    while (j + 8 <= stop && acc <= 184467440736ULL) { /* (2^64 − 1 − 99999999) / 10^8 */
        uint64_t v;
        memcpy(&v, s + j, 8);
        if (!rr_eight_digits(v)) break;
        acc = acc * 100000000ULL + rr_parse_eight(v);
        j += 8;
    }
    if (j + 4 <= stop && acc <= 1844674407370954ULL) { /* (2^64 − 1 − 9999) / 10^4 */
        uint32_t v;
        memcpy(&v, s + j, 4);
        if ((((v + 0x46464646U) | (v - 0x30303030U)) & 0x80808080U) == 0) {
            v -= 0x30303030U;
            v = (v * 10) + (v >> 8); /* two-digit pairs in bytes 0 and 2 */
            acc = acc * 10000ULL + ((v & 0x000000FFU) * 100 + ((v >> 16) & 0x000000FFU));
            j += 4;
        }
    }
#endif
    for (; j < stop && (unsigned char)(s[j] - '0') <= 9; j++) {
        if (acc > (ULLONG_MAX - 9) / 10) {
            *overflow = 1;
        } else {
            acc = acc * 10 + (unsigned)(s[j] - '0');
        }
    }
    *w = acc;
    return j;
}

/* One float item (a JSON number with a fraction or exponent, or null) at s[i] into *out;
 * returns its end or -1. The digits are read once (JSON grammar checked as they are), and the
 * value formed as decimal_fast forms it; what that does not cover goes to json_item. */
static Py_ssize_t rr_double(const char *s, Py_ssize_t i, Py_ssize_t stop, double *out)
{
    if (s[i] == 'n') return json_item(s, i, stop, 0, (char *)out);
#if LDBL_MANT_DIG == 64
    static const long double pow10[28] = {
        1e0L, 1e1L, 1e2L, 1e3L, 1e4L, 1e5L, 1e6L, 1e7L, 1e8L, 1e9L, 1e10L, 1e11L, 1e12L, 1e13L,
        1e14L, 1e15L, 1e16L, 1e17L, 1e18L, 1e19L, 1e20L, 1e21L, 1e22L, 1e23L, 1e24L, 1e25L,
        1e26L, 1e27L};
    unsigned long long w = 0;
    int overflow = 0, integer = 1, negative = s[i] == '-';
    long scale = 0;
    Py_ssize_t j = i + negative, d;
    if (j >= stop) return -1;
    if (s[j] == '0') {
        j++;
    } else if (s[j] >= '1' && s[j] <= '9') {
        j = rr_digits(s, j, stop, &w, &overflow);
        if (overflow) return json_item(s, i, stop, 0, (char *)out);
    } else {
        return -1;
    }
    if (j < stop && s[j] == '.') {
        integer = 0;
        d = ++j;
        j = rr_digits(s, j, stop, &w, &overflow);
        if (j == d) return -1;
        scale = -(long)(j - d);
    }
    if (j < stop && (s[j] == 'e' || s[j] == 'E')) {
        long exponent = 0;
        int minus = 0;
        integer = 0;
        j++;
        if (j < stop && (s[j] == '+' || s[j] == '-')) minus = s[j++] == '-';
        d = j;
        for (; j < stop && s[j] >= '0' && s[j] <= '9'; j++) {
            if (exponent <= 100000) exponent = exponent * 10 + (s[j] - '0');
        }
        if (j == d) return -1;
        scale += minus ? -exponent : exponent;
    }
    if (integer) return -1; /* json.loads makes an int of it: the reference */
    if (overflow || j - i >= JSON_NUMBER_MAX) return json_item(s, i, stop, 0, (char *)out);
    if (w == 0) {
        *out = negative ? -0.0 : 0.0;
        return j;
    }
    if (scale < -27 || scale > 27) return json_item(s, i, stop, 0, (char *)out);
    long double r = (long double)w;
    r = scale < 0 ? r / pow10[-scale] : r * pow10[scale];
    double v = (double)r;
    if ((long double)v != r) {
        double other = r > (long double)v ? nextafter(v, INFINITY) : nextafter(v, -INFINITY);
        if (((long double)v + (long double)other) * 0.5L == r) /* halfway: one rounding */
            return json_item(s, i, stop, 0, (char *)out);
    }
    if (!(v >= DBL_MIN && v <= DBL_MAX)) return json_item(s, i, stop, 0, (char *)out);
    *out = negative ? -v : v;
    return j;
#else
    return json_item(s, i, stop, 0, (char *)out);
#endif
}

/* The items of the array opening at s[i] (after its '[') into rows offset … of out (item
 * size `size`, `capacity` rows); returns the index after its ']' or -1, *rows the count. */
static Py_ssize_t rr_column(const char *s, Py_ssize_t i, Py_ssize_t stop, int kind, char *out,
                            Py_ssize_t size, Py_ssize_t offset, Py_ssize_t capacity,
                            Py_ssize_t *rows)
{
    Py_ssize_t n = 0;
    if (i < stop && s[i] == ']') {
        *rows = 0;
        return i + 1;
    }
    while (i < stop) {
        if (offset + n >= capacity) return -1;
        char *item = out + (offset + n) * size;
        if (kind == 0) {
            i = rr_double(s, i, stop, (double *)item);
        } else if (kind == 1 && stop - i > 4 && memcmp(s + i, "true", 4) == 0) {
            *(unsigned char *)item = 1; /* json_item's reading of it, without its calls */
            i += 4;
        } else if (kind == 2 && stop - i > 1 && (unsigned char)(s[i] - '0') <= 9 &&
                   (s[i + 1] == ',' || s[i + 1] == ']')) {
            *(long long *)item = s[i] - '0'; /* one digit: json_item's value */
            i += 1;
        } else {
            i = json_item(s, i, stop, kind, item);
        }
        if (i < 0 || i >= stop) return -1;
        n++;
        if (s[i] == ']') {
            *rows = n;
            return i + 1;
        }
        if (s[i] != ',') return -1;
        i++;
    }
    return -1;
}

/* s[i:] starts with `word`: the index after it, else -1. */
static Py_ssize_t rr_expect(const char *s, Py_ssize_t i, Py_ssize_t stop, const char *word)
{
    const Py_ssize_t n = (Py_ssize_t)strlen(word);
    return i >= 0 && stop - i >= n && memcmp(s + i, word, (size_t)n) == 0 ? i + n : -1;
}

static PyObject *py_samples_into(PyObject *self, PyObject *args)
{
    static const char *const separators[4] = {
        ",\"position_rad\":[", "],\"torque_nm\":[", "],\"valid\":[", "],\"status\":["};
    static const int kinds[4] = {0, 0, 1, 2};
    static const Py_ssize_t sizes[4] = {8, 8, 1, 8};
    Py_buffer data, col[4];
    Py_ssize_t offset;
    if (!PyArg_ParseTuple(args, "y*w*w*w*w*n", &data, &col[0], &col[1], &col[2], &col[3],
                          &offset))
        return NULL;
    const char *s = (const char *)data.buf;
    const Py_ssize_t stop = data.len;
    const Py_ssize_t capacity = col[0].len / 8;
    long long first_index = 0;
    double fs_hz = 0.0, ignored;
    Py_ssize_t rows = -1, n = 0, i;
    int ok = offset >= 0;
    for (int c = 0; c < 4; c++) ok = ok && col[c].len == capacity * sizes[c];
    i = ok ? rr_expect(s, 0, stop, "{\"first_index\":") : -1;
    if (i >= 0 && i < stop) i = json_item(s, i, stop, 2, (char *)&first_index); else i = -1;
    i = rr_expect(s, i, stop, ",\"fs_hz\":");
    if (i >= 0 && i < stop && s[i] != 'n') i = rr_double(s, i, stop, &fs_hz); else i = -1;
    i = rr_expect(s, i, stop, ",\"t_first_s\":");
    if (i >= 0 && i < stop) i = rr_double(s, i, stop, &ignored); else i = -1;
    for (int c = 0; ok && c < 4 && i >= 0; c++) {
        i = rr_expect(s, i, stop, separators[c]);
        if (i < 0) break;
        /* the arrays' closing brackets are part of the next separator */
        i = rr_column(s, i, stop, kinds[c], (char *)col[c].buf, sizes[c], offset, capacity, &n);
        if (i < 0) break;
        i--;
        if (rows >= 0 && n != rows) i = -1;
        rows = n;
    }
    ok = ok && i >= 0 && i == stop - 2 && s[i] == ']' && s[i + 1] == '}';
    PyBuffer_Release(&data);
    for (int c = 0; c < 4; c++) PyBuffer_Release(&col[c]);
    if (!ok) Py_RETURN_NONE;
    return Py_BuildValue("(Ldn)", first_index, fs_hz, rows);
}

/* A growing output buffer: a local array first, then the heap. */
typedef struct {
    char *p;
    Py_ssize_t n, cap;
    char local[1536];
} rr_buf;

static int rr_put(rr_buf *b, const char *src, Py_ssize_t n)
{
    if (b->n + n > b->cap) {
        Py_ssize_t cap = 2 * (b->n + n);
        char *p = b->p == b->local ? PyMem_Malloc((size_t)cap) : PyMem_Realloc(b->p, (size_t)cap);
        if (p == NULL) {
            PyErr_NoMemory();
            return -1;
        }
        if (b->p == b->local) memcpy(p, b->local, (size_t)b->n);
        b->p = p;
        b->cap = cap;
    }
    memcpy(b->p + b->n, src, (size_t)n);
    b->n += n;
    return 1;
}

/* A text as json's ASCII encoder (encode_basestring_ascii) writes it: printable ASCII as it
 * is, `"` and `\` escaped, \b \f \n \r \t, every other character as \uXXXX (lowercase hex;
 * beyond the BMP a surrogate pair). 1 done, -1 error. */
static int rr_text(rr_buf *b, PyObject *v)
{
    static const char hex[] = "0123456789abcdef";
    const Py_ssize_t n = PyUnicode_GET_LENGTH(v);
    const int kind = PyUnicode_KIND(v);
    const void *data = PyUnicode_DATA(v);
    if (rr_put(b, "\"", 1) < 0) return -1;
    if (PyUnicode_IS_ASCII(v)) { /* the usual text: printable ASCII, copied whole */
        const char *t = (const char *)data;
        Py_ssize_t k = 0;
        while (k < n && t[k] >= ' ' && t[k] <= '~' && t[k] != '"' && t[k] != '\\') k++;
        if (k == n) return rr_put(b, t, n) < 0 || rr_put(b, "\"", 1) < 0 ? -1 : 1;
    }
    for (Py_ssize_t k = 0; k < n; k++) {
        Py_UCS4 c = PyUnicode_READ(kind, data, k);
        char out[12];
        int m = 0;
        if (c >= ' ' && c <= '~' && c != '"' && c != '\\') {
            out[m++] = (char)c;
        } else {
            out[m++] = '\\';
            switch (c) {
            case '\\': out[m++] = '\\'; break;
            case '"': out[m++] = '"'; break;
            case '\b': out[m++] = 'b'; break;
            case '\f': out[m++] = 'f'; break;
            case '\n': out[m++] = 'n'; break;
            case '\r': out[m++] = 'r'; break;
            case '\t': out[m++] = 't'; break;
            default:
                if (c >= 0x10000) {
                    const Py_UCS4 high = Py_UNICODE_HIGH_SURROGATE(c);
                    out[m++] = 'u';
                    for (int shift = 12; shift >= 0; shift -= 4) out[m++] = hex[(high >> shift) & 0xf];
                    c = Py_UNICODE_LOW_SURROGATE(c);
                    out[m++] = '\\';
                }
                out[m++] = 'u';
                for (int shift = 12; shift >= 0; shift -= 4) out[m++] = hex[(c >> shift) & 0xf];
            }
        }
        if (rr_put(b, out, m) < 0) return -1;
    }
    return rr_put(b, "\"", 1) < 0 ? -1 : 1;
}

/* One value of an estimate: 1 written, 0 not one this encoder writes, -1 error. */
static int rr_value(rr_buf *b, PyObject *v, int top)
{
    if (v == Py_None) return rr_put(b, "null", 4);
    if (v == Py_True) return rr_put(b, "true", 4);
    if (v == Py_False) return rr_put(b, "false", 5);
    if (PyUnicode_Check(v)) return rr_text(b, v);
    if (PyLong_Check(v)) {
        int overflow = 0;
        long long x = PyLong_AsLongLongAndOverflow(v, &overflow);
        if (x == -1 && PyErr_Occurred()) return -1;
        if (overflow) { /* beyond 64 bits: int's own decimal, as json writes it */
            PyObject *text = PyLong_Type.tp_repr(v);
            if (text == NULL) return -1;
            Py_ssize_t n;
            const char *t = PyUnicode_AsUTF8AndSize(text, &n);
            int done = t == NULL ? -1 : rr_put(b, t, n);
            Py_DECREF(text);
            return done;
        }
        char digits[32];
        int n = snprintf(digits, sizeof digits, "%lld", x);
        return rr_put(b, digits, n);
    }
    if (PyFloat_Check(v)) {
        const double x = PyFloat_AS_DOUBLE(v);
        if (!isfinite(x)) return 0; /* null in the reference */
        char *repr = PyOS_double_to_string(x, 'r', 0, Py_DTSF_ADD_DOT_0, NULL);
        if (repr == NULL) return -1;
        int done = rr_put(b, repr, (Py_ssize_t)strlen(repr));
        PyMem_Free(repr);
        return done;
    }
    if (top && (PyList_Check(v) || PyTuple_Check(v))) {
        PyObject *seq = v;
        const Py_ssize_t n = PySequence_Fast_GET_SIZE(seq);
        PyObject **items = PySequence_Fast_ITEMS(seq);
        if (rr_put(b, "[", 1) < 0) return -1;
        for (Py_ssize_t k = 0; k < n; k++) {
            if (k > 0 && rr_put(b, ",", 1) < 0) return -1;
            if (!PyUnicode_Check(items[k])) return 0;
            if (rr_text(b, items[k]) < 0) return -1;
        }
        return rr_put(b, "]", 1);
    }
    return 0;
}

static PyObject *py_estimate_json(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 3 || !PyTuple_Check(args[1]) || !PyTuple_Check(args[2]) ||
        PyTuple_GET_SIZE(args[1]) != PyTuple_GET_SIZE(args[2])) {
        PyErr_SetString(PyExc_TypeError, "estimate_json(message, keys, prefixes): two tuples");
        return NULL;
    }
    PyObject *message = args[0], *keys = args[1], *prefixes = args[2];
    const Py_ssize_t count = PyTuple_GET_SIZE(keys);
    if (!PyDict_CheckExact(message) || PyDict_GET_SIZE(message) != count) Py_RETURN_NONE;
    rr_buf b;
    b.p = b.local;
    b.n = 0;
    b.cap = (Py_ssize_t)sizeof b.local;
    PyObject *key, *value, *result = NULL;
    Py_ssize_t pos = 0, k = 0;
    int done = 1;
    while (done > 0 && PyDict_Next(message, &pos, &key, &value)) {
        PyObject *want = PyTuple_GET_ITEM(keys, k);
        PyObject *prefix = PyTuple_GET_ITEM(prefixes, k);
        if (key != want && (!PyUnicode_Check(key) || PyUnicode_Compare(key, want) != 0)) {
            if (PyErr_Occurred()) done = -1; else done = 0;
            break;
        }
        if (!PyBytes_Check(prefix)) {
            PyErr_SetString(PyExc_TypeError, "estimate_json: prefixes must be bytes");
            done = -1;
            break;
        }
        done = rr_put(&b, PyBytes_AS_STRING(prefix), PyBytes_GET_SIZE(prefix));
        if (done > 0) done = rr_value(&b, value, 1);
        k++;
    }
    if (done > 0 && k == count && rr_put(&b, "}", 1) > 0) {
        result = PyBytes_FromStringAndSize(b.p, b.n);
    } else if (done >= 0 && !PyErr_Occurred()) {
        result = Py_None;
        Py_INCREF(result);
    }
    if (b.p != b.local) PyMem_Free(b.p);
    return result;
}

/* ------------------------------------------------------------------ branch winpath (issue 22)
 * instance_dict: the tracker's (and its filters', the newest part's) attributes are read and
 * written through the instance's __dict__ (section stream8's tracker_step), a dictionary lookup
 * with the interned name instead of getattr's type walk. An attribute found in the instance's
 * dictionary is what getattr returns and what setattr replaces: the classes (ParameterTracker,
 * _LevelRateFilter, NewestPart) define no data descriptor of these names
 * (tests/ident/test_window_path_lanes.py).
 */
/* The instance's __dict__ (a new reference) by the public PyObject_GenericGetDict, or NULL
 * (no error set) for an object without one. */
static PyObject *instance_dict(PyObject *obj)
{
    if (Py_TYPE(obj)->tp_dictoffset == 0) return NULL;
    PyObject *dict = PyObject_GenericGetDict(obj, NULL);
    if (dict == NULL || !PyDict_Check(dict)) {
        Py_XDECREF(dict);
        PyErr_Clear();
        return NULL;
    }
    return dict;
}

/* minus_line(out, n, coef, t): out[i] -= coef·(t + i) for i < n, as the scalar loop
 * `for (...; t += 1.0) out[i] -= coef * t` of without_trend: t steps by 1 between integers or
 * half-integers, so t + i in either lane is the scalar loop's t exactly, and each lane does the
 * same multiply and subtract. */
static void minus_line(double *out, Py_ssize_t n, double coef, double t)
{
    Py_ssize_t i = 0;
#ifdef LANE_PAIRS
    const lane_pair c = pair_of(coef), two = pair_of(2.0);
    lane_pair tp = {t, t + 1.0};
    for (; i + 2 <= n; i += 2, tp += two) {
        lane_pair v = pair_at(out + i);
        v -= c * tp;
        memcpy(out + i, &v, sizeof v);
    }
    t += (double)i;
#endif
    for (; i < n; i++, t += 1.0) out[i] -= coef * t;
}

/* phase_minus_line: one phase of detrend_phases' linear detrending, phase[j] = sign·x[i] − off −
 * line·t for i = p, p + factor, … < n with t stepping by factor from the given t (integers or
 * half-integers: every t exact, as the scalar loop's), two outputs at a time, each lane the
 * scalar expression's operations in its order. */
static void phase_minus_line(const double *x, Py_ssize_t p, Py_ssize_t n, Py_ssize_t factor,
                             double sign, double off, double line, double t, double *phase)
{
    const double step = (double)factor;
    Py_ssize_t i = p;
#ifdef LANE_PAIRS
    const lane_pair sg = pair_of(sign), of = pair_of(off), ln = pair_of(line);
    const lane_pair two_steps = pair_of(2.0 * step);
    lane_pair tp = {t, t + step};
    for (; i + factor < n; i += 2 * factor, tp += two_steps, phase += 2) {
        const lane_pair v = {x[i], x[i + factor]};
        const lane_pair out = sg * v - of - ln * tp;
        memcpy(phase, &out, sizeof out);
    }
    memcpy(&t, &tp, sizeof t); /* the next t: the first lane's */
#endif
    for (; i < n; i += factor, t += step) *phase++ = sign * x[i] - off - line * t;
}

/* stencil_rows: oe_design's regressor rows, d1[t] = (Σ_s u[t + s]·STENCIL_D1[s])·fs,
 * d2[t] = (Σ_s u[t + s]·STENCIL_D2[s])·fs², u0[t] = u[t + 4] for t < n, rows t and t + 1 in the
 * two lanes: each lane sums its s = 0 … 8 in order from 0.0, as the scalar loop. */
static void stencil_rows(const double *u, Py_ssize_t n, double fs, double *d1, double *d2,
                         double *u0)
{
    Py_ssize_t t = 0;
#ifdef LANE_PAIRS
    const lane_pair f1 = pair_of(fs), f2 = pair_of(fs * fs);
    for (; t + 2 <= n; t += 2) {
        lane_pair a1 = pair_of(0.0), a2 = pair_of(0.0);
        for (int s = 0; s < 9; s++) {
            const lane_pair v = pair_at(u + t + s);
            a1 += v * pair_of(STENCIL_D1[s]);
            a2 += v * pair_of(STENCIL_D2[s]);
        }
        a1 *= f1;
        a2 *= f2;
        memcpy(d1 + t, &a1, sizeof a1);
        memcpy(d2 + t, &a2, sizeof a2);
        u0[t] = u[t + 4];
        u0[t + 1] = u[t + 5];
    }
#endif
    for (; t < n; t++) {
        double a1 = 0.0, a2 = 0.0;
        for (int s = 0; s < 9; s++) {
            a1 += u[t + s] * STENCIL_D1[s];
            a2 += u[t + s] * STENCIL_D2[s];
        }
        d1[t] = a1 * fs;
        d2[t] = a2 * (fs * fs);
        u0[t] = u[t + 4];
    }
}

/* ------------------------------------------------------------------ branch fits5 (issue 22)
 * The slow lane's fits, seventh pass: zero_phase_rows' copies into and out of its interleaved
 * buffer a 4 × 4 block at a time (four vector loads, eight shuffles, four vector stores)
 * instead of one double per lane and step. Copies only: the same numbers bit for bit.
 */
#define FITS5_LANES 4 /* the lanes of fits3's lanes_t */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__ELF__)
#define FITS5_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define FITS5_CLONES
#endif
#if defined(__GNUC__) && !defined(__clang__)
typedef long long lanes_mask_t __attribute__((vector_size(8 * FITS5_LANES)));
/* The 4 × 4 block whose rows are a, b, c, d, transposed into out[0..3]. */
static inline __attribute__((always_inline)) void lanes_transpose(lanes_t a, lanes_t b, lanes_t c,
                                                                  lanes_t d, lanes_t *out)
{
    const lanes_mask_t even = {0, 4, 2, 6}, odd = {1, 5, 3, 7};
    const lanes_mask_t low = {0, 1, 4, 5}, high = {2, 3, 6, 7};
    const lanes_t ab0 = __builtin_shuffle(a, b, even), ab1 = __builtin_shuffle(a, b, odd);
    const lanes_t cd0 = __builtin_shuffle(c, d, even), cd1 = __builtin_shuffle(c, d, odd);
    out[0] = __builtin_shuffle(ab0, cd0, low);
    out[1] = __builtin_shuffle(ab1, cd1, low);
    out[2] = __builtin_shuffle(ab0, cd0, high);
    out[3] = __builtin_shuffle(ab1, cd1, high);
}

/* Four doubles at p (any alignment). */
#define LANES_AT(v, p) memcpy(&(v), (p), sizeof(v))
#define FITS5_BLOCKS 1
#endif

/* lanes_extend: scipy's odd extension of the rows row[0..3] (n samples each) into buf,
 * interleaved (lane q of buf[i] from row q): 2·x[0] − x[e − j] before, x, then
 * 2·x[n−1] − x[n−2−j] after; the interior copied a block at a time. */
FITS5_CLONES static void lanes_extend(const double *const *row, Py_ssize_t n, Py_ssize_t e,
                                      lanes_t *buf)
{
    Py_ssize_t i = 0;
#ifdef FITS5_BLOCKS
    const double *r0 = row[0], *r1 = row[1], *r2 = row[2], *r3 = row[3];
    for (; i + FITS5_LANES <= n; i += FITS5_LANES) {
        lanes_t a, b, c, d;
        LANES_AT(a, r0 + i);
        LANES_AT(b, r1 + i);
        LANES_AT(c, r2 + i);
        LANES_AT(d, r3 + i);
        lanes_transpose(a, b, c, d, buf + e + i);
    }
#endif
    for (int q = 0; q < FITS5_LANES; q++) {
        const double *x = row[q];
        double *lane = (double *)buf + q;
        const double first = 2.0 * x[0], last = 2.0 * x[n - 1];
        for (Py_ssize_t j = 0; j < e; j++) lane[FITS5_LANES * j] = first - x[e - j];
        for (Py_ssize_t k = i; k < n; k++) lane[FITS5_LANES * (e + k)] = x[k];
        for (Py_ssize_t j = 0; j < e; j++) lane[FITS5_LANES * (e + n + j)] = last - x[n - 2 - j];
    }
}

/* lanes_read_out: lane q of buf[factor·k] into out[q][k] for k < kept (rows repeated in a short
 * last group are written twice, with the same values); with factor 1 a block at a time. */
FITS5_CLONES static void lanes_read_out(const lanes_t *buf, Py_ssize_t kept, Py_ssize_t factor,
                                        double *const *out)
{
    Py_ssize_t k = 0;
#ifdef FITS5_BLOCKS
    if (factor == 1) {
        double *o0 = out[0], *o1 = out[1], *o2 = out[2], *o3 = out[3];
        for (; k + FITS5_LANES <= kept; k += FITS5_LANES) {
            lanes_t block[FITS5_LANES];
            lanes_transpose(buf[k], buf[k + 1], buf[k + 2], buf[k + 3], block);
            memcpy(o0 + k, &block[0], sizeof block[0]);
            memcpy(o1 + k, &block[1], sizeof block[1]);
            memcpy(o2 + k, &block[2], sizeof block[2]);
            memcpy(o3 + k, &block[3], sizeof block[3]);
        }
    }
#endif
    for (; k < kept; k++) {
        const lanes_t v = buf[k * factor];
        for (int q = 0; q < FITS5_LANES; q++) out[q][k] = v[q];
    }
}

/* ================================================================== rest7 (issue 22)
 * checking the CRC-32 of a recording's decompressed chunks.
 *
 * crc32(data, value=0) -> int: zlib.crc32(data, value) (the IEEE 802.3 / gzip CRC-32 an MCAP
 *   chunk's uncompressed_crc holds), folded sixteen bytes at a time by carry-less
 *   multiplication where the CPU has it (PCLMULQDQ; the folding of zlib's crc32_simd.c, Intel's
 *   "Fast CRC Computation for Generic Polynomials Using PCLMULQDQ", 2009), a byte table
 *   otherwise and for the last bytes. zlib's own loop took ≈ 4 instructions a byte, the fifth
 *   of replay's reading a recording. Any buffer (bytes, memoryview, numpy array).
 */

#include <stdint.h>

/* The reflected CRC-32 table (polynomial 0xEDB88320), one byte at a time. */
static uint32_t crc_table[256];

static void crc_table_fill(void)
{
    for (uint32_t n = 0; n < 256; n++) {
        uint32_t c = n;
        for (int k = 0; k < 8; k++) c = c & 1 ? 0xEDB88320U ^ (c >> 1) : c >> 1;
        crc_table[n] = c;
    }
}

/* The register (not complemented) advanced over n bytes, one at a time. */
static uint32_t crc_bytes(uint32_t c, const unsigned char *p, Py_ssize_t n)
{
    for (Py_ssize_t i = 0; i < n; i++) c = crc_table[(c ^ p[i]) & 0xFFU] ^ (c >> 8);
    return c;
}

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define CRC_FOLDING 1

/* The register (not complemented) advanced over n bytes, n ≥ 64 and a multiple of 16. */
__attribute__((target("pclmul,sse4.1"))) static uint32_t crc_fold(uint32_t crc,
                                                                  const unsigned char *buf,
                                                                  Py_ssize_t len)
{
    /* x^(4·128+64), x^(4·128) mod P; x^(128+64), x^128; x^64; the Barrett µ and P (all
     * bit-reflected, shifted left once). */
    const __m128i k1k2 = _mm_set_epi64x(0x01c6e41596LL, 0x0154442bd4LL);
    const __m128i k3k4 = _mm_set_epi64x(0x00ccaa009eLL, 0x01751997d0LL);
    const __m128i k5k0 = _mm_set_epi64x(0, 0x0163cd6124LL);
    const __m128i poly = _mm_set_epi64x(0x01f7011641LL, 0x01db710641LL);
    __m128i x1, x2, x3, x4, x5, x6, x7, x8;

    x1 = _mm_loadu_si128((const __m128i *)(buf + 0x00));
    x2 = _mm_loadu_si128((const __m128i *)(buf + 0x10));
    x3 = _mm_loadu_si128((const __m128i *)(buf + 0x20));
    x4 = _mm_loadu_si128((const __m128i *)(buf + 0x30));
    x1 = _mm_xor_si128(x1, _mm_cvtsi32_si128((int)crc));
    buf += 64;
    len -= 64;
    while (len >= 64) { /* four lanes of 128 bits folded 512 bits ahead */
        x5 = _mm_clmulepi64_si128(x1, k1k2, 0x00);
        x6 = _mm_clmulepi64_si128(x2, k1k2, 0x00);
        x7 = _mm_clmulepi64_si128(x3, k1k2, 0x00);
        x8 = _mm_clmulepi64_si128(x4, k1k2, 0x00);
        x1 = _mm_clmulepi64_si128(x1, k1k2, 0x11);
        x2 = _mm_clmulepi64_si128(x2, k1k2, 0x11);
        x3 = _mm_clmulepi64_si128(x3, k1k2, 0x11);
        x4 = _mm_clmulepi64_si128(x4, k1k2, 0x11);
        x1 = _mm_xor_si128(_mm_xor_si128(x1, x5), _mm_loadu_si128((const __m128i *)(buf + 0x00)));
        x2 = _mm_xor_si128(_mm_xor_si128(x2, x6), _mm_loadu_si128((const __m128i *)(buf + 0x10)));
        x3 = _mm_xor_si128(_mm_xor_si128(x3, x7), _mm_loadu_si128((const __m128i *)(buf + 0x20)));
        x4 = _mm_xor_si128(_mm_xor_si128(x4, x8), _mm_loadu_si128((const __m128i *)(buf + 0x30)));
        buf += 64;
        len -= 64;
    }
    /* the four lanes into one */
    x5 = _mm_clmulepi64_si128(x1, k3k4, 0x00);
    x1 = _mm_clmulepi64_si128(x1, k3k4, 0x11);
    x1 = _mm_xor_si128(_mm_xor_si128(x1, x2), x5);
    x5 = _mm_clmulepi64_si128(x1, k3k4, 0x00);
    x1 = _mm_clmulepi64_si128(x1, k3k4, 0x11);
    x1 = _mm_xor_si128(_mm_xor_si128(x1, x3), x5);
    x5 = _mm_clmulepi64_si128(x1, k3k4, 0x00);
    x1 = _mm_clmulepi64_si128(x1, k3k4, 0x11);
    x1 = _mm_xor_si128(_mm_xor_si128(x1, x4), x5);
    while (len >= 16) { /* one lane, 128 bits ahead */
        x2 = _mm_loadu_si128((const __m128i *)buf);
        x5 = _mm_clmulepi64_si128(x1, k3k4, 0x00);
        x1 = _mm_clmulepi64_si128(x1, k3k4, 0x11);
        x1 = _mm_xor_si128(_mm_xor_si128(x1, x2), x5);
        buf += 16;
        len -= 16;
    }
    /* 128 bits to 64, then Barrett's reduction to 32 */
    x2 = _mm_clmulepi64_si128(x1, k3k4, 0x10);
    x3 = _mm_setr_epi32(~0, 0, ~0, 0);
    x1 = _mm_xor_si128(_mm_srli_si128(x1, 8), x2);
    x2 = _mm_srli_si128(x1, 4);
    x1 = _mm_and_si128(x1, x3);
    x1 = _mm_xor_si128(_mm_clmulepi64_si128(x1, k5k0, 0x00), x2);
    x2 = _mm_and_si128(x1, x3);
    x2 = _mm_clmulepi64_si128(x2, poly, 0x10);
    x2 = _mm_and_si128(x2, x3);
    x2 = _mm_clmulepi64_si128(x2, poly, 0x00);
    x1 = _mm_xor_si128(x1, x2);
    return (uint32_t)_mm_extract_epi32(x1, 1);
}
#endif

/* -1: not checked yet; 0: no carry-less multiplication; 1: folding. */
static int crc_can_fold = -1;

/* The table filled and the CPU asked, once (under the GIL). */
static void crc_ready(void)
{
    if (crc_can_fold >= 0) return;
    crc_table_fill();
#ifdef CRC_FOLDING
    __builtin_cpu_init();
    crc_can_fold = __builtin_cpu_supports("pclmul") && __builtin_cpu_supports("sse4.1");
#else
    crc_can_fold = 0;
#endif
}

/* zlib.crc32(p[0:n], value), after crc_ready. */
static uint32_t crc_update(uint32_t value, const unsigned char *p, Py_ssize_t n)
{
    uint32_t c = ~value;
#ifdef CRC_FOLDING
    if (crc_can_fold && n >= 64) {
        const Py_ssize_t folded = n & ~(Py_ssize_t)15;
        c = crc_fold(c, p, folded);
        p += folded;
        n -= folded;
    }
#endif
    return ~crc_bytes(c, p, n);
}

static PyObject *py_crc32(PyObject *self, PyObject *args)
{
    Py_buffer data;
    unsigned int value = 0;
    if (!PyArg_ParseTuple(args, "y*|I", &data, &value)) return NULL;
    crc_ready();
    const uint32_t c = crc_update((uint32_t)value, (const unsigned char *)data.buf, data.len);
    PyBuffer_Release(&data);
    return PyLong_FromUnsignedLong(c);
}

/* ================================================================== glue7 (issue 22)
 * The window path's lane-pair loops four lanes wide. On x86-64 each function below is built
 * twice (target_clones: an AVX2 clone, chosen at load time where the processor has it, and
 * the baseline); a four-double vector holds four independent outputs (or, in g7_dot, the
 * four running sums s0 … s3 that dot_unrolled keeps), and each lane does the IEEE multiply
 * and add of the scalar loop in the same order: no fused multiply-add (the AVX2 clone enables
 * neither FMA nor contraction, and the build says -ffp-contract=off), so every output is the
 * loop's bit for bit, as the lane pairs' were, in half the vector instructions. Where the
 * compiler has no vector extension (G7_QUADS undefined) the callers keep their lane pairs.
 *
 * g7_dot          dot_unrolled's four sums as one vector, the remainder into s0 (inlined as
 *                 g7_dot_inline, top of file, into eureka_filters, eureka_apply and
 *                 gram_sweeps, themselves built as clones: EUREKA's element-wise updates
 *                 four lanes wide too).
 * g7_fir_rows     fir_phases' outputs 32 (then 16) at a time.
 * g7_smooth_rows  band_smooth's rows 32 (then 16) at a time over its padded row.
 * g7_predict_rows lagged_predict's outputs 16 at a time.
 * g7_band_powers  band_powers_table's groups of four bins, the bins in the lanes.
 * The front end's correlations use fits4's xcorr_lanes (sixteen lags at a time).
 */
#ifdef G7_QUADS
GLUE7_CLONES static double g7_dot(const double *u, const double *v, Py_ssize_t n)
{
    return g7_dot_inline(u, v, n);
}

GLUE7_CLONES static Py_ssize_t g7_fir_rows(const double *phases, const Py_ssize_t *at,
                                           const double *taps, Py_ssize_t nt, Py_ssize_t m,
                                           double *out)
{
    Py_ssize_t k = 0;
    for (; k + 32 <= m; k += 32) {
        g7_quad a[8];
        for (int b = 0; b < 8; b++) a[b] = g7_of(0.0);
        for (Py_ssize_t j = 0; j < nt; j++) {
            const g7_quad tj = g7_of(taps[j]);
            const double *s = phases + at[j] + k;
            for (int b = 0; b < 8; b++) a[b] += tj * g7_at(s + 4 * b);
        }
        memcpy(out + k, a, sizeof a);
    }
    for (; k + 16 <= m; k += 16) {
        g7_quad a[4];
        for (int b = 0; b < 4; b++) a[b] = g7_of(0.0);
        for (Py_ssize_t j = 0; j < nt; j++) {
            const g7_quad tj = g7_of(taps[j]);
            const double *s = phases + at[j] + k;
            for (int b = 0; b < 4; b++) a[b] += tj * g7_at(s + 4 * b);
        }
        memcpy(out + k, a, sizeof a);
    }
    return k;
}

/* padded: the row with `lags` zeros each side; mirror[lags + e] = r[|e|]. */
GLUE7_CLONES static Py_ssize_t g7_smooth_rows(const double *padded, const double *mirror,
                                              Py_ssize_t n, Py_ssize_t lags, double *smoothed)
{
    Py_ssize_t t = 0;
    for (; t + 32 <= n; t += 32) {
        g7_quad a[8];
        for (int b = 0; b < 8; b++) a[b] = g7_of(0.0);
        for (Py_ssize_t e = -lags; e <= lags; e++) {
            const g7_quad re = g7_of(mirror[lags + e]);
            const double *src = padded + lags + t + e;
            for (int b = 0; b < 8; b++) a[b] += g7_at(src + 4 * b) * re;
        }
        memcpy(smoothed + t, a, sizeof a);
    }
    for (; t + 16 <= n; t += 16) {
        g7_quad a[4];
        for (int b = 0; b < 4; b++) a[b] = g7_of(0.0);
        for (Py_ssize_t e = -lags; e <= lags; e++) {
            const g7_quad re = g7_of(mirror[lags + e]);
            const double *src = padded + lags + t + e;
            for (int b = 0; b < 4; b++) a[b] += g7_at(src + 4 * b) * re;
        }
        memcpy(smoothed + t, a, sizeof a);
    }
    return t;
}

GLUE7_CLONES static Py_ssize_t g7_predict_rows(const double *h, const double *u, Py_ssize_t nh,
                                               Py_ssize_t lag, Py_ssize_t t0, Py_ssize_t t1,
                                               double *out)
{
    Py_ssize_t t = t0;
    for (; t + 16 <= t1; t += 16) {
        g7_quad a[4];
        for (int b = 0; b < 4; b++) a[b] = g7_of(0.0);
        for (Py_ssize_t j = 0; j < nh; j++) {
            const g7_quad hj = g7_of(h[j]);
            const double *src = u + t + lag - j;
            for (int b = 0; b < 4; b++) a[b] += hj * g7_at(src + 4 * b);
        }
        memcpy(out + t, a, sizeof a);
    }
    return t;
}

GLUE7_CLONES static void g7_band_powers(const double *meas, const double *err, Py_ssize_t n,
                                        Py_ssize_t kmax, const double *table, double *total,
                                        double *left)
{
    for (Py_ssize_t g = 0; g < (kmax + 3) / 4; g++) {
        const double *at = table + g * n * 8;
        g7_quad mr = g7_of(0.0), mi = mr, er = mr, ei = mr;
        for (Py_ssize_t t = 0; t < n; t++, at += 8) {
            const g7_quad m = g7_of(meas[t]), e = g7_of(err[t]);
            const g7_quad c = g7_at(at), s = g7_at(at + 4);
            mr += m * c;
            mi -= m * s;
            er += e * c;
            ei -= e * s;
        }
        double r[4][4];
        memcpy(r[0], &mr, 32), memcpy(r[1], &mi, 32), memcpy(r[2], &er, 32);
        memcpy(r[3], &ei, 32);
        for (int b = 0; b < 4 && 4 * g + 1 + b <= kmax; b++) {
            *total += r[0][b] * r[0][b] + r[1][b] * r[1][b];
            *left += r[2][b] * r[2][b] + r[3][b] * r[3][b];
        }
    }
}
#endif /* G7_QUADS */

/* round12(*values) -> tuple of round(value, 12): the published VAFs' rounding (rtsid.ident.
 * assess.published_vafs; Python's round is the reference). round(x, 12) is the double nearest
 * the decimal N·10⁻¹², N the integer nearest the exact x·10¹² (float.__round__: dtoa's digits,
 * then strtod). N and 10¹² are exact doubles below 2⁵³, so IEEE's correctly rounded N / 10¹² is
 * that double. N is nearbyint(x·10¹²) when the exact remainder x·10¹² − N (the product's
 * rounding error by Dekker's split, exact without a fused multiply-add) is clearly inside
 * ±1/2; near a tie, for |x| ≥ 4096, for NaN, infinities and non-floats Python's round
 * answers. About 30 instructions a value instead of a decimal conversion (≈ 8 k). */
static int g7_round12(double x, double *out)
{
    static const double scale = 1e12, split = 134217729.0; /* 2^27 + 1 */
    if (!(fabs(x) < 4096.0)) return 0;
    const double p = x * scale, n = nearbyint(p);
    double c = split * x;
    const double xh = c - (c - x), xl = x - xh;
    c = split * scale;
    const double sh = c - (c - scale), sl = scale - sh;
    const double err = ((xh * sh - p) + xh * sl + xl * sh) + xl * sl; /* x·10¹² − p, exactly */
    const double r = (p - n) + err;
    if (!(fabs(r) < 0.499)) return 0;
    *out = n / scale;
    return 1;
}

static PyObject *py_round12(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    PyObject *result = PyTuple_New(nargs);
    if (result == NULL) return NULL;
    for (Py_ssize_t i = 0; i < nargs; i++) {
        double rounded;
        PyObject *item;
        if (PyFloat_CheckExact(args[i]) && g7_round12(PyFloat_AS_DOUBLE(args[i]), &rounded)) {
            item = PyFloat_FromDouble(rounded);
        } else {
            item = PyObject_CallMethod(args[i], "__round__", "i", 12); /* the reference */
        }
        if (item == NULL) {
            Py_DECREF(result);
            return NULL;
        }
        PyTuple_SET_ITEM(result, i, item);
    }
    return result;
}

/* ------------------------------------------------------------------ branch fits6 (issue 22)
 * The slow lane's fits, eighth pass: what a fit can take from the previous one bit for bit.
 *
 * savgol_range(x, taps1, taps2, lo, hi, d1, d2): the interior outputs i in [lo, hi) of
 *   savgol_pair (ndimage's correlation of each filter, its order of operations: the same
 *   ndimage_interior and ndimage_point of section fits3) written into d1 and d2, nothing else
 *   written: each interior output depends on x[i − half … i + half] alone, so a record's
 *   interior outputs are those of any record holding those samples (the slow lane's evidence
 *   basis keeps the previous fit's and forms only the new ones: rtsid.ident.yardstick.
 *   BasisStore). half ≤ lo ≤ hi ≤ n − half (half = taps // 2), else a ValueError. O((hi − lo)·taps).
 * all_finite(x, y) -> bool: no NaN nor infinity in x nor in y (numpy.isfinite(x).all() and
 *   numpy.isfinite(y).all()), from the sum of v·0 over both, four lanes at a time (0 for
 *   finite v, NaN for a NaN or an infinity). O(n).
 */
#define FITS6_LANES 4
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__ELF__)
#define FITS6_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define FITS6_CLONES
#endif
typedef double fits6_lanes __attribute__((vector_size(8 * FITS6_LANES)));
typedef double fits6_lanes_u __attribute__((vector_size(8 * FITS6_LANES), aligned(8)));

static void savgol_interior_range(const double *x, Py_ssize_t lo, Py_ssize_t hi,
                                  const double *taps, Py_ssize_t size, double *out)
{
    double reversed[64];
    for (Py_ssize_t k = 0; k < size; k++) reversed[k] = taps[size - 1 - k];
    const Py_ssize_t half = size / 2;
    const double *fw = reversed + half;
    const int symmetry = ndimage_symmetry(fw, half);
    /* the records x[lo − half … hi + half): its interior outputs are outputs lo … hi − 1 */
    const double *sub = x + lo - half;
    const Py_ssize_t m = hi - lo + 2 * half;
    double *sub_out = out + lo - half;
    const Py_ssize_t formed = hi > lo ? ndimage_interior(sub, m, fw, half, symmetry, sub_out) : 0;
    for (Py_ssize_t i = formed > half ? formed : half; i < m - half; i++)
        sub_out[i] = ndimage_point(sub, m, i, fw, half, symmetry, 1);
}

static PyObject *py_savgol_range(PyObject *self, PyObject *args)
{
    PyObject *objs[5];
    Py_ssize_t lo, hi;
    if (!PyArg_ParseTuple(args, "OOOnnOO", &objs[0], &objs[1], &objs[2], &lo, &hi, &objs[3],
                          &objs[4]))
        return NULL;
    const char *names[5] = {"x", "taps1", "taps2", "d1", "d2"};
    Py_buffer b[5];
    if (get_buffers(objs, 5, 3, names, b) < 0) return NULL;
    const Py_ssize_t n = b[0].len / 8, size = b[1].len / 8, half = size / 2;
    PyObject *result = NULL;
    if (size < 1 || size > 63 || size % 2 == 0 || b[2].len != b[1].len || b[3].len != b[0].len ||
        b[4].len != b[0].len || lo < half || hi < lo || hi > n - half) {
        PyErr_SetString(PyExc_ValueError, "savgol_range: inconsistent sizes or range");
    } else {
        savgol_interior_range(b[0].buf, lo, hi, b[1].buf, size, b[3].buf);
        savgol_interior_range(b[0].buf, lo, hi, b[2].buf, size, b[4].buf);
        Py_INCREF(Py_None);
        result = Py_None;
    }
    release_buffers(b, 5);
    return result;
}

FITS6_CLONES static int all_finite_run(const double *x, Py_ssize_t n)
{
    fits6_lanes acc = {0.0, 0.0, 0.0, 0.0};
    Py_ssize_t i = 0;
    for (; i + FITS6_LANES <= n; i += FITS6_LANES) acc += *(const fits6_lanes_u *)(x + i) * 0.0;
    double rest = 0.0;
    for (; i < n; i++) rest += x[i] * 0.0;
    return acc[0] == 0.0 && acc[1] == 0.0 && acc[2] == 0.0 && acc[3] == 0.0 && rest == 0.0;
}

static PyObject *py_all_finite(PyObject *self, PyObject *args)
{
    PyObject *objs[2];
    if (!PyArg_ParseTuple(args, "OO", &objs[0], &objs[1])) return NULL;
    const char *names[2] = {"x", "y"};
    Py_buffer b[2];
    if (get_buffers(objs, 2, 2, names, b) < 0) return NULL;
    const int finite = all_finite_run(b[0].buf, b[0].len / 8) && all_finite_run(b[1].buf, b[1].len / 8);
    release_buffers(b, 2);
    return PyBool_FromLong(finite);
}
#undef FITS6_LANES
#undef FITS6_CLONES

/* ================================================================== eval8 (issue 22)
 * window_scan(position, torque, valid, status, start, stop) -> (raised, all_valid, finite) or
 * None: the evaluator's check of rows start .. stop - 1 of a window's columns in one pass,
 * where numpy took three reductions and the window sums (rtsid.ident.check.window_scan, whose
 * numpy body stays the reference): the status bits any row raises (OR), whether every row is
 * valid (AND), and whether the sums of the valid rows' position and of their torque are
 * finite (they are iff every term is: rad and N·m never overflow), summed in row order as
 * window_sums does. None when a column is not the type the data path gives (contiguous
 * float64 position and torque, one-byte valid, unsigned one- or eight-byte status): the
 * caller then takes the reference.
 */
static int e8_column(PyObject *obj, Py_buffer *view, Py_ssize_t itemsize, Py_ssize_t alt)
{
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) != 0) {
        PyErr_Clear();
        return 0;
    }
    const char *f = view->format;
    int ok = view->ndim == 1 && (view->itemsize == itemsize || view->itemsize == alt) && f != NULL;
    if (ok) { /* float64 columns, else one- or eight-byte integers (or bool) */
        const char code = f[0] != '\0' ? f[strlen(f) - 1] : '\0';
        ok = itemsize == 8 && alt == 8 ? strcmp(f, "d") == 0 : code != '\0' && strchr("bB?lLqQ", code) != NULL;
    }
    if (!ok) PyBuffer_Release(view);
    return ok;
}

static PyObject *py_window_scan(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError,
                        "window_scan(position, torque, valid, status, start, stop)");
        return NULL;
    }
    const Py_ssize_t start = PyLong_AsSsize_t(args[4]), stop = PyLong_AsSsize_t(args[5]);
    if ((start == -1 || stop == -1) && PyErr_Occurred()) return NULL;
    Py_buffer b[4];
    int got = 0;
    got += e8_column(args[0], &b[0], 8, 8);
    if (got == 1) got += e8_column(args[1], &b[1], 8, 8);
    if (got == 2) got += e8_column(args[2], &b[2], 1, 1);
    if (got == 3) got += e8_column(args[3], &b[3], 1, 8);
    if (got < 4) {
        for (int i = 0; i < got; i++) PyBuffer_Release(&b[i]);
        Py_RETURN_NONE;
    }
    const Py_ssize_t n = b[0].len / 8;
    if (b[1].len / 8 != n || b[2].len != n || b[3].len / b[3].itemsize != n || start < 0 ||
        stop > n || start > stop) {
        for (int i = 0; i < 4; i++) PyBuffer_Release(&b[i]);
        PyErr_SetString(PyExc_ValueError, "window_scan: columns of different lengths, or rows "
                                          "outside them");
        return NULL;
    }
    const double *p = b[0].buf, *t = b[1].buf;
    const unsigned char *v = b[2].buf;
    unsigned long long raised = 0;
    if (b[3].itemsize == 1) {
        const unsigned char *s = b[3].buf;
        unsigned char r = 0;
        for (Py_ssize_t i = start; i < stop; i++) r |= s[i];
        raised = r;
    } else {
        const unsigned long long *s = b[3].buf;
        for (Py_ssize_t i = start; i < stop; i++) raised |= s[i];
    }
    int all_valid = 1;
    for (Py_ssize_t i = start; i < stop; i++) all_valid &= v[i] != 0;
    double sp = 0.0, st = 0.0;
    if (all_valid) {
        for (Py_ssize_t i = start; i < stop; i++) {
            sp += p[i];
            st += t[i];
        }
    } else {
        for (Py_ssize_t i = start; i < stop; i++) {
            if (v[i]) {
                sp += p[i];
                st += t[i];
            }
        }
    }
    for (int i = 0; i < 4; i++) PyBuffer_Release(&b[i]);
    return Py_BuildValue("(KOO)", raised, all_valid ? Py_True : Py_False,
                         isfinite(sp) && isfinite(st) ? Py_True : Py_False);
}

/* finite_dict(names, values) -> dict: {names[i]: values[i]} in order, a float that is not
 * finite (JSON has no NaN) as None: rtsid.io.messages._json_object's comprehension (the
 * reference) in one call, the dict sized once for its keys instead of grown key by key (a
 * copy of a laid-out dict, its values then replaced, measured 15 % more instructions). */
static PyObject *py_finite_dict(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 2 || !PyTuple_Check(args[0]) || !PyTuple_Check(args[1]) ||
        PyTuple_GET_SIZE(args[0]) != PyTuple_GET_SIZE(args[1])) {
        PyErr_SetString(PyExc_TypeError, "finite_dict(names, values): two tuples of one length");
        return NULL;
    }
    const Py_ssize_t n = PyTuple_GET_SIZE(args[0]);
    PyObject *out = _PyDict_NewPresized(n);
    if (out == NULL) return NULL;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *value = PyTuple_GET_ITEM(args[1], i);
        if (PyFloat_Check(value) && !isfinite(PyFloat_AS_DOUBLE(value))) value = Py_None;
        if (PyDict_SetItem(out, PyTuple_GET_ITEM(args[0], i), value) < 0) {
            Py_DECREF(out);
            return NULL;
        }
    }
    return out;
}

/* ------------------------------------------------------------------ branch fits7 (issue 22)
 * The slow lane's fits, ninth pass: the MDL rank without a full eigendecomposition.
 *
 * mdl_decompose(phi_rr) -> bytes, then mdl_rank(decomposition, full, power_e, n_samples, out)
 *   -> rank: rtsid.ident.reflex.mdl_projection for a symmetric Toeplitz matrix T (first column
 *   phi_rr, size n = L + 1 ≥ 4) and its EUREKA solution `full`. T is centrosymmetric, so it
 *   splits into its symmetric and skew-symmetric halves (as reflex._centrosymmetric_halves);
 *   mdl_decompose reduces each half to tridiagonal form by Householder reflections (the whole
 *   trailing block updated, so every product runs along rows, four lanes of partial sums) and
 *   finds its eigenvalues by implicit QL (tql2's iteration), recording each rotation instead
 *   of accumulating eigenvectors: O(m³) with a small constant for the reduction, O(m²) for
 *   QL (numpy's dsyevd also forms every eigenvector). Formed once per system (a cascade's
 *   alternations share it: reflex.ToeplitzSystem keeps it). mdl_rank folds `full` on each
 *   half, applies the reflections and the rotations to it (every coefficient vᵢᵀ·full,
 *   O(m²)), keeps the components explaining the most output variance up to the rank where
 *   V(M)·(1 + M·ln N / N) is smallest (numpy's expressions), and forms Σ_kept cᵢ·vᵢ as Q·Z·u
 *   (u: the kept coefficients, the others zero) by the rotations in reverse, then the
 *   reflections: one vector, whatever the rank. The eigenpairs of numpy.linalg.eigh to
 *   rounding, not the same bits (the numpy reference stays the RTSID_NUMPY_ONLY=1 path, tested
 *   to agree). mdl_decompose raises ArithmeticError when QL does not converge (60 sweeps for
 *   one eigenvalue); mdl_rank a ValueError for bytes that are not a decomposition.
 */
typedef struct {
    Py_ssize_t *at; /* the rotation's first index i (it rotates i and i + 1) */
    double *cs;     /* its cosine and sine, two per rotation */
    Py_ssize_t count, room;
} fits7_rotations;

static int fits7_record(fits7_rotations *r, Py_ssize_t i, double c, double s)
{
    if (r->count == r->room) {
        const Py_ssize_t room = r->room ? 2 * r->room : 1024;
        Py_ssize_t *at = PyMem_RawRealloc(r->at, (size_t)room * sizeof(Py_ssize_t));
        if (at == NULL) return -1;
        r->at = at;
        double *cs = PyMem_RawRealloc(r->cs, (size_t)room * 2 * sizeof(double));
        if (cs == NULL) return -1;
        r->cs = cs;
        r->room = room;
    }
    r->at[r->count] = i;
    r->cs[2 * r->count] = c;
    r->cs[2 * r->count + 1] = s;
    r->count++;
    return 0;
}

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__ELF__)
#define FITS7_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define FITS7_CLONES
#endif
typedef double fits7_lanes __attribute__((vector_size(32)));
typedef double fits7_lanes_u __attribute__((vector_size(32), aligned(8)));

/* Σ x[j]·y[j], four lanes of partial sums (then lanes 0 + 1 + 2 + 3, then the tail) */
FITS7_CLONES static double fits7_dot(const double *x, const double *y, Py_ssize_t n)
{
    fits7_lanes acc = {0.0, 0.0, 0.0, 0.0};
    Py_ssize_t j = 0;
    for (; j + 4 <= n; j += 4) acc += *(const fits7_lanes_u *)(x + j) * *(const fits7_lanes_u *)(y + j);
    double s = ((acc[0] + acc[1]) + acc[2]) + acc[3];
    for (; j < n; j++) s += x[j] * y[j];
    return s;
}

/* row[j] −= v_i·w[j] + w_i·v[j], j < n */
FITS7_CLONES static void fits7_rank2_row(double *row, double vi, const double *w, double wi,
                                         const double *v, Py_ssize_t n)
{
    for (Py_ssize_t j = 0; j < n; j++) row[j] -= vi * w[j] + wi * v[j];
}

/* Householder reduction of the symmetric a (m × m, row-major, both triangles, overwritten) to
 * tridiagonal d (m), e (m: e[i] couples i and i + 1, e[m − 1] = 0). Reflection k
 * (I − βₖ·vₖ·vₖᵀ on rows and columns k + 1 … m − 1) is kept in a's row k right of the
 * diagonal (vₖ, contiguous), βₖ in beta[k]; the trailing block is updated whole (both
 * triangles), so every product runs along rows. */
static void fits7_tridiagonal(double *a, Py_ssize_t m, double *d, double *e, double *beta,
                              double *p)
{
    for (Py_ssize_t k = 0; k + 2 < m; k++) {
        double *v = a + k * m + k + 1; /* row k's tail: the column below the diagonal */
        const Py_ssize_t r = m - k - 1;
        const double x0 = v[0];
        const double sigma = fits7_dot(v + 1, v + 1, r - 1);
        d[k] = a[k * m + k];
        if (sigma == 0.0) {
            beta[k] = 0.0;
            e[k] = x0;
            continue;
        }
        const double norm = sqrt(x0 * x0 + sigma);
        const double alpha = x0 > 0.0 ? -norm : norm;
        /* v = x − α·e₁ (v₀ = x₀ − α, no cancellation), β = 2 / vᵀv */
        v[0] = x0 - alpha;
        const double b = 2.0 / (v[0] * v[0] + sigma);
        beta[k] = b;
        e[k] = alpha;
        /* p = β·A₂₂·v, w = p − (β·pᵀv / 2)·v, A₂₂ −= v·wᵀ + w·vᵀ */
        double *block = a + (k + 1) * m + k + 1;
        for (Py_ssize_t i = 0; i < r; i++) p[i] = b * fits7_dot(block + i * m, v, r);
        const double half = 0.5 * b * fits7_dot(p, v, r);
        for (Py_ssize_t i = 0; i < r; i++) p[i] -= half * v[i];
        for (Py_ssize_t i = 0; i < r; i++) fits7_rank2_row(block + i * m, v[i], p, p[i], v, r);
    }
    for (Py_ssize_t k = m - 2 > 0 ? m - 2 : 0; k < m; k++) d[k] = a[k * m + k];
    if (m >= 2) {
        e[m - 2] = a[(m - 1) * m + m - 2];
        beta[m - 2] = 0.0;
    }
    e[m - 1] = 0.0;
}

/* y ← Qᵀ·y (forward = 1: the reflections 0, 1, … in turn) or y ← Q·y (forward = 0). */
static void fits7_reflect(const double *a, const double *beta, Py_ssize_t m, double *y, int forward)
{
    for (Py_ssize_t step = 0; step + 2 < m; step++) {
        const Py_ssize_t k = forward ? step : m - 3 - step;
        if (beta[k] == 0.0) continue;
        const double *v = a + k * m + k + 1;
        const Py_ssize_t r = m - k - 1;
        const double s = beta[k] * fits7_dot(v, y + k + 1, r);
        for (Py_ssize_t i = 0; i < r; i++) y[k + 1 + i] -= s * v[i];
    }
}

/* Implicit QL on the tridiagonal (d, e) of size m (tql2's iteration): the eigenvalues into d,
 * each rotation recorded (not accumulated into vectors). 0, or −1 (no convergence, no memory). */
static int fits7_ql(double *d, double *e, Py_ssize_t m, fits7_rotations *rot)
{
    for (Py_ssize_t l = 0; l < m; l++) {
        int sweeps = 0;
        Py_ssize_t k;
        do {
            for (k = l; k + 1 < m; k++) {
                const double dd = fabs(d[k]) + fabs(d[k + 1]);
                if (fabs(e[k]) + dd == dd) break;
            }
            if (k == l) break;
            if (++sweeps > 60) return -1;
            double g = (d[l + 1] - d[l]) / (2.0 * e[l]);
            double r = hypot(g, 1.0);
            g = d[k] - d[l] + e[l] / (g + copysign(r, g));
            double s = 1.0, c = 1.0, p = 0.0;
            int underflow = 0;
            for (Py_ssize_t i = k - 1; i >= l; i--) {
                const double f = s * e[i], b = c * e[i];
                r = sqrt(f * f + g * g); /* f, g: of the matrix's scale, far from overflow */
                e[i + 1] = r;
                if (r == 0.0) {
                    d[i + 1] -= p;
                    e[k] = 0.0;
                    underflow = 1;
                    break;
                }
                s = f / r;
                c = g / r;
                g = d[i + 1] - p;
                r = (d[i] - g) * s + 2.0 * c * b;
                p = s * r;
                d[i + 1] = g + p;
                g = c * r - b;
                if (fits7_record(rot, i, c, s) < 0) return -1;
            }
            if (underflow) continue;
            d[l] -= p;
            e[l] = g;
            e[k] = 0.0;
        } while (1);
    }
    return 0;
}

/* w ← Zᵀ·w (the recorded rotations in order: w's coefficients on the eigenvectors) */
static void fits7_rotate(const double *rotations, Py_ssize_t count, double *w)
{
    for (Py_ssize_t q = 0; q < count; q++) {
        const Py_ssize_t i = (Py_ssize_t)rotations[3 * q];
        const double c = rotations[3 * q + 1], s = rotations[3 * q + 2];
        const double wi = w[i], wn = w[i + 1];
        w[i + 1] = s * wi + c * wn;
        w[i] = c * wi - s * wn;
    }
}

/* u ← Z·u (the recorded rotations, last first) */
static void fits7_unrotate(const double *rotations, Py_ssize_t count, double *u)
{
    for (Py_ssize_t q = count - 1; q >= 0; q--) {
        const Py_ssize_t i = (Py_ssize_t)rotations[3 * q];
        const double c = rotations[3 * q + 1], s = rotations[3 * q + 2];
        const double ui = u[i], un = u[i + 1];
        u[i] = c * ui + s * un;
        u[i + 1] = c * un - s * ui;
    }
}

/* A decomposition, as mdl_decompose packs it into one bytes object of doubles:
 * [n, rotations of the symmetric half, of the skew half], then each half's reflections (its
 * matrix after fits7_tridiagonal, m × m), their β (m), its eigenvalues (m), and each half's
 * rotations (i, c, s). */
typedef struct {
    Py_ssize_t n, ms, mk, count_s, count_k;
    const double *as, *ak, *bs, *bk, *ls, *lk, *rot_s, *rot_k;
} fits7_decomposition;

static Py_ssize_t fits7_packed_doubles(Py_ssize_t n, Py_ssize_t count_s, Py_ssize_t count_k)
{
    const Py_ssize_t mk = n / 2, ms = n - mk;
    return 3 + ms * ms + mk * mk + 2 * n + 3 * (count_s + count_k);
}

static int fits7_unpack(const double *packed, Py_ssize_t doubles, fits7_decomposition *t)
{
    if (doubles < 3) return -1;
    t->n = (Py_ssize_t)packed[0];
    t->count_s = (Py_ssize_t)packed[1];
    t->count_k = (Py_ssize_t)packed[2];
    if (t->n < 4 || t->count_s < 0 || t->count_k < 0 ||
        fits7_packed_doubles(t->n, t->count_s, t->count_k) != doubles)
        return -1;
    t->mk = t->n / 2;
    t->ms = t->n - t->mk;
    t->as = packed + 3;
    t->ak = t->as + t->ms * t->ms;
    t->bs = t->ak + t->mk * t->mk;
    t->bk = t->bs + t->ms;
    t->ls = t->bk + t->mk;
    t->lk = t->ls + t->ms;
    t->rot_s = t->lk + t->mk;
    t->rot_k = t->rot_s + 3 * t->count_s;
    return 0;
}

/* The halves of T (as reflex._centrosymmetric_halves forms them, both triangles) into as and
 * ak, tridiagonalised, and their eigenvalues and rotations: 0, or −1. */
static int fits7_decompose(const double *phi, Py_ssize_t n, double *as, double *ak, double *bs,
                           double *bk, double *ls, double *lk, double *e, double *p,
                           fits7_rotations rot[2])
{
    const Py_ssize_t half = n / 2, ms = n - half, mk = half;
    for (Py_ssize_t i = 0; i < half; i++) {
        for (Py_ssize_t j = 0; j < half; j++) {
            const double near = phi[i > j ? i - j : j - i], far = phi[n - 1 - i - j];
            as[i * ms + j] = near + far;
            ak[i * mk + j] = near - far;
        }
    }
    if (n % 2) {
        for (Py_ssize_t i = 0; i < half; i++)
            as[i * ms + half] = as[half * ms + i] = sqrt(2.0) * phi[half - i];
        as[half * ms + half] = phi[0];
    }
    fits7_tridiagonal(as, ms, ls, e, bs, p);
    if (fits7_ql(ls, e, ms, &rot[0]) < 0) return -1;
    fits7_tridiagonal(ak, mk, lk, e, bk, p);
    return fits7_ql(lk, e, mk, &rot[1]);
}

static Py_ssize_t fits7_mdl(const fits7_decomposition *t, const double *full, double power_e,
                            double samples, double *out, double *work)
{
    const Py_ssize_t n = t->n, half = t->mk, ms = t->ms;
    const double root_half = sqrt(0.5);
    double *ys = work, *yk = ys + ms, *explained = yk + half, *u = explained + n;
    Py_ssize_t *order = (Py_ssize_t *)(u + n);
    /* the solution folded on each half's basis, then on its eigenvectors (Zᵀ·Qᵀ·y) */
    for (Py_ssize_t i = 0; i < half; i++) {
        ys[i] = root_half * (full[i] + full[n - 1 - i]);
        yk[i] = root_half * (full[i] - full[n - 1 - i]);
    }
    if (n % 2) ys[half] = full[half];
    fits7_reflect(t->as, t->bs, ms, ys, 1);
    fits7_rotate(t->rot_s, t->count_s, ys);
    fits7_reflect(t->ak, t->bk, half, yk, 1);
    fits7_rotate(t->rot_k, t->count_k, yk);
    /* the variance each component explains, largest first (ties in index order) */
    for (Py_ssize_t i = 0; i < n; i++) {
        const double lambda = i < ms ? t->ls[i] : t->lk[i - ms], c = ys[i]; /* yk follows ys */
        explained[i] = (lambda > 0.0 ? lambda : 0.0) * c * c;
        Py_ssize_t j = i;
        for (; j > 0 && explained[order[j - 1]] < explained[i]; j--) order[j] = order[j - 1];
        order[j] = i;
    }
    /* numpy's expressions: power_e − cumsum, max(·, 1e-300)·(1 + M·ln N / N), first minimum */
    double explained_sum = 0.0, best = INFINITY;
    Py_ssize_t rank = 1;
    const double log_n = log(samples);
    for (Py_ssize_t r = 1; r <= n; r++) {
        explained_sum += explained[order[r - 1]];
        const double residual = power_e - explained_sum;
        const double mdl =
            (residual > 1e-300 ? residual : 1e-300) * (1.0 + (double)r * log_n / samples);
        if (mdl < best) {
            best = mdl;
            rank = r;
        }
    }
    /* Σ_kept cᵢ·vᵢ: each half's Q·Z·u (u: the kept coefficients, the others zero), unfolded
     * as ToeplitzSystem's vectors are */
    for (Py_ssize_t i = 0; i < n; i++) u[i] = 0.0;
    for (Py_ssize_t r = 0; r < rank; r++) u[order[r]] = ys[order[r]];
    double *us = u, *uk = u + ms;
    fits7_unrotate(t->rot_s, t->count_s, us);
    fits7_reflect(t->as, t->bs, ms, us, 0);
    fits7_unrotate(t->rot_k, t->count_k, uk);
    fits7_reflect(t->ak, t->bk, half, uk, 0);
    for (Py_ssize_t i = 0; i < half; i++) {
        out[i] = root_half * us[i] + root_half * uk[i];
        out[n - 1 - i] = root_half * us[i] - root_half * uk[i];
    }
    if (n % 2) out[half] = us[half];
    return rank;
}

static PyObject *py_mdl_decompose(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *obj;
    if (!PyArg_ParseTuple(args, "O", &obj)) return NULL;
    Py_buffer b;
    if (get_doubles(obj, &b, 0, "phi_rr") < 0) return NULL;
    const Py_ssize_t n = b.len / 8, mk = n / 2, ms = n - mk;
    if (n < 4) {
        PyBuffer_Release(&b);
        PyErr_SetString(PyExc_ValueError, "mdl_decompose: at least 4 lags");
        return NULL;
    }
    double *work = PyMem_Malloc((size_t)(ms * ms + mk * mk + 6 * n) * sizeof(double));
    fits7_rotations rot[2] = {{NULL, NULL, 0, 0}, {NULL, NULL, 0, 0}};
    PyObject *result = NULL;
    if (work == NULL) {
        PyErr_NoMemory();
    } else {
        double *as = work, *ak = as + ms * ms, *bs = ak + mk * mk, *bk = bs + ms, *ls = bk + mk;
        double *lk = ls + ms, *e = lk + mk, *p = e + n;
        int status;
        Py_BEGIN_ALLOW_THREADS
        status = fits7_decompose(b.buf, n, as, ak, bs, bk, ls, lk, e, p, rot);
        Py_END_ALLOW_THREADS
        if (status < 0) {
            PyErr_SetString(PyExc_ArithmeticError,
                            "mdl_decompose: the eigenvalue iteration did not converge");
        } else {
            const Py_ssize_t doubles = fits7_packed_doubles(n, rot[0].count, rot[1].count);
            result = PyBytes_FromStringAndSize(NULL, doubles * 8);
            if (result != NULL) {
                double *packed = (double *)PyBytes_AS_STRING(result);
                packed[0] = (double)n;
                packed[1] = (double)rot[0].count;
                packed[2] = (double)rot[1].count;
                memcpy(packed + 3, work, (size_t)(ms * ms + mk * mk + 2 * n) * sizeof(double));
                double *r = packed + 3 + ms * ms + mk * mk + 2 * n;
                for (int h = 0; h < 2; h++) {
                    for (Py_ssize_t q = 0; q < rot[h].count; q++, r += 3) {
                        r[0] = (double)rot[h].at[q];
                        r[1] = rot[h].cs[2 * q];
                        r[2] = rot[h].cs[2 * q + 1];
                    }
                }
            }
        }
    }
    for (int h = 0; h < 2; h++) {
        PyMem_RawFree(rot[h].at);
        PyMem_RawFree(rot[h].cs);
    }
    PyMem_Free(work);
    PyBuffer_Release(&b);
    return result;
}

static PyObject *py_mdl_rank(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objs[2];
    const char *packed;
    Py_ssize_t packed_bytes;
    double power_e, samples;
    if (!PyArg_ParseTuple(args, "y#OddO", &packed, &packed_bytes, &objs[0], &power_e, &samples,
                          &objs[1]))
        return NULL;
    fits7_decomposition t;
    if (packed_bytes % 8 || fits7_unpack((const double *)packed, packed_bytes / 8, &t) < 0) {
        PyErr_SetString(PyExc_ValueError, "mdl_rank: not a decomposition from mdl_decompose");
        return NULL;
    }
    const char *names[2] = {"full", "out"};
    Py_buffer b[2];
    if (get_buffers(objs, 2, 1, names, b) < 0) return NULL;
    PyObject *result = NULL;
    const Py_ssize_t n = t.n;
    double *work = NULL;
    if (b[0].len / 8 != n || b[1].len / 8 != n) {
        PyErr_SetString(PyExc_ValueError, "mdl_rank: inconsistent sizes");
    } else if ((work = PyMem_Malloc((size_t)(4 * n) * sizeof(double) +
                                    (size_t)n * sizeof(Py_ssize_t))) == NULL) {
        PyErr_NoMemory();
    } else {
        const Py_ssize_t rank = fits7_mdl(&t, b[0].buf, power_e, samples, b[1].buf, work);
        result = PyLong_FromSsize_t(rank);
    }
    PyMem_Free(work);
    release_buffers(b, 2);
    return result;
}
#undef FITS7_CLONES

/* ================================================================== stream8 (issue 22)
 * The stream's per-window bookkeeping around onecall_window, in C: what rtsid.ident.stream
 * does in Python for every window of the one-call path (its Python stays the reference, run
 * with RTSID_NUMPY_ONLY=1 and for every window the one call declines; tests/ident/
 * test_stream8.py holds the two together bit for bit).
 *
 * median_new(horizon, min_count) -> a running median, RunningMedian's rule (add, median,
 *   min_count): the last `horizon` values in a ring and the finite ones sorted (inserted and
 *   removed by the same bisections as bisect.insort / bisect_left, so the same multiset), NaN
 *   counted; the median the middle value or the mean of the two middle ones, NaN while a NaN
 *   is in the horizon, None before min_count values.
 * stream_window(position, torque, explained, h, work, consts, state, out, excitation, inertia,
 *   damping, context) -> None (declined: the stream untouched) or (estimate, learned, newest):
 *   onecall_window, then WindowStream._fit_in_one_call's bookkeeping: the typical level read
 *   from and the window's level added to `excitation`; the published VAFs rounded as
 *   published_vafs; the flags of assess.window_flags; the WindowEstimate built as
 *   records.built builds it; the full fit learned by `inertia` and `damping` as
 *   HeldParameters.learn (full_fit_explains's test; learned: whether it was); newest: the
 *   newest hop's (K, variance, centre row) or None.
 *   context = (WindowEstimate, field names, lags_s, fs_hz, method, lost, held flags by k (3
 *   pairs), the seven flags in window_flags' order, low_vaf_percent, k, newest) with newest =
 *   (NewestPart, window_samples - 1, factor, delay, fs_hz): built once per plan and held
 *   value. The newest hop's record is built as split.row_offsets_s places its centre row:
 *   centre_s = (window_samples - 1 - ((row + 4) * factor + delay)) / fs_hz.
 * window_flags(params, se, vafs, low_vaf_percent, flags) -> tuple: the flags stream_window
 *   raises, for tests to hold to assess.window_flags on any numbers.
 */
typedef struct {
    PyObject_HEAD
    Py_ssize_t horizon, min_count, count, head, nans, nsorted;
    double *ring, *sorted;
} S8Median;

static void s8_median_dealloc(S8Median *self)
{
    PyMem_Free(self->ring);
    PyMem_Free(self->sorted);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/* RunningMedian.add: the oldest leaves a full horizon, the value enters */
static void s8_median_push(S8Median *m, double value)
{
    double *s = m->sorted;
    if (m->count == m->horizon) {
        const double oldest = m->ring[m->head];
        if (isnan(oldest)) {
            m->nans -= 1;
        } else { /* del sorted[bisect_left(sorted, oldest)] */
            Py_ssize_t lo = 0, hi = m->nsorted;
            while (lo < hi) {
                const Py_ssize_t mid = (lo + hi) / 2;
                if (s[mid] < oldest) lo = mid + 1;
                else hi = mid;
            }
            memmove(s + lo, s + lo + 1, sizeof(double) * (size_t)(m->nsorted - lo - 1));
            m->nsorted -= 1;
        }
        m->ring[m->head] = value;
        m->head = (m->head + 1) % m->horizon;
    } else {
        m->ring[(m->head + m->count) % m->horizon] = value;
        m->count += 1;
    }
    if (isnan(value)) {
        m->nans += 1;
    } else { /* insort(sorted, value): bisect_right */
        Py_ssize_t lo = 0, hi = m->nsorted;
        while (lo < hi) {
            const Py_ssize_t mid = (lo + hi) / 2;
            if (value < s[mid]) hi = mid;
            else lo = mid + 1;
        }
        memmove(s + lo + 1, s + lo, sizeof(double) * (size_t)(m->nsorted - lo));
        s[lo] = value;
        m->nsorted += 1;
    }
}

/* RunningMedian.median: 0 None, else 1 with *out */
static int s8_median_value(const S8Median *m, double *out)
{
    const Py_ssize_t n = m->nsorted;
    if (m->nans) {
        if (n + m->nans < m->min_count) return 0;
        *out = NAN;
        return 1;
    }
    if (n < m->min_count) return 0;
    const Py_ssize_t half = n / 2;
    *out = n % 2 ? m->sorted[half] : (m->sorted[half - 1] + m->sorted[half]) / 2.0;
    return 1;
}

static PyObject *s8_median_add(S8Median *self, PyObject *value)
{
    const double v = PyFloat_AsDouble(value);
    if (v == -1.0 && PyErr_Occurred()) return NULL;
    s8_median_push(self, v);
    Py_RETURN_NONE;
}

static PyObject *s8_median_median(S8Median *self, PyObject *unused)
{
    (void)unused;
    double v;
    if (!s8_median_value(self, &v)) Py_RETURN_NONE;
    return PyFloat_FromDouble(v);
}

static PyMethodDef s8_median_methods[] = {
    {"add", (PyCFunction)s8_median_add, METH_O, "add(value): RunningMedian.add."},
    {"median", (PyCFunction)s8_median_median, METH_NOARGS,
     "median() -> float or None: RunningMedian.median."},
    {NULL, NULL, 0, NULL},
};

static PyObject *s8_median_min_count(S8Median *self, void *closure)
{
    (void)closure;
    return PyLong_FromSsize_t(self->min_count);
}

static PyGetSetDef s8_median_getset[] = {
    {"min_count", (getter)s8_median_min_count, NULL, "values needed before a median", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject S8MedianType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "rtsid.ident._eureka.RunningMedian",
    .tp_basicsize = sizeof(S8Median),
    .tp_dealloc = (destructor)s8_median_dealloc,
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "The compiled RunningMedian (section stream8): median_new(horizon, min_count).",
    .tp_methods = s8_median_methods,
    .tp_getset = s8_median_getset,
};

static PyObject *py_median_new(PyObject *self, PyObject *args)
{
    (void)self;
    Py_ssize_t horizon, min_count;
    if (!PyArg_ParseTuple(args, "nn", &horizon, &min_count)) return NULL;
    if (PyType_Ready(&S8MedianType) < 0) return NULL;
    S8Median *m = PyObject_New(S8Median, &S8MedianType);
    if (m == NULL) return NULL;
    /* RunningMedian.__init__: max(1, horizon); max(1, min(min_count, horizon)) */
    m->horizon = horizon > 1 ? horizon : 1;
    const Py_ssize_t least = min_count < horizon ? min_count : horizon;
    m->min_count = least > 1 ? least : 1;
    m->count = m->head = m->nans = m->nsorted = 0;
    m->ring = PyMem_Malloc(sizeof(double) * (size_t)m->horizon);
    m->sorted = PyMem_Malloc(sizeof(double) * (size_t)m->horizon);
    if (m->ring == NULL || m->sorted == NULL) {
        Py_DECREF(m);
        return PyErr_NoMemory();
    }
    return (PyObject *)m;
}

static S8Median *s8_as_median(PyObject *obj, const char *name)
{
    if (Py_TYPE(obj) != &S8MedianType) {
        PyErr_Format(PyExc_TypeError, "stream_window: %s must be a compiled running median", name);
        return NULL;
    }
    return (S8Median *)obj;
}

/* round(x, 12) as Python gives it: glue7's, else float.__round__ (the reference) */
static int s8_round12(double x, double *out)
{
    if (g7_round12(x, out)) return 0;
    PyObject *f = PyFloat_FromDouble(x);
    if (f == NULL) return -1;
    PyObject *r = PyObject_CallMethod(f, "__round__", "i", 12);
    Py_DECREF(f);
    if (r == NULL) return -1;
    *out = PyFloat_AsDouble(r);
    Py_DECREF(r);
    return PyErr_Occurred() ? -1 : 0;
}

enum {
    S8C_CLASS, S8C_NAMES, S8C_LAGS, S8C_FS, S8C_METHOD, S8C_LOST, S8C_HELD, S8C_FLAGS,
    S8C_LOW_VAF, S8C_K, S8C_NEWEST, S8C_SIZE
};
enum { S8_FIELDS = 17 };

/* assess.window_flags: the flags in a fixed order */
static PyObject *s8_flags(const double *p, const double *se, const double *vafs, double low,
                          PyObject *table)
{
    PyObject *raised[7];
    int n = 0;
    if (vafs[0] < low) raised[n++] = PyTuple_GET_ITEM(table, 0);
    if (vafs[2] < 50.0) raised[n++] = PyTuple_GET_ITEM(table, 1);
    if (p[2] <= 0) raised[n++] = PyTuple_GET_ITEM(table, 2);
    if (p[1] <= 0) raised[n++] = PyTuple_GET_ITEM(table, 3);
    if (p[0] <= 0) raised[n++] = PyTuple_GET_ITEM(table, 4);
    if (isfinite(se[0]) && se[0] > 0.25 * fabs(p[0])) raised[n++] = PyTuple_GET_ITEM(table, 5);
    if (isfinite(se[2]) && se[2] > 0.1 * fabs(p[2])) raised[n++] = PyTuple_GET_ITEM(table, 6);
    PyObject *flags = PyTuple_New(n);
    if (flags == NULL) return NULL;
    for (int i = 0; i < n; i++) {
        Py_INCREF(raised[i]);
        PyTuple_SET_ITEM(flags, i, raised[i]);
    }
    return flags;
}

/* window_flags(params, se, vafs, low_vaf_percent, table) -> tuple: s8_flags from Python, so
 * that tests hold it to assess.window_flags (the reference) on any numbers */
static PyObject *py_window_flags(PyObject *self, PyObject *args)
{
    (void)self;
    double p[3], se[3], vafs[3], low;
    PyObject *table;
    if (!PyArg_ParseTuple(args, "(ddd)(ddd)(ddd)dO!", &p[0], &p[1], &p[2], &se[0], &se[1],
                          &se[2], &vafs[0], &vafs[1], &vafs[2], &low, &PyTuple_Type, &table)) {
        return NULL;
    }
    if (PyTuple_GET_SIZE(table) != 7) {
        PyErr_SetString(PyExc_ValueError, "window_flags: table must hold the seven flags");
        return NULL;
    }
    return s8_flags(p, se, vafs, low, table);
}

/* records.built(WindowEstimate, ...): the instance's __dict__ filled in field order */
static PyObject *s8_estimate(PyObject *ctx, const double *p, const double *se,
                             const double *vafs, PyObject *h, PyObject *flags)
{
    PyObject *cls = PyTuple_GET_ITEM(ctx, S8C_CLASS), *names = PyTuple_GET_ITEM(ctx, S8C_NAMES);
    const long k = PyLong_AsLong(PyTuple_GET_ITEM(ctx, S8C_K));
    PyObject *held = PyTuple_GET_ITEM(PyTuple_GET_ITEM(ctx, S8C_HELD), k);
    PyObject *values[S8_FIELDS];
    const double numbers[9] = {p[0], p[1], p[2], se[0], se[1], se[2], vafs[0], vafs[1], vafs[2]};
    int made = 0;
    for (; made < 9; made++) {
        if ((values[made] = PyFloat_FromDouble(numbers[made])) == NULL) break;
    }
    PyObject *record = NULL, *dict = NULL;
    if (made < 9) goto done;
    values[9] = h;
    values[10] = PyTuple_GET_ITEM(ctx, S8C_LAGS);
    values[11] = PyTuple_GET_ITEM(ctx, S8C_FS);
    values[12] = flags;
    values[13] = PyTuple_GET_ITEM(ctx, S8C_METHOD);
    values[14] = PyTuple_GET_ITEM(ctx, S8C_LOST);
    values[15] = PyTuple_GET_ITEM(held, 0);
    values[16] = PyTuple_GET_ITEM(held, 1);
    record = PyBaseObject_Type.tp_new((PyTypeObject *)cls, empty_tuple(), NULL);
    if (record == NULL) goto done;
    dict = PyObject_GenericGetDict(record, NULL);
    if (dict == NULL) goto fail;
    for (int i = 0; i < S8_FIELDS; i++) {
        if (PyDict_SetItem(dict, PyTuple_GET_ITEM(names, i), values[i]) < 0) goto fail;
    }
    goto done;
fail:
    Py_CLEAR(record);
done:
    Py_XDECREF(dict);
    for (int i = 0; i < made; i++) Py_DECREF(values[i]);
    return record;
}

/* records.built(NewestPart, k=, var=, centre_s=row_offsets_s(row, plan, window_samples)) */
static PyObject *s8_newest(PyObject *spec, const double *kvr)
{
    double c[4];
    for (int i = 0; i < 4; i++) c[i] = PyFloat_AsDouble(PyTuple_GET_ITEM(spec, 1 + i));
    if (PyErr_Occurred()) return NULL;
    const double centre = (c[0] - ((kvr[2] + 4.0) * c[1] + c[2])) / c[3];
    static PyObject *names[3] = {NULL, NULL, NULL};
    static const char *const fields[3] = {"k", "var", "centre_s"};
    if (tc_intern(names, fields, 3) < 0) return NULL;
    PyObject *values[3] = {PyFloat_FromDouble(kvr[0]), PyFloat_FromDouble(kvr[1]),
                           PyFloat_FromDouble(centre)};
    PyObject *record = NULL, *dict = NULL;
    if (values[0] == NULL || values[1] == NULL || values[2] == NULL) goto done;
    record = PyBaseObject_Type.tp_new((PyTypeObject *)PyTuple_GET_ITEM(spec, 0), empty_tuple(),
                                      NULL);
    if (record == NULL) goto done;
    dict = PyObject_GenericGetDict(record, NULL);
    if (dict == NULL) goto fail;
    for (int i = 0; i < 3; i++) {
        if (PyDict_SetItem(dict, names[i], values[i]) < 0) goto fail;
    }
    goto done;
fail:
    Py_CLEAR(record);
done:
    Py_XDECREF(dict);
    for (int i = 0; i < 3; i++) Py_XDECREF(values[i]);
    return record;
}

static PyObject *py_stream_window(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 12) {
        PyErr_SetString(PyExc_TypeError, "stream_window(position, torque, explained, h, work, "
                                         "consts, state, out, excitation, inertia, damping, "
                                         "context)");
        return NULL;
    }
    S8Median *excitation = s8_as_median(args[8], "excitation");
    S8Median *inertia = excitation ? s8_as_median(args[9], "inertia") : NULL;
    S8Median *damping = inertia ? s8_as_median(args[10], "damping") : NULL;
    PyObject *ctx = args[11];
    if (damping == NULL) return NULL;
    if (!PyTuple_Check(ctx) || PyTuple_GET_SIZE(ctx) != S8C_SIZE ||
        !PyTuple_Check(PyTuple_GET_ITEM(ctx, S8C_NAMES)) ||
        PyTuple_GET_SIZE(PyTuple_GET_ITEM(ctx, S8C_NAMES)) != S8_FIELDS ||
        !PyTuple_Check(PyTuple_GET_ITEM(ctx, S8C_FLAGS)) ||
        PyTuple_GET_SIZE(PyTuple_GET_ITEM(ctx, S8C_FLAGS)) != 7 ||
        !PyTuple_Check(PyTuple_GET_ITEM(ctx, S8C_HELD)) ||
        !PyTuple_Check(PyTuple_GET_ITEM(ctx, S8C_NEWEST)) ||
        PyTuple_GET_SIZE(PyTuple_GET_ITEM(ctx, S8C_NEWEST)) != 5 ||
        !PyType_Check(PyTuple_GET_ITEM(PyTuple_GET_ITEM(ctx, S8C_NEWEST), 0)) ||
        PyTuple_GET_SIZE(PyTuple_GET_ITEM(ctx, S8C_HELD)) != 3 ||
        !PyType_Check(PyTuple_GET_ITEM(ctx, S8C_CLASS))) {
        PyErr_SetString(PyExc_ValueError, "stream_window: a malformed context");
        return NULL;
    }
    const long k = PyLong_AsLong(PyTuple_GET_ITEM(ctx, S8C_K));
    const double low = PyFloat_AsDouble(PyTuple_GET_ITEM(ctx, S8C_LOW_VAF));
    if (PyErr_Occurred()) return NULL;
    if (k < 0 || k > 2) {
        PyErr_SetString(PyExc_ValueError, "stream_window: k must be 0, 1 or 2");
        return NULL;
    }
    PyObject *held = PyTuple_GET_ITEM(PyTuple_GET_ITEM(ctx, S8C_HELD), k);
    if (!PyTuple_Check(held) || PyTuple_GET_SIZE(held) != 2) {
        PyErr_SetString(PyExc_ValueError, "stream_window: held flags must be pairs");
        return NULL;
    }
    Py_buffer sb, ob;
    if (get_doubles(args[6], &sb, 1, "state") < 0) return NULL;
    if (get_doubles(args[7], &ob, 0, "out") < 0) {
        PyBuffer_Release(&sb);
        return NULL;
    }
    PyObject *result = NULL, *status = NULL, *flags = NULL, *estimate = NULL, *newest = NULL;
    if (sb.len / 8 < 4 || ob.len / 8 != OC_OUT_SIZE) {
        PyErr_SetString(PyExc_ValueError, "stream_window: state or out of the wrong size");
        goto done;
    }
    double *state = sb.buf;
    const double *out = ob.buf;
    double typical;
    state[3] = s8_median_value(excitation, &typical) ? typical : NAN;
    PyObject *call = PyTuple_Pack(7, args[0], args[1], args[2], args[3], args[4], args[5],
                                  args[6]);
    if (call == NULL) goto done;
    status = py_onecall_window(self, call);
    Py_DECREF(call);
    if (status == NULL) goto done;
    if (PyLong_AsLong(status) != OC_DONE) {
        if (!PyErr_Occurred()) {
            Py_INCREF(Py_None);
            result = Py_None;
        }
        goto done;
    }
    s8_median_push(excitation, out[OC_LEVEL]);
    double vafs[3];
    for (int i = 0; i < 3; i++) {
        if (s8_round12(out[OW_VAFS + i], &vafs[i]) < 0) goto done;
    }
    flags = s8_flags(out + OW_PARAMS, out + OW_SE, vafs, low, PyTuple_GET_ITEM(ctx, S8C_FLAGS));
    if (flags == NULL) goto done;
    estimate = s8_estimate(ctx, out + OW_PARAMS, out + OW_SE, vafs, args[3], flags);
    if (estimate == NULL) goto done;
    /* HeldParameters.learn(whole I, whole B, full_fit_explains(whole VAF)) */
    const double whole_vaf = out[OW_WHOLE + 3];
    int explains;
    if (fabs(whole_vaf - low) > 1e-9) {
        explains = whole_vaf >= low;
    } else {
        double rounded;
        if (s8_round12(whole_vaf, &rounded) < 0) goto done;
        explains = rounded >= low;
    }
    const int learned = explains && out[OW_WHOLE] > 0;
    if (learned) {
        s8_median_push(inertia, out[OW_WHOLE]);
        if (out[OW_WHOLE + 1] > 0) s8_median_push(damping, out[OW_WHOLE + 1]);
    }
    if (isnan(out[OW_NEWEST])) {
        Py_INCREF(Py_None);
        newest = Py_None;
    } else {
        newest = s8_newest(PyTuple_GET_ITEM(ctx, S8C_NEWEST), out + OW_NEWEST);
        if (newest == NULL) goto done;
    }
    result = PyTuple_Pack(3, estimate, learned ? Py_True : Py_False, newest);
done:
    Py_XDECREF(status);
    Py_XDECREF(flags);
    Py_XDECREF(estimate);
    Py_XDECREF(newest);
    PyBuffer_Release(&sb);
    PyBuffer_Release(&ob);
    return result;
}

/* tracker_step(tracker, t_s, z, se, newest, split, record) -> TrackEstimate or None:
 * the calm step (section onecall's former tracker_calm) with what it re-did each window taken
 * out. The tracker's and its filters' instance dictionaries are fetched once a call (not once
 * an attribute: ≈ 90 a window), values are read and written in them directly (a name missing from a dictionary
 * declines: the Python step, the reference, runs), a value that did not change is not
 * written again, and the answer is the TrackEstimate record itself, built as records.built
 * builds it (record = (TrackEstimate, its field names, "quiet", "trend", "fast")), instead of
 * a tuple the caller re-packed. The same operations in the same order as the Python step
 * (ParameterTracker.step of a calm window), so the same doubles; tests/ident/test_onecall.py
 * and test_stream8.py hold it to the Python step, state included.
 */
enum { T8_TRACKER, T8_QUIET, T8_TREND, T8_FAST, T8_DICTS };

/* The value of name in dict (borrowed), NULL with *missing set when absent (no error). */
static PyObject *t8_item(PyObject *dict, PyObject *name, int *missing)
{
    PyObject *v = PyDict_GetItemWithError(dict, name);
    if (v == NULL && !PyErr_Occurred()) *missing = 1;
    return v;
}

static int t8_double(PyObject *dict, PyObject *name, double *out, int *missing)
{
    PyObject *v = t8_item(dict, name, missing);
    if (v == NULL) return -1;
    *out = PyFloat_CheckExact(v) ? PyFloat_AS_DOUBLE(v) : PyFloat_AsDouble(v);
    return *out == -1.0 && PyErr_Occurred() ? -1 : 0;
}

/* dict[name] = value, unless value is bit for bit (NaN and -0.0 too) what the call read there
 * at its start (was: no second lookup) */
static int t8_set_double(PyObject *dict, PyObject *name, double value, double was)
{
    if (memcmp(&was, &value, sizeof value) == 0) return 0;
    PyObject *v = PyFloat_FromDouble(value);
    if (v == NULL) return -1;
    int status = PyDict_SetItem(dict, name, v);
    Py_DECREF(v);
    return status;
}

static int t8_set_long(PyObject *dict, PyObject *name, long value)
{
    PyObject *v = PyLong_FromLong(value);
    if (v == NULL) return -1;
    int status = PyDict_SetItem(dict, name, v);
    Py_DECREF(v);
    return status;
}

/* dict[name] = value (a singleton or a new object), unless it holds that object already */
static int t8_set(PyObject *dict, PyObject *name, PyObject *value)
{
    PyObject *old = PyDict_GetItemWithError(dict, name);
    if (old == value) return 0;
    if (old == NULL && PyErr_Occurred()) return -1;
    return PyDict_SetItem(dict, name, value);
}

/* records.built(TrackEstimate, value=..., se=..., rate=..., updated=..., change=False, mode=) */
static PyObject *t8_record(PyObject *record, double value, double se, double rate, int updated,
                           int mode)
{
    PyObject *cls = PyTuple_GET_ITEM(record, 0), *names = PyTuple_GET_ITEM(record, 1);
    PyObject *values[6] = {PyFloat_FromDouble(value), PyFloat_FromDouble(se),
                           PyFloat_FromDouble(rate), NULL, NULL, NULL};
    PyObject *out = NULL, *dict = NULL;
    if (values[0] == NULL || values[1] == NULL || values[2] == NULL) goto done;
    values[3] = updated ? Py_True : Py_False;
    values[4] = Py_False;
    values[5] = PyTuple_GET_ITEM(record, 2 + mode);
    out = PyBaseObject_Type.tp_new((PyTypeObject *)cls, empty_tuple(), NULL);
    if (out == NULL) goto done;
    dict = PyObject_GenericGetDict(out, NULL);
    if (dict == NULL) goto fail;
    for (int i = 0; i < 6; i++) {
        if (PyDict_SetItem(dict, PyTuple_GET_ITEM(names, i), values[i]) < 0) goto fail;
    }
    goto done;
fail:
    Py_CLEAR(out);
done:
    Py_XDECREF(dict);
    for (int i = 0; i < 3; i++) Py_XDECREF(values[i]);
    return out;
}

/* _published(updated, False) of the filters' new values */
static PyObject *t8_published(PyObject *record, int fast_on, const double *quiet,
                              const double *trend, const double *fast, int trending, int updated)
{
    const int use_fast = fast_on && fast != NULL;
    const double *pub = use_fast ? fast : (trending ? trend : quiet);
    const int mode = use_fast ? 2 : (trending ? 1 : 0);
    return t8_record(record, pub[TC_X0], sqrt(tc_max(0.0, pub[TC_P00])), pub[TC_X1], updated,
                     mode);
}

/* A filter's fields from its dictionary, and its cached transition for dt as tc_filter: 1 the
 * last interval's, 2 another seen before (*seen, a new reference), 0 none (or a name missing:
 * *missing). */
static int t8_filter(PyObject *fd, double dt, double *x, double *steps, PyObject **seen,
                     int *missing)
{
    for (int i = 0; i < TC_FIELDS; i++) {
        if (t8_double(fd, tn_filter[i], &x[i], missing) < 0) return *missing ? 0 : -1;
    }
    if (!(dt > 0)) return 1; /* predict() does nothing */
    PyObject *last = t8_item(fd, tn[TN_LAST], missing);
    if (last == NULL) return *missing ? 0 : -1;
    PyObject *cached = NULL;
    int ok = 0;
    if (PyTuple_Check(last) && PyTuple_GET_SIZE(last) == 2 &&
        PyFloat_AsDouble(PyTuple_GET_ITEM(last, 0)) == dt) {
        ok = 1;
        cached = PyTuple_GET_ITEM(last, 1);
    } else if (!PyErr_Occurred()) { /* the intervals seen: _by_dt */
        PyObject *by_dt = t8_item(fd, tn[TN_BY_DT], missing);
        PyObject *key = by_dt != NULL ? PyFloat_FromDouble(dt) : NULL;
        if (key != NULL && PyDict_Check(by_dt)) {
            cached = PyDict_GetItemWithError(by_dt, key);
            if (cached != NULL) {
                ok = 2;
                Py_INCREF(cached);
                *seen = cached;
            }
        }
        Py_XDECREF(key);
    }
    if (ok && PyTuple_Check(cached) && PyTuple_GET_SIZE(cached) == 5) {
        for (int i = 0; i < 5; i++) steps[i] = PyFloat_AsDouble(PyTuple_GET_ITEM(cached, i));
    } else {
        ok = 0;
    }
    return PyErr_Occurred() ? -1 : ok;
}

static PyObject *t8_dict(PyObject *obj)
{
    PyObject *dict = instance_dict(obj);
    if (dict == NULL && !PyErr_Occurred()) {
        PyErr_SetString(PyExc_TypeError, "tracker_step: the tracker and its filters must keep "
                                         "their state in an instance dictionary");
    }
    return dict;
}

static PyObject *py_tracker_step(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError,
                        "tracker_step(tracker, t_s, z, se, newest, split, record)");
        return NULL;
    }
    PyObject *tr = args[0], *zo = args[2], *seo = args[3], *newest = args[4], *split = args[5];
    PyObject *record = args[6];
    const double t_s = PyFloat_AsDouble(args[1]);
    if (t_s == -1.0 && PyErr_Occurred()) return NULL;
    if (!PyTuple_Check(record) || PyTuple_GET_SIZE(record) != 5 ||
        !PyType_Check(PyTuple_GET_ITEM(record, 0)) ||
        !PyTuple_Check(PyTuple_GET_ITEM(record, 1)) ||
        PyTuple_GET_SIZE(PyTuple_GET_ITEM(record, 1)) != 6) {
        PyErr_SetString(PyExc_ValueError, "tracker_step: record must be (TrackEstimate, its six "
                                          "field names, the three modes)");
        return NULL;
    }
    if (tc_names() < 0) return NULL;
    const int given = zo != Py_None && seo != Py_None;
    const double z = given ? PyFloat_AsDouble(zo) : NAN, se = given ? PyFloat_AsDouble(seo) : NAN;
    if (PyErr_Occurred()) return NULL;
    const int usable = given && isfinite(z) && se > 0 && isfinite(se);
    PyObject *dicts[T8_DICTS] = {NULL, NULL, NULL, NULL};
    PyObject *result = NULL, *new_hop_recent = NULL, *new_recent = NULL, *entry = NULL;
    PyObject *seen[3] = {NULL, NULL, NULL}; /* transitions found in _by_dt, for _last */
    int missing = 0, fast_on = -1; /* fast_on -1: the fast filter not stepped */
    double d[TS_DOUBLES];
    long n[TI_INTS];
    PyObject *td = dicts[T8_TRACKER] = t8_dict(tr);
    if (td == NULL) goto done;
    for (int i = 0; i < TS_DOUBLES; i++) {
        if (t8_double(td, tn_double[i], &d[i], &missing) < 0) goto declined;
    }
    for (int i = 0; i < TI_INTS; i++) {
        PyObject *v = t8_item(td, tn_int[i], &missing);
        if (v == NULL) goto declined;
        n[i] = PyLong_AsLong(v);
        if (n[i] == -1 && PyErr_Occurred()) goto done;
    }
    PyObject *flag_items[3] = {t8_item(td, tn[TN_SPLITTING], &missing),
                               t8_item(td, tn[TN_TRENDING], &missing),
                               t8_item(td, tn[TN_FAST_ON], &missing)};
    if (flag_items[0] == NULL || flag_items[1] == NULL || flag_items[2] == NULL) goto declined;
    const int splitting = PyObject_IsTrue(flag_items[0]);
    int trending = PyObject_IsTrue(flag_items[1]);
    const int was_fast_on = PyObject_IsTrue(flag_items[2]);
    if (splitting < 0 || trending < 0 || was_fast_on < 0) goto done;
    if (splitting || n[TI_CHANGE] != 0) goto declined;
    double outlier;
    if (t8_double(td, tn[TN_OUTLIER], &outlier, &missing) < 0) goto declined;
    PyObject *all = t8_item(td, tn[TN_ALL], &missing);
    if (all == NULL) goto declined;
    const Py_ssize_t count = PyTuple_Check(all) ? PyTuple_GET_SIZE(all) : 0;
    if (count < 2 || count > 3) {
        PyErr_SetString(PyExc_ValueError, "tracker_step: the tracker's filters");
        goto done;
    }
    double x[3][TC_FIELDS], read[3][TC_FIELDS], steps[5];
    const double dt = t_s - d[TS_T];
    const double t = t_s > d[TS_T] ? t_s : d[TS_T];
    for (Py_ssize_t i = 0; i < count; i++) {
        PyObject *fd = dicts[T8_QUIET + i] = t8_dict(PyTuple_GET_ITEM(all, i));
        if (fd == NULL) goto done;
        int got = t8_filter(fd, dt, x[i], steps, &seen[i], &missing);
        if (got < 0) goto done;
        if (i == 0 && isnan(x[0][TC_X0])) goto declined; /* not started */
        if (!got) goto declined; /* an interval without its cached transition */
        memcpy(read[i], x[i], sizeof read[i]);
        if (dt > 0) tc_predict(x[i], steps);
    }
    double *quiet = x[0], *trend = x[1], *fast = count == 3 ? x[2] : NULL;
    if (!usable) { /* prediction only: _withheld outside a change mode */
        for (Py_ssize_t i = 0; i < count; i++) {
            for (int j = 0; j < TC_LAG; j++) {
                if (t8_set_double(dicts[T8_QUIET + i], tn_filter[j], x[i][j], read[i][j]) < 0) {
                    goto done;
                }
            }
        }
        if (t8_set_double(td, tn_double[TS_T], t, d[TS_T]) < 0 ||
            t8_set(td, tn[TN_RECENT], empty_tuple()) < 0 ||
            t8_set(td, tn[TN_CANDIDATE], Py_None) < 0) {
            goto done;
        }
        goto remember;
    }
    const long calm_after = n[TI_CALM_AFTER];
    const int calm = calm_after <= 0; /* no change mode, not splitting: checked above */
    const double hop = d[TS_HOP], alpha = d[TS_ALPHA];
    const double near = 1e-9 * tc_max(1.0, t);
    long fast_scored = n[TI_FAST_SCORED], fast_hops = n[TI_FAST_HOPS];
    double fast_cusum = d[TS_FAST_CUSUM], fast_scale2 = d[TS_FAST_SCALE2];
    if (newest != Py_None && fast != NULL) {
        /* _take_newest and _learn_hop_scale */
        double k, var, centre;
        PyObject *nd = instance_dict(newest);
        if (nd == NULL) {
            if (!PyErr_Occurred()) goto declined;
            goto done;
        }
        int bad = t8_double(nd, tn[TN_K], &k, &missing) < 0 ||
                  t8_double(nd, tn[TN_VAR], &var, &missing) < 0 ||
                  t8_double(nd, tn[TN_CENTRE], &centre, &missing) < 0;
        Py_DECREF(nd);
        if (bad) goto declined;
        fast[TC_LAG] = centre;
        const double hop_var = var * se * se;
        double hr[2][3];
        PyObject *hop_recent = t8_item(td, tn[TN_HOP_RECENT], &missing);
        if (hop_recent == NULL) goto declined;
        int nr = tc_recent(hop_recent, hr);
        if (nr < 0) goto declined;
        if (nr && fabs((t - hr[nr - 1][0]) - hop) >= near) nr = 0;
        if (nr == 2 && calm) {
            const double d2 = k - 2.0 * hr[1][1] + hr[0][1];
            const double u = d2 * d2 / (2.0 * (hr[0][2] + hr[1][2] + hop_var));
            fast_scored += 1;
            const double weight = tc_max(alpha, 1.0 / (double)fast_scored);
            const double scale2 = fast_scale2;
            fast_scale2 += weight * (tc_min(u, TC_SCALE_CAP * scale2) - scale2);
        }
        new_hop_recent = tc_pushed(hop_recent, nr, t, k, hop_var);
        if (new_hop_recent == NULL) goto done;
        const double r = fast_scale2 * var * se * se;
        const double c = fast[TC_LAG];
        const double s_f = fast[TC_P00] - 2.0 * c * fast[TC_P01] + c * c * fast[TC_P11] + r;
        const double nu_f = k - (fast[TC_X0] - fast[TC_LAG] * fast[TC_X1]);
        const double nis = nu_f * nu_f / s_f;
        const double *slow = trending ? trend : quiet;
        const double nu_s = k - (slow[TC_X0] - centre * slow[TC_X1]);
        const double spread = -0.5 * log(s_f), half_df = 0.5 * (TC_FAST_DF + 1.0);
        double llr = (spread - half_df * log1p(nis / TC_FAST_DF)) -
                     (spread - half_df * log1p(nu_s * nu_s / s_f / TC_FAST_DF));
        llr = tc_min(TC_FAST_LLR_CAP, tc_max(-TC_FAST_LLR_CAP, llr));
        fast_cusum = tc_max(0.0, d[TS_FORGET] * fast_cusum + llr);
        fast_hops = fast_cusum > d[TS_THRESHOLD] ? fast_hops + 1 : 0;
        const int warm = fast_scored >= TC_FAST_WARM_UP * n[TI_END_HOPS];
        fast_on = warm && fast_hops >= TC_FAST_CONFIRM_HOPS;
        double nu, hph;
        tc_update(fast, k, r + s_f * tc_max(0.0, nis - 1.0) / (TC_FAST_DF + 1.0), &nu, &hph);
    }
    /* _update: _learn_scale, the pre-gate, the gate, _select */
    double scale2 = d[TS_SCALE2];
    double rc[2][3];
    PyObject *recent = t8_item(td, tn[TN_RECENT], &missing);
    if (recent == NULL) goto declined;
    int nrc = tc_recent(recent, rc);
    if (nrc < 0) goto declined;
    if (nrc == 2 && fabs((t - rc[1][0]) - hop) < near) {
        if (calm) {
            const double d2 = z - 2.0 * rc[1][1] + rc[0][1];
            const double var = (rc[0][2] * rc[0][2] + rc[1][2] * rc[1][2] + se * se) / 3.0;
            const double u = d[TS_OVERLAP] * d2 * d2 / (4.0 * var);
            scale2 += alpha * (tc_min(u, TC_SCALE_CAP * scale2) - scale2);
        }
    } else if (nrc && fabs((t - rc[nrc - 1][0]) - hop) >= near) {
        nrc = 0;
    }
    const double sigma2 = scale2 * se * se;
    double se_ref = d[TS_SE_REF];
    const double ref = sqrt(scale2) * se_ref;
    const double departure = z - (trend[TC_X0] - trend[TC_LAG] * trend[TC_X1]);
    const int worth = fabs(departure) > TC_PREGATE * ref || se > TC_SE_SWELL * se_ref;
    if (split != Py_None && worth) { /* the window's splits are read */
        int quiet_scan = tc_no_split(split, sqrt(scale2) * se_ref, d[TS_SPLIT_GATE]);
        if (quiet_scan < 0) goto done;
        if (!quiet_scan) goto declined; /* a significant split: the Python step reads it */
    }
    const double level_before = trending ? trend[TC_X0] : quiet[TC_X0];
    const double u = departure / sqrt(scale2 * pow(se_ref, 2.0));
    if (fabs(u) > d[TS_GATE]) goto declined; /* an outlier or a change: the Python step */
    se_ref += 5.0 * alpha * (se - se_ref);
    const double common = d[TS_OVERLAP] * sigma2;
    double nu_q, hph_q, nu_t, hph_t;
    tc_update(quiet, z, sigma2, &nu_q, &hph_q);
    tc_update(trend, z, sigma2, &nu_t, &hph_t);
    const double s_q = hph_q + common, s_t = hph_t + common;
    const double llr = 0.5 * (nu_q * nu_q / s_q - nu_t * nu_t / s_t) + 0.5 * log(s_q / s_t);
    const double cusum = tc_max(0.0, d[TS_FORGET] * d[TS_CUSUM] + llr);
    trending = cusum > d[TS_THRESHOLD];
    if (trending) { /* quiet.reset(trend.x0, trend.p00) */
        quiet[TC_X0] = trend[TC_X0];
        quiet[TC_X1] = 0.0;
        quiet[TC_P00] = trend[TC_P00];
        quiet[TC_P01] = 0.0;
        quiet[TC_P11] = quiet[TC_RATE_Q] * quiet[TC_RATE_Q] * quiet[TC_TAU] / 2.0;
    }
    new_recent = tc_pushed(recent, nrc, t, z, se);
    entry = Py_BuildValue("(dd)", u, level_before);
    if (new_recent == NULL || entry == NULL) goto done;
    /* calm: write everything back */
    PyObject *history = t8_item(td, tn[TN_HISTORY], &missing);
    if (history == NULL) goto declined;
    PyObject *appended = PyObject_CallMethodOneArg(history, tn[TN_APPEND], entry);
    if (appended == NULL) goto done;
    Py_DECREF(appended);
    for (Py_ssize_t i = 0; i < count; i++) {
        const int fields = i == 2 && fast_on >= 0 ? TC_LAG + 1 : TC_LAG;
        for (int j = 0; j < fields; j++) {
            if (t8_set_double(dicts[T8_QUIET + i], tn_filter[j], x[i][j], read[i][j]) < 0) {
                goto done;
            }
        }
    }
    if (t8_set_double(td, tn_double[TS_T], t, d[TS_T]) < 0 ||
        t8_set_double(td, tn_double[TS_SCALE2], scale2, d[TS_SCALE2]) < 0 ||
        t8_set_double(td, tn_double[TS_SE_REF], se_ref, d[TS_SE_REF]) < 0 ||
        t8_set_double(td, tn_double[TS_CUSUM], cusum, d[TS_CUSUM]) < 0 ||
        t8_set_double(td, tn[TN_OUTLIER], 0.0, outlier) < 0 ||
        t8_set_long(td, tn_int[TI_UPDATES], n[TI_UPDATES] + 1) < 0 ||
        t8_set_long(td, tn_int[TI_CALM_AFTER], calm_after - 1) < 0 ||
        t8_set(td, tn[TN_TRENDING], trending ? Py_True : Py_False) < 0 ||
        t8_set(td, tn[TN_RECENT], new_recent) < 0 ||
        t8_set(td, tn[TN_CANDIDATE], Py_None) < 0) {
        goto done;
    }
    if (fast_on >= 0) {
        if (t8_set_double(td, tn_double[TS_FAST_CUSUM], fast_cusum, d[TS_FAST_CUSUM]) < 0 ||
            t8_set_double(td, tn_double[TS_FAST_SCALE2], fast_scale2, d[TS_FAST_SCALE2]) < 0 ||
            t8_set_long(td, tn_int[TI_FAST_SCORED], fast_scored) < 0 ||
            t8_set_long(td, tn_int[TI_FAST_HOPS], fast_hops) < 0 ||
            t8_set(td, tn[TN_FAST_ON], fast_on ? Py_True : Py_False) < 0 ||
            t8_set(td, tn[TN_HOP_RECENT], new_hop_recent) < 0) {
            goto done;
        }
    }
remember: /* predict() remembers an interval found in _by_dt: _last = (dt, cached) */
    for (Py_ssize_t i = 0; i < count; i++) {
        if (seen[i] == NULL) continue;
        PyObject *last = Py_BuildValue("(dO)", dt, seen[i]);
        if (last == NULL || PyDict_SetItem(dicts[T8_QUIET + i], tn[TN_LAST], last) < 0) {
            Py_XDECREF(last);
            goto done;
        }
        Py_DECREF(last);
    }
    result = t8_published(record, fast_on >= 0 ? fast_on : was_fast_on, quiet, trend, fast,
                          trending, usable);
    goto done;
declined:
    if (!PyErr_Occurred()) {
        Py_INCREF(Py_None);
        result = Py_None;
    }
done:
    for (int i = 0; i < 3; i++) Py_XDECREF(seen[i]);
    for (int i = 0; i < T8_DICTS; i++) Py_XDECREF(dicts[i]);
    Py_XDECREF(new_hop_recent);
    Py_XDECREF(new_recent);
    Py_XDECREF(entry);
    return result;
}
