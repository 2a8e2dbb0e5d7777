/* Ouster XYZ from a lookup table (ouster-sdk's XYZLut: direction and offset per pixel). */
#include "common.h"

/* One return slot: out[i, k] = range[i] * dir[k, i] + off[k, i], +0.0 where range[i] is 0, in the
 * precision of T (float64: ouster-sdk's XYZLut; float32: its XYZLutFloat, whose table is the float64
 * one rounded to float32 and whose products and sums are float32). */
/* uint32 -> float64 / float32, exactly as the C conversion rounds, from signed 32-bit conversions (x86
 * has no vector conversion of unsigned integers before AVX-512, and with (T)v gcc leaves the loop
 * scalar): float64, v - 2^31 converted and 2^31 added back, both exact; float32, the high and low 16
 * bits converted exactly and summed with one rounding. */
static inline double u32_to_f64(uint32_t v) { return (double)(int32_t)(v ^ 0x80000000u) + 2147483648.0; }
static inline float u32_to_f32(uint32_t v) { return (float)(int32_t)(v >> 16) * 65536.0f + (float)(int32_t)(v & 0xFFFFu); }

/* The loop has no branch, so that gcc vectorises it: a pixel without a return is zeroed by AND-ing the
 * bits of its coordinates with an all-zeros mask (+0.0 exactly), as the NumPy twin does. */
#define XYZ_LUT_ROWS(NAME, T, BITS, TO_T)                                                                         \
    MULTIVERSION                                                                                                  \
    static void NAME(const uint32_t *restrict range, const T *restrict dir, const T *restrict off,                \
                     BITS *restrict out, Py_ssize_t hw) {                                                         \
        const T *dx = dir, *dy = dir + hw, *dz = dir + 2 * hw;                                                    \
        const T *ox = off, *oy = off + hw, *oz = off + 2 * hw;                                                    \
        for (Py_ssize_t i = 0; i < hw; i++) {                                                                     \
            uint32_t v = range[i];                                                                                \
            T s = TO_T(v);                                                                                        \
            T x = s * dx[i] + ox[i], y = s * dy[i] + oy[i], z = s * dz[i] + oz[i];                                \
            BITS keep = (BITS)0 - (BITS)(v != 0), bx, by, bz;                                                     \
            memcpy(&bx, &x, sizeof x);                                                                            \
            memcpy(&by, &y, sizeof y);                                                                            \
            memcpy(&bz, &z, sizeof z);                                                                            \
            out[3 * i] = bx & keep;                                                                               \
            out[3 * i + 1] = by & keep;                                                                           \
            out[3 * i + 2] = bz & keep;                                                                           \
        }                                                                                                         \
    }

XYZ_LUT_ROWS(xyz_lut_rows_f64, double, uint64_t, u32_to_f64)
XYZ_LUT_ROWS(xyz_lut_rows_f32, float, uint32_t, u32_to_f32)

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
                             (uint64_t *)xb->buf + r * hw * 3, hw);
        else
            xyz_lut_rows_f32(range + r * hw, (const float *)db->buf, (const float *)ob->buf,
                             (uint32_t *)xb->buf + r * hw * 3, hw);
    }
    Py_END_ALLOW_THREADS
    Py_INCREF(Py_None);
    return release_buffers(b, got, Py_None);
}
