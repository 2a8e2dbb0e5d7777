/* Ouster XYZ from a lookup table (ouster-sdk's XYZLut: direction and offset per pixel). */
#include "common.h"

/* One return slot: out[i, k] = range[i] * dir[k, i] + off[k, i], +0.0 where range[i] is 0, in the
 * precision of T (float64: ouster-sdk's XYZLut; float32: its XYZLutFloat, whose table is the float64
 * one rounded to float32 and whose products and sums are float32). */
#define XYZ_LUT_ROWS(NAME, T)                                                                                     \
    MULTIVERSION                                                                                                  \
    static void NAME(const uint32_t *restrict range, const T *restrict dir, const T *restrict off,                \
                     T *restrict out, Py_ssize_t hw) {                                                            \
        const T *dx = dir, *dy = dir + hw, *dz = dir + 2 * hw;                                                    \
        const T *ox = off, *oy = off + hw, *oz = off + 2 * hw;                                                    \
        for (Py_ssize_t i = 0; i < hw; i++) {                                                                     \
            uint32_t v = range[i];                                                                                \
            T s = (T)v;                                                                                           \
            /* computed for every pixel and then selected, so that the loop vectorises */                        \
            T x = s * dx[i] + ox[i], y = s * dy[i] + oy[i], z = s * dz[i] + oz[i];                                \
            out[3 * i] = v ? x : (T)0;                                                                            \
            out[3 * i + 1] = v ? y : (T)0;                                                                        \
            out[3 * i + 2] = v ? z : (T)0;                                                                        \
        }                                                                                                         \
    }

XYZ_LUT_ROWS(xyz_lut_rows_f64, double)
XYZ_LUT_ROWS(xyz_lut_rows_f32, float)

/* xyz_lut(range, direction, offset, out)
 *
 * range: uint32 [R, H*W]; direction, offset: [3, H*W]; out: [R, H*W, 3], all C-contiguous, the last
 * three all float64 or all float32. out[r, i, k] = range[r, i] * direction[k, i] + offset[k, i], +0.0
 * where the range is 0: the same two roundings as NumPy's multiply-then-add in that precision (and
 * ouster-sdk's XYZLut / XYZLutFloat).
 */
PyObject *lp_xyz_lut(PyObject *self, PyObject *args) {
    PyObject *r_obj, *d_obj, *o_obj, *x_obj;
    if (!PyArg_ParseTuple(args, "OOOO", &r_obj, &d_obj, &o_obj, &x_obj)) return NULL;
    Py_buffer b[4];
    int got = 0;
    if (get_buffer(r_obj, &b[got], PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 4, "xyz_lut range") < 0)
        return release_buffers(b, got, NULL);
    got++;
    PyObject *objs[3] = {d_obj, o_obj, x_obj};
    for (int i = 0; i < 3; i++) {
        if (PyObject_GetBuffer(objs[i], &b[got], (i == 2 ? PyBUF_WRITABLE : 0) | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
            return release_buffers(b, got, NULL);
        got++;
    }
    Py_buffer *rb = &b[0], *db = &b[1], *ob = &b[2], *xb = &b[3];
    Py_ssize_t item = db->itemsize, hw = item > 0 ? db->len / (3 * item) : 0;
    const char *code = item == 8 ? "d" : "f";
    if ((item != 8 && item != 4) || ob->itemsize != item || xb->itemsize != item || db->len != ob->len || hw == 0 ||
        (rb->len / 4) % hw != 0 || xb->len != (rb->len / 4) * 3 * item || !is_native(rb->format, "IL") ||
        !is_native(db->format, code) || !is_native(ob->format, code) || !is_native(xb->format, code)) {
        PyErr_SetString(PyExc_ValueError, "xyz_lut: range must be uint32 and direction, offset, out all float64 or all "
                                          "float32, of agreeing sizes");
        return release_buffers(b, got, NULL);
    }
    Py_ssize_t returns = (rb->len / 4) / hw;
    const uint32_t *range = (const uint32_t *)rb->buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t r = 0; r < returns; r++) {
        if (item == 8)
            xyz_lut_rows_f64(range + r * hw, (const double *)db->buf, (const double *)ob->buf,
                             (double *)xb->buf + r * hw * 3, hw);
        else
            xyz_lut_rows_f32(range + r * hw, (const float *)db->buf, (const float *)ob->buf,
                             (float *)xb->buf + r * hw * 3, hw);
    }
    Py_END_ALLOW_THREADS
    Py_INCREF(Py_None);
    return release_buffers(b, got, Py_None);
}
