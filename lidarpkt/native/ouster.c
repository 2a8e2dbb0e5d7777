/* Ouster: the pixels of lidar packets scattered straight into a frame's [H, W] field arrays.
 *
 * A packet holds C columns, each of H pixels of `pixel_bytes` (column-major on the wire); a frame's
 * field arrays are row-major [H, W]. The NumPy twin (lidarpkt/ouster/frames.py) transposes the
 * pixel words into word planes [words, H, W] and then extracts each field from its plane; this
 * kernel does both in one pass, so no plane is written or read again.
 */
#include "common.h"

/* The pixel word at p (little-endian on the wire). */
static inline uint32_t load_le32(const unsigned char *p) {
    uint32_t v;
    memcpy(&v, p, 4);
#if !PY_LITTLE_ENDIAN
    v = bswap32(v);
#endif
    return v;
}

/* How a field is read from its pixel word, chosen once per call (fewer instructions per pixel than
 * the general shift-mask-shift): BYTES = a whole little-endian 1/2/4-byte load at a byte offset
 * (byte-aligned fields that fill their type, no up-shift); MASK = the word & mask; SHIFT = the general
 * ((word >> off) & mask) << upshift, cast to the field's type before the up-shift as NumPy does. */
enum { KIND_BYTES, KIND_MASK, KIND_SHIFT };

static inline uint32_t load_le16(const unsigned char *p) {
    uint16_t v;
    memcpy(&v, p, 2);
#if !PY_LITTLE_ENDIAN
    v = (uint16_t)((v >> 8) | (v << 8));
#endif
    return v;
}

#define PIXEL_U8(s) ((uint32_t)(s)[0])
#define PIXEL_U16(s) load_le16(s)
#define PIXEL_U32(s) load_le32(s)

/* One row of one field of one packet: dst[mids[j]] (or dst[j] when `consecutive`, dst already at
 * mids[0]) for the C columns j, src at the field's bytes in column 0, columns `cstride` apart.
 * Always inlined into calls with C = 16 (every Ouster firmware's columns per packet), so that the
 * compiler unrolls the columns, and into one with C at run time. */
#define SCATTER_ROW(NAME, TYPE)                                                                                   \
    static inline __attribute__((always_inline)) void NAME(                                                      \
        const unsigned char *restrict s, Py_ssize_t cstride, Py_ssize_t c, const int64_t *restrict mids,          \
        int consecutive, int kind, unsigned off, uint32_t mask, unsigned upshift, TYPE *restrict d) {            \
        if (consecutive && kind == KIND_BYTES) {                                                                  \
            for (Py_ssize_t j = 0; j < c; j++) d[j] = (TYPE)(sizeof(TYPE) == 1 ? PIXEL_U8(s + j * cstride)       \
                                                     : sizeof(TYPE) == 2 ? PIXEL_U16(s + j * cstride)             \
                                                                         : PIXEL_U32(s + j * cstride));           \
        } else if (consecutive && kind == KIND_MASK) {                                                            \
            for (Py_ssize_t j = 0; j < c; j++) d[j] = (TYPE)(load_le32(s + j * cstride) & mask);                 \
        } else if (consecutive) {                                                                                 \
            for (Py_ssize_t j = 0; j < c; j++)                                                                    \
                d[j] = (TYPE)((TYPE)((load_le32(s + j * cstride) >> off) & mask) << upshift);                     \
        } else { /* columns out of order within the packet: rare, so one loop for every kind */               \
            for (Py_ssize_t j = 0; j < c; j++) {                                                                  \
                const unsigned char *p = s + j * cstride;                                                         \
                d[mids[j]] = kind == KIND_BYTES ? (TYPE)(sizeof(TYPE) == 1   ? PIXEL_U8(p)                        \
                                                         : sizeof(TYPE) == 2 ? PIXEL_U16(p)                       \
                                                                             : PIXEL_U32(p))                      \
                             : kind == KIND_MASK ? (TYPE)(load_le32(p) & mask)                                    \
                                                 : (TYPE)((TYPE)((load_le32(p) >> off) & mask) << upshift);       \
            }                                                                                                     \
        }                                                                                                         \
    }                                                                                                             \
    static void NAME##_packet(const unsigned char *restrict src, Py_ssize_t cstride, Py_ssize_t pstride,         \
                              Py_ssize_t h, Py_ssize_t c, const int64_t *restrict mids, int consecutive,          \
                              Py_ssize_t w, int kind, unsigned off, uint32_t mask, unsigned upshift,              \
                              TYPE *restrict dst) {                                                               \
        TYPE *d = dst + (consecutive ? mids[0] : 0);                                                              \
        if (c == 16)                                                                                              \
            for (Py_ssize_t row = 0; row < h; row++)                                                              \
                NAME(src + row * pstride, cstride, 16, mids, consecutive, kind, off, mask, upshift, d + row * w); \
        else                                                                                                      \
            for (Py_ssize_t row = 0; row < h; row++)                                                              \
                NAME(src + row * pstride, cstride, c, mids, consecutive, kind, off, mask, upshift, d + row * w);  \
    }

