/* The public time_to_collision: a C function that answers one pair itself
 * and hands every other call to the general path (one pair from Python without the
 * batch entry's array set-up).
 *
 * Why C, and why the public callable itself: measured in one run
 * (bench/bench_core.py --one-pair), numba's dispatcher alone, called with the
 * pair's 15 (2-D) floats, costs ~2x a trivial jitted call, and a Python
 * function in front of a C entry cost ~0.3 us of the ~1.1 us per call (its
 * frame, the keyword `horizon`, the second call); see one_pair.py.
 * So the public name is bound to a builtin function made here
 * (METH_FASTCALL | METH_KEYWORDS: CPython's vectorcall, no argument tuple
 * or dict), which reads the sequences with the CPython API and calls the
 * certified kernels (batch.certified_pair2/3, compiled by numba as
 * cfuncs: the same compiled code as the numba entry points) through their
 * addresses.
 *
 * It answers itself (same bits as the batch: the batch runs the same
 * kernels on the row, then the exact path for what they leave undecided):
 *   time_to_collision(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b[, horizon])
 * with horizon positional or the keyword `horizon`, each vector a list or
 * tuple of D numbers, a 1-D float64 ndarray of length D or a (1, D) float64
 * ndarray (native byte order, any strides), D = 2 or 3 for all; each
 * radius and the horizon a float (or subclass, e.g. numpy.float64), an int
 * (exactly: no bool) or a (1,) float64 ndarray; numbers: a float or an int.
 * The result is a numpy.float64 (numpy's type for a 0-d result) or, when an
 * argument has the batch shape (1,), a float64 array of shape (1,) -- what
 * the general path returns for these shapes.
 *
 * Everything else goes to the general path unchanged (same positional and
 * keyword arguments): other types or shapes (which it converts or rejects
 * with a message naming the argument), and rows the certified kernels leave
 * undecided (its exact decision).  Invalid values (NaN, inf, a negative
 * radius or horizon) are decided by the kernels as in a batch: NaN.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <string.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>
#include <numpy/arrayscalars.h>

typedef double (*kernel_t)(const double *);

static kernel_t kernels[4];      /* by dimension: kernels[2], kernels[3] */
static PyObject *general_path;   /* batch's Python time_to_collision */
static PyObject *kernel_loader;  /* called once, before the first pair: installs the kernels */
static PyObject *horizon_name;   /* interned "horizon" */

#define UNDECIDED (-1.0) /* evaluate.UNDECIDED */

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

/* A float64 ndarray in native byte order (exact type: no subclass, whose
 * __array_finalize__ etc. the general path must honour). */
static int is_f8_array(PyObject *o)
{
    return PyArray_CheckExact(o) && PyArray_TYPE((PyArrayObject *)o) == NPY_DOUBLE
           && PyArray_ISNOTSWAPPED((PyArrayObject *)o);
}

/* A number, or a (1,) float64 array (sets *batch1): 1 with *x set; 0: not
 * for this path. */
static int read_scalar(PyObject *o, double *x, int *batch1)
{
    if (read_num(o, x))
        return 1;
    if (is_f8_array(o) && PyArray_NDIM((PyArrayObject *)o) == 1
        && PyArray_DIM((PyArrayObject *)o, 0) == 1) {
        memcpy(x, PyArray_BYTES((PyArrayObject *)o), sizeof(double));
        *batch1 = 1;
        return 1;
    }
    return 0;
}

/* 1: out[0..D) set (D fixed by the first vector; a (1, D) array sets
 * *batch1); 0: not for this path */
static int read_vec(PyObject *o, double *out, Py_ssize_t *D, int *batch1)
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
    else if (is_f8_array(o)) {
        PyArrayObject *a = (PyArrayObject *)o;
        int nd = PyArray_NDIM(a);
        const char *p;
        npy_intp s;
        if (nd == 2 && PyArray_DIM(a, 0) == 1)
            *batch1 = 1;
        else if (nd != 1)
            return 0;
        n = PyArray_DIM(a, nd - 1);
        if ((n != 2 && n != 3) || (*D && n != *D))
            return 0;
        p = PyArray_BYTES(a);
        s = PyArray_STRIDE(a, nd - 1);
        for (i = 0; i < n; i++)
            memcpy(out + i, p + i * s, sizeof(double));
    }
    else
        return 0;
    *D = n;
    return 1;
}

/* The first-contact time of the pair in args (p_a v_a a_a r_a p_b v_b a_b
 * r_b, horizon in hz, NULL: inf), or Py_None (not a new reference, never
 * returned to Python) where the general path must decide. */
