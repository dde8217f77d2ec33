/*
 * EUREKA (Wiggins & Robinson 1965; Levinson 1947) for a symmetric Toeplitz system R x = b.
 *
 * Compiled kernel behind rtsid.ident.levinson.eureka; the pure-numpy version in levinson.py
 * is the reference and the fallback when this module cannot be built. Only the buffer
 * protocol is used (no numpy headers), and the GIL is released during the recursion so the
 * acquisition thread keeps running while a window is solved.
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
        Py_BEGIN_ALLOW_THREADS
        status = eureka_solve((const double *)r.buf, (const double *)b.buf, (double *)x.buf,
                              work, work + n, n, &alpha);
        Py_END_ALLOW_THREADS
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
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_eureka", "Compiled EUREKA / Levinson kernel.", -1, methods,
};

PyMODINIT_FUNC PyInit__eureka(void)
{
    return PyModule_Create(&module);
}