SCATTER_ROW(scatter_u8, uint8_t)
SCATTER_ROW(scatter_u16, uint16_t)
SCATTER_ROW(scatter_u32, uint32_t)

#define MAX_FIELDS 16

typedef struct {
    Py_ssize_t at, itemsize; /* byte of the pixel the field is read from (its word's, or its own for BYTES) */
    int kind;
    unsigned off, upshift;
    uint32_t mask;
    void *out;
} field_plan;

/* Checks the outputs (F writable C-contiguous unsigned [h, w] arrays of 1, 2 or 4 bytes) and the
 * steps (int64 [F, 4]: word, bit offset, mask or 0 for none, up-shift) into plans; 0 or -1. */
static int plan_fields(PyObject *outs, const int64_t *steps, Py_ssize_t nsteps, Py_ssize_t h, Py_ssize_t pixel_bytes,
                       Py_buffer *views, int *got, Py_ssize_t *w, field_plan *plans) {
    Py_ssize_t f = PySequence_Fast_GET_SIZE(outs);
    if (f != nsteps || f > MAX_FIELDS) {
        PyErr_SetString(PyExc_ValueError, "ouster_scatter: one output per step (at most 16)");
        return -1;
    }
    for (Py_ssize_t i = 0; i < f; i++) {
        Py_buffer *v = &views[i];
        if (PyObject_GetBuffer(PySequence_Fast_GET_ITEM(outs, i), v, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0)
            return -1;
        (*got)++;
        const int64_t *s = steps + 4 * i;
        if (v->ndim != 2 || v->shape[0] != h || (i > 0 && v->shape[1] != *w) || !is_native(v->format, "BHIL") ||
            (v->itemsize != 1 && v->itemsize != 2 && v->itemsize != 4) || s[0] < 0 || 4 * s[0] + 4 > pixel_bytes ||
            s[1] < 0 || s[1] > 31 || s[2] < 0 || s[2] > 0xFFFFFFFFLL || s[3] < 0 || s[3] >= 8 * v->itemsize) {
            PyErr_SetString(PyExc_ValueError, "ouster_scatter: outputs must be unsigned [H, W] arrays of 1, 2 or 4 "
                                              "bytes and steps (word, offset, mask, up-shift) fit the pixel");
            return -1;
        }
        *w = v->shape[1];
        field_plan *p = &plans[i];
        *p = (field_plan){4 * s[0], v->itemsize, KIND_SHIFT, (unsigned)s[1], (unsigned)s[3],
                          s[2] ? (uint32_t)s[2] : 0xFFFFFFFFu, v->buf};
        int fills = s[2] == 0 || s[2] == (int64_t)(0xFFFFFFFFu >> (32 - 8 * v->itemsize));
        if (PY_LITTLE_ENDIAN && s[1] % 8 == 0 && s[1] + 8 * v->itemsize <= 32 && fills && s[3] == 0) {
            p->kind = KIND_BYTES;
            p->at += s[1] / 8;
        } else if (s[1] == 0 && s[3] == 0 && v->itemsize == 4) {
            p->kind = KIND_MASK;
        }
    }
    return 0;
}

/* ouster_scatter(payload, columns_at, column_bytes, pixels_at, pixel_bytes, h, mids, steps, outs)
 *
 * payload: uint8 [N, L] (each row contiguous, rows any stride apart: packets in a capture file);
 * column c of packet p starts at byte columns_at + c * column_bytes of its row, its H pixels at
 * pixels_at in the column, pixel_bytes each; mids: int64 [N, C] the frame column of each packet
 * column (each < W); steps: int64 [F, 4]; outs: F arrays [H, W] (see plan_fields). Packets are
 * written in order, so a column received twice keeps the last one's pixels, as in the NumPy twin.
 * Raises ValueError for arguments that do not fit together (nothing is written then).
 */
PyObject *lp_ouster_scatter(PyObject *self, PyObject *args) {
    PyObject *p_obj, *m_obj, *s_obj, *o_obj;
    Py_ssize_t columns_at, column_bytes, pixels_at, pixel_bytes, h;
    if (!PyArg_ParseTuple(args, "OnnnnnOOO", &p_obj, &columns_at, &column_bytes, &pixels_at, &pixel_bytes, &h, &m_obj,
                          &s_obj, &o_obj))
        return NULL;
    PyObject *outs = PySequence_Fast(o_obj, "ouster_scatter: outs must be a sequence of arrays");
    if (outs == NULL) return NULL;
    Py_buffer pb, mb, sb, views[MAX_FIELDS];
    field_plan plans[MAX_FIELDS];
    int have = 0, got = 0;
    PyObject *result = NULL;
    if (get_buffer(p_obj, &pb, PyBUF_STRIDES | PyBUF_FORMAT, 1, "ouster_scatter payload") < 0) goto done;
    have = 1;
    if (get_buffer(m_obj, &mb, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 8, "ouster_scatter mids") < 0) goto done;
    have = 2;
    if (get_buffer(s_obj, &sb, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 8, "ouster_scatter steps") < 0) goto done;
    have = 3;
    Py_ssize_t n = pb.ndim == 2 ? pb.shape[0] : -1, c = mb.ndim == 2 ? mb.shape[1] : -1, w = 0;
    if (n < 0 || c < 1 || pb.strides[1] != 1 || mb.ndim != 2 || mb.shape[0] != n || !is_native(mb.format, INTEGER_CODES) ||
        !is_native(sb.format, INTEGER_CODES) || sb.ndim != 2 || sb.shape[1] != 4 || h < 1 || pixel_bytes < 4 ||
        columns_at < 0 || pixels_at < 0 || column_bytes < pixels_at + h * pixel_bytes ||
        columns_at + c * column_bytes > pb.shape[1]) {
        PyErr_SetString(PyExc_ValueError, "ouster_scatter: payload uint8 [N, L] and mids int64 [N, C] of a packet "
                                          "layout that fits L");
        goto done;
    }
    if (plan_fields(outs, (const int64_t *)sb.buf, sb.shape[0], h, pixel_bytes, views, &got, &w, plans) < 0) goto done;
    const int64_t *mids = (const int64_t *)mb.buf;
    for (Py_ssize_t i = 0; i < n * c; i++) {
        if (mids[i] < 0 || mids[i] >= w) {
            PyErr_Format(PyExc_ValueError, "ouster_scatter: measurement id %lld outside the frame's %zd columns",
                         (long long)mids[i], w);
            goto done;
        }
    }
    {
        const unsigned char *base = (const unsigned char *)pb.buf;
        Py_ssize_t nf = got;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t p = 0; p < n; p++) {
            const int64_t *m = mids + p * c;
            int consecutive = m[c - 1] - m[0] == c - 1;
            for (Py_ssize_t j = 1; consecutive && j < c; j++) consecutive = m[j] == m[j - 1] + 1;
            const unsigned char *col0 = base + p * pb.strides[0] + columns_at + pixels_at;
            for (Py_ssize_t i = 0; i < nf; i++) {
                const field_plan *f = &plans[i];
                const unsigned char *src = col0 + f->at;
                if (f->itemsize == 1)
                    scatter_u8_packet(src, column_bytes, pixel_bytes, h, c, m, consecutive, w, f->kind, f->off,
                                      f->mask, f->upshift, (uint8_t *)f->out);
                else if (f->itemsize == 2)
                    scatter_u16_packet(src, column_bytes, pixel_bytes, h, c, m, consecutive, w, f->kind, f->off,
                                       f->mask, f->upshift, (uint16_t *)f->out);
                else
                    scatter_u32_packet(src, column_bytes, pixel_bytes, h, c, m, consecutive, w, f->kind, f->off,
                                       f->mask, f->upshift, (uint32_t *)f->out);
            }
        }
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;
done:
    for (int i = 0; i < got; i++) PyBuffer_Release(&views[i]);
    if (have >= 3) PyBuffer_Release(&sb);
    if (have >= 2) PyBuffer_Release(&mb);
    if (have >= 1) PyBuffer_Release(&pb);
    Py_DECREF(outs);
    return result;
}