static PyObject *one_pair(PyObject *const *args, PyObject *hz)
{
    double v[6][3], ra, rb, h = Py_HUGE_VAL, x[21], t;
    Py_ssize_t D = 0;
    int k, j, m = 0, batch1 = 0;
    static const int vec_arg[6] = {0, 1, 2, 4, 5, 6};
    for (k = 0; k < 6; k++)
        if (!read_vec(args[vec_arg[k]], v[k], &D, &batch1))
            return Py_None;
    if (!read_scalar(args[3], &ra, &batch1) || !read_scalar(args[7], &rb, &batch1)
        || (hz != NULL && !read_scalar(hz, &h, &batch1)))
        return Py_None;
    if (!kernels[D]) {
        if (kernel_loader == NULL)
            return Py_None; /* the loader failed before: the general path */
        PyObject *loader = kernel_loader, *r;
        kernel_loader = NULL; /* once, even if it fails (it raised then) */
        r = PyObject_CallNoArgs(loader);
        Py_DECREF(loader);
        if (r == NULL)
            return NULL;
        Py_DECREF(r);
        if (!kernels[D])
            return Py_None;
    }
    /* argument order of certified_pair2/3: p_a v_a a_a r_a p_b v_b a_b r_b H */
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
        return Py_None;
    if (batch1) {
        npy_intp one = 1;
        PyObject *res = PyArray_SimpleNew(1, &one, NPY_DOUBLE);
        if (res != NULL)
            *(double *)PyArray_DATA((PyArrayObject *)res) = t;
        return res;
    }
    else {
        /* numpy.float64, as numpy returns for a 0-d result: a 0-d array
         * would cost ~0.4 us more (measured: 0.87x vs 0.35x a trivial jitted
         * call for a C call returning either) */
        PyObject *res = PyArrayScalar_New(Double);
        if (res != NULL)
            PyArrayScalar_ASSIGN(res, Double, t);
        return res;
    }
}

static PyObject *entry(PyObject *self, PyObject *const *args, Py_ssize_t nargs, PyObject *kwnames)
{
    PyObject *hz = NULL, *res;
    if (kwnames == NULL || PyTuple_GET_SIZE(kwnames) == 0) {
        if (nargs == 9)
            hz = args[8];
        else if (nargs != 8)
            goto general;
    }
    else {
        PyObject *key = PyTuple_GET_ITEM(kwnames, 0);
        if (nargs != 8 || PyTuple_GET_SIZE(kwnames) != 1
            || (key != horizon_name && PyUnicode_Compare(key, horizon_name) != 0))
            goto general;
        hz = args[8];
    }
    res = one_pair(args, hz);
    if (res != Py_None)
        return res; /* the answer, or NULL with the loader's exception */
general:
    if (general_path == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "time_to_collision: general path not registered");
        return NULL;
    }
    return PyObject_Vectorcall(general_path, args, nargs, kwnames);
}

static PyMethodDef entry_def = {"time_to_collision", (PyCFunction)(void (*)(void))entry,
                                METH_FASTCALL | METH_KEYWORDS, NULL};

static PyObject *make_entry(PyObject *self, PyObject *args)
{
    PyObject *general, *loader, *module_name;
    const char *doc;
    Py_ssize_t len;
    char *copy;
    if (!PyArg_ParseTuple(args, "OOs#U", &general, &loader, &doc, &len, &module_name))
        return NULL;
    if (!PyCallable_Check(general) || !PyCallable_Check(loader)) {
        PyErr_SetString(PyExc_TypeError, "make_entry: general path and loader must be callable");
        return NULL;
    }
    if (general_path != NULL) {
        PyErr_SetString(PyExc_RuntimeError, "make_entry: the entry exists already (one per process)");
        return NULL;
    }
    /* the docstring lives as long as the function (for ever: kept in a
     * module global) */
    copy = PyMem_RawMalloc(len + 1);
    if (copy == NULL)
        return PyErr_NoMemory();
    memcpy(copy, doc, len + 1);
    entry_def.ml_doc = copy;
    Py_INCREF(general);
    general_path = general;
    Py_INCREF(loader);
    kernel_loader = loader;
    return PyCFunction_NewEx(&entry_def, NULL, module_name);
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

/* The one-pair answer without the general path behind it (tests: proof
 * that the C path, not the general one, answers a call): the result, or
 * None where the general path would decide. */
static PyObject *c_path(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    PyObject *res;
    if (nargs != 8 && nargs != 9) {
        PyErr_SetString(PyExc_TypeError, "c_path() takes 8 or 9 arguments");
        return NULL;
    }
    res = one_pair(args, nargs == 9 ? args[8] : NULL);
    if (res == Py_None)
        Py_RETURN_NONE;
    return res;
}

static PyMethodDef methods[] = {
    {"make_entry", make_entry, METH_VARARGS,
     "make_entry(general, loader, doc, module) -> the public time_to_collision: a builtin "
     "function answering one pair itself and calling general(*args, **kwargs) for the rest; "
     "loader() runs once before the first pair and must call set_kernels."},
    {"set_kernels", set_kernels, METH_VARARGS,
     "set_kernels(addr2, addr3): addresses of the certified 2-D / 3-D cfunc kernels "
     "(double (*)(const double *))."},
    {"c_path", (PyCFunction)(void (*)(void))c_path, METH_FASTCALL,
     "c_path(p_a, v_a, a_a, r_a, p_b, v_b, a_b, r_b[, horizon]): the C path's answer, or None "
     "where the general path would decide."},
    {NULL, NULL, 0, NULL}};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "one_pair_entry",
                                    "The public time_to_collision's C entry (see one_pair_entry.c).", -1,
                                    methods};

PyMODINIT_FUNC PyInit_one_pair_entry(void)
{
    import_array();
    horizon_name = PyUnicode_InternFromString("horizon");
    if (horizon_name == NULL)
        return NULL;
    return PyModule_Create(&module);
}
