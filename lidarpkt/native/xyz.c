/* Ouster XYZ from a lookup table (ouster-sdk's XYZLut: direction and offset per pixel). */
#include "common.h"

/* One return slot: out[i, k] = range[i] * dir[k, i] + off[k, i], +0.0 where range[i] is 0. */
MULTIVERSION
static void xyz_lut_rows(const uint32_t *restrict range, const double *restrict dir, const double *restrict off,
                         double *restrict out, Py_ssize_t hw) {
    const double *dx = dir, *dy = dir + hw, *dz = dir + 2 * hw;
    const double *ox = off, *oy = off + hw, *oz = off + 2 * hw;
    for (Py_ssize_t i = 0; i < hw; i++) {
        uint32_t v = range[i];
        double s = (double)v;
        /* computed for every pixel and then selected, so that the loop vectorises */
        double x = s * dx[i] + ox[i], y = s * dy[i] + oy[i], z = s * dz[i] + oz[i];
        out[3 * i] = v ? x : 0.0;
        out[3 * i + 1] = v ? y : 0.0;
        out[3 * i + 2] = v ? z : 0.0;
    }
}

/* xyz_lut(range, direction, offset, out)
 *
 * range: uint32 [R, H*W]; direction, offset: float64 [3, H*W]; out: float64 [R, H*W, 3], all
 * C-contiguous.  out[r, i, k] = range[r, i] * direction[k, i] + offset[k, i], +0.0 where the
 * range is 0: the same two roundings as NumPy's multiply-then-add (and ouster-sdk's XYZLut).
 */
PyObject *lp_xyz_lut(PyObject *self, PyObject *args) {
    PyObject *r_obj, *d_obj, *o_obj, *x_obj;
    if (!PyArg_ParseTuple(args, "OOOO", &r_obj, &d_obj, &o_obj, &x_obj)) return NULL;
    Py_buffer rb, db, ob, xb;
    if (get_buffer(r_obj, &rb, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 4, "xyz_lut range") < 0) return NULL;
    if (get_buffer(d_obj, &db, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 8, "xyz_lut direction") < 0) {
        PyBuffer_Release(&rb);
        return NULL;
    }
    if (get_buffer(o_obj, &ob, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 8, "xyz_lut offset") < 0) {
        PyBuffer_Release(&rb);
        PyBuffer_Release(&db);
        return NULL;
    }
    if (get_buffer(x_obj, &xb, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 8, "xyz_lut out") < 0) {
        PyBuffer_Release(&rb);
        PyBuffer_Release(&db);
        PyBuffer_Release(&ob);
        return NULL;
    }
    PyObject *result = NULL;
    Py_ssize_t hw = db.len / 24;
    if (db.len != ob.len || hw == 0 || (rb.len / 4) % hw != 0 || xb.len != (rb.len / 4) * 24 ||
        !is_native(rb.format, "IL") || !is_native(db.format, "d") || !is_native(ob.format, "d") ||
        !is_native(xb.format, "d")) {
        PyErr_SetString(PyExc_ValueError, "xyz_lut: range must be uint32 and direction, offset, out float64, of "
                                          "agreeing sizes");
        goto done;
    }
    {
        Py_ssize_t returns = (rb.len / 4) / hw;
        const uint32_t *range = (const uint32_t *)rb.buf;
        const double *dir = (const double *)db.buf, *off = (const double *)ob.buf;
        double *out = (double *)xb.buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t r = 0; r < returns; r++) xyz_lut_rows(range + r * hw, dir, off, out + r * hw * 3, hw);
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;
done:
    PyBuffer_Release(&rb);
    PyBuffer_Release(&db);
    PyBuffer_Release(&ob);
    PyBuffer_Release(&xb);
    return result;
}
