/* One pair from Python without the numba dispatcher (issue 17: <= 0.8 us).
 *
 * Why C: numba's dispatcher alone, called with the pair's 15 (2-D) floats,
 * costs ~2x a trivial jitted call (bench/bench_core.py --one-pair, same run),
 * and with the Python wrapper and the 0-d result array on top no numba entry
 * got under 0.8 us (the previous one took 3.4-3.8 us; see narrow_one_pair.py).  Here the sequences are read with the CPython API and the
 * certified kernels (narrow_phase._certified_pair2/3, compiled by numba as
 * cfuncs: the same compiled code as the numba entry points) are called
 * through their addresses.
 *
 * ttc(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, horizon) returns a
 * numpy.float64, or None when this path does not apply -- the caller then takes the
 * general path, which decides or raises its message:
 *   - a vector that is not a list, tuple or 1-D float64 array (native byte
 *     order) of length 2 or 3, or lengths that differ;
 *   - an element or scalar that is not a float (or subclass, e.g.
 *     numpy.float64) or an int (exactly, no bool);
 *   - a row the certified kernels leave undecided (exact path).
 * Invalid values (NaN, inf, negative radius or horizon) are decided by the
 * kernels like in a batch: NaN.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <string.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
#include <numpy/arrayscalars.h>

typedef double (*kernel_t)(const double *);

static kernel_t kernels[4]; /* by dimension: kernels[2], kernels[3] */

#define UNDECIDED (-1.0) /* narrow_eval.UNDECIDED */

/* 1: *x set; 0: not a number this path takes */
static int read_num(PyObject *o, double *x)
{
    if (PyFloat_Check(o)) {
        *x = PyFloat_AS_DOUBLE(o);
        return 1;
    }
    if (PyLong_CheckExact(o)) {
        *x = PyLong_AsDouble(o); /* correctly rounded, as numpy converts */
        if (*x == -1.0 && PyErr_Occurred()) {
            PyErr_Clear(); /* too large: the general path decides */
            return 0;
        }
        return 1;
    }
    return 0;
}

/* 1: out[0..D) set (D fixed by the first vector); 0: not for this path */
static int read_vec(PyObject *o, double *out, Py_ssize_t *D)
{
    Py_ssize_t n, i;
    if (PyList_CheckExact(o) || PyTuple_CheckExact(o)) {
        PyObject **items;
        n = PySequence_Fast_GET_SIZE(o);
        if ((n != 2 && n != 3) || (*D && n != *D))
            return 0;
        items = PySequence_Fast_ITEMS(o);
        for (i = 0; i < n; i++)
            if (!read_num(items[i], out + i))
                return 0;
    }
    else if (PyArray_CheckExact(o)) {
        PyArrayObject *a = (PyArrayObject *)o;
        const char *p;
        npy_intp s;
        if (PyArray_NDIM(a) != 1 || PyArray_TYPE(a) != NPY_DOUBLE || !PyArray_ISNOTSWAPPED(a))
            return 0;
        n = PyArray_DIM(a, 0);
        if ((n != 2 && n != 3) || (*D && n != *D))
            return 0;
        p = PyArray_BYTES(a);
        s = PyArray_STRIDE(a, 0);
        for (i = 0; i < n; i++)
            memcpy(out + i, p + i * s, sizeof(double));
    }
    else
        return 0;
    *D = n;
    return 1;
}

static PyObject *ttc(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    double v[6][3], ra, rb, h, x[21], t;
    Py_ssize_t D = 0;
    int k, j, m = 0;
    PyObject *res;
    static const int vec_arg[6] = {0, 1, 2, 4, 5, 6};
    if (nargs != 9) {
        PyErr_SetString(PyExc_TypeError, "ttc() takes 9 arguments");
        return NULL;
    }
    for (k = 0; k < 6; k++)
        if (!read_vec(args[vec_arg[k]], v[k], &D))
            Py_RETURN_NONE;
    if (!read_num(args[3], &ra) || !read_num(args[7], &rb) || !read_num(args[8], &h) || !kernels[D])
        Py_RETURN_NONE;
    /* argument order of _certified_pair2/3: p_a v_a a_a r_a p_b v_b a_b r_b H */
    for (k = 0; k < 6; k++) {
        for (j = 0; j < D; j++)
            x[m++] = v[k][j];
        if (k == 2)
            x[m++] = ra;
        else if (k == 5)
            x[m++] = rb;
    }
    x[m] = h;
    t = kernels[D](x);
    if (t == UNDECIDED)
        Py_RETURN_NONE;
    /* numpy.float64, as numpy returns for a 0-d result: a 0-d array would
     * cost ~0.4 us more (measured: 0.87x vs 0.35x a trivial jitted call for
     * a C call returning either) */
    res = PyArrayScalar_New(Double);
    if (res == NULL)
        return NULL;
    PyArrayScalar_ASSIGN(res, Double, t);
    return res;
}

static PyObject *set_kernels(PyObject *self, PyObject *args)
{
    PyObject *a2, *a3;
    void *p2, *p3;
    if (!PyArg_ParseTuple(args, "OO", &a2, &a3))
        return NULL;
    p2 = PyLong_AsVoidPtr(a2);
    if (p2 == NULL && PyErr_Occurred())
        return NULL;
    p3 = PyLong_AsVoidPtr(a3);
    if (p3 == NULL && PyErr_Occurred())
        return NULL;
    kernels[2] = (kernel_t)p2;
    kernels[3] = (kernel_t)p3;
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"ttc", (PyCFunction)(void (*)(void))ttc, METH_FASTCALL,
     "ttc(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b, horizon): first-contact time of one pair "
     "as a numpy.float64, or None where the general path must decide."},
    {"set_kernels", set_kernels, METH_VARARGS,
     "set_kernels(addr2, addr3): addresses of the certified 2-D / 3-D cfunc kernels "
     "(double (*)(const double *))."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_one_pair",
                                    "One-pair entry of the narrow phase (see _one_pair.c).", -1,
                                    methods};

PyMODINIT_FUNC PyInit__one_pair(void)
{
    import_array();
    return PyModule_Create(&module);
}
