/*
 * EUREKA (Wiggins & Robinson 1965; Levinson 1947) for a symmetric Toeplitz system R x = b.
 *
 * Compiled kernel behind rtsid.ident.levinson.eureka; the pure-numpy version in levinson.py
 * is the reference and the fallback when this module cannot be built. Only the buffer
 * protocol is used (no numpy headers). The GIL is released only for large systems: for the
 * small per-window systems, handing it over costs the caller a switch interval.
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

/* Release the GIL only for systems this large (≈ 1 ms and up); shorter calls keep it so that
 * a latency-critical caller does not wait a whole switch interval to get it back. */
#define RELEASE_GIL_ABOVE 1000

static double dot_unrolled(const double *u, const double *v, Py_ssize_t n)
{
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
static void detrend_into(const double *x, double *out, Py_ssize_t n, double sign, int kind)
{
    double mean = 0.0, slope = 0.0, tt = 0.0, tx = 0.0;
    const double centre = (double)(n - 1) / 2.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        mean += sign * x[i];
    }
    mean /= (double)n;
    if (kind == 2) {
        for (Py_ssize_t i = 0; i < n; i++) {
            double t = (double)i - centre;
            tt += t * t;
            tx += t * sign * x[i];
        }
        slope = tt > 0.0 ? tx / tt : 0.0;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        double v = sign * x[i];
        if (kind >= 1) v -= mean;
        if (kind == 2) v -= slope * ((double)i - centre);
        out[i] = v;
    }
}

static void fir_decimate(const double *x, Py_ssize_t n, const double *taps, Py_ssize_t nt,
                         Py_ssize_t factor, double *out, Py_ssize_t m)
{
    for (Py_ssize_t k = 0; k < m; k++) {
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

static Py_ssize_t window_irf(const double *pos, const double *trq, Py_ssize_t n,
                             const double *taps, Py_ssize_t nt, Py_ssize_t factor, double sign,
                             int kind, Py_ssize_t lag, double ridge, Py_ssize_t sweeps,
                             double fs, double *u, double *y, Py_ssize_t m, double *h,
                             double *phi, double *work, double *alpha)
{
    const Py_ssize_t nh = 2 * lag + 1;
    double *dp = work, *dt = work + n;              /* detrended, n each */
    double *a = dt + n, *rr = a + nh;               /* Levinson scratch, nh each */
    double *g = rr + nh, *delta = g + nh;           /* gradient and update, nh each */
    double *err = delta + nh;                        /* residual, m */
    detrend_into(pos, dp, n, 1.0, kind);
    detrend_into(trq, dt, n, sign, kind);
    fir_decimate(dp, n, taps, nt, factor, u, m);
    fir_decimate(dt, n, taps, nt, factor, y, m);
    xcorr(u, u, m, 0, nh - 1, (double)m, phi);
    const double loading = ridge * phi[0];
    phi[0] += loading;
    /* phi_uy(k) = sum_t u(t-k) y(t) / m  =  sum_s u(s) y(s+k) / m */
    xcorr(u, y, m, -lag, lag, (double)m, g);
    Py_ssize_t status = eureka_solve(phi, g, h, a, rr, nh, alpha);
    if (status >= 0) return status;
    for (Py_ssize_t k = 0; k < nh; k++) h[k] *= fs;
    const Py_ssize_t inner = m - 2 * lag;
    for (Py_ssize_t s = 0; s < sweeps; s++) {
        for (Py_ssize_t t = lag; t < m - lag; t++) {
            double pred = 0.0;
            for (Py_ssize_t j = 0; j < nh; j++) {
                pred += h[j] * u[t - (j - lag)];
            }
            err[t] = y[t] - pred / fs;
        }
        for (Py_ssize_t j = 0; j < nh; j++) {
            Py_ssize_t k = j - lag;
            double acc = 0.0;
            for (Py_ssize_t t = lag; t < m - lag; t++) {
                acc += u[t - k] * err[t];
            }
            g[j] = acc / (double)inner - loading * h[j] / fs;
        }
        status = eureka_solve(phi, g, delta, a, rr, nh, alpha);
        if (status >= 0) return status;
        for (Py_ssize_t j = 0; j < nh; j++) h[j] += delta[j] * fs;
    }
    return -1;
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
            double *work = PyMem_Malloc(sizeof(double) * (2 * n + 4 * nh + m));
            if (work == NULL) {
                PyErr_NoMemory();
            } else {
                double alpha = 0.0;
                Py_ssize_t status;
                /* Short (tens of µs): keep the GIL. Releasing it would let another thread
                 * take it for a whole switch interval before this one gets it back. */
                status = window_irf(b[0].buf, b[1].buf, n, b[2].buf, nt, factor, sign, kind, lag,
                                    ridge, sweeps, fs, b[3].buf, b[4].buf, m, b[5].buf,
                                    b[6].buf, work, &alpha);
                PyMem_Free(work);
                result = Py_BuildValue("nd", status, alpha);
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

static PyMethodDef methods[] = {
    {"solve", py_solve, METH_VARARGS,
     "solve(r, b, x, work) -> (status, alpha): symmetric Toeplitz R x = b by EUREKA."},
    {"window_irf", py_window_irf, METH_VARARGS,
     "window_irf(position, torque, taps, factor, sign, detrend, lag, sweeps, ridge, fs, u, y, h, "
     "phi) -> (status, alpha): detrend, FIR-decimate, correlate, EUREKA and refine one window."},
    {"xcorr", py_xcorr, METH_VARARGS,
     "xcorr(u, y, first, last, norm, c): c[k-first] = sum_t u[t] y[t+k] / norm."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_eureka", "Compiled EUREKA / Levinson kernel.", -1, methods,
};

PyMODINIT_FUNC PyInit__eureka(void)
{
    return PyModule_Create(&module);
}
