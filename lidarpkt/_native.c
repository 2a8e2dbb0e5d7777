/* Compiled kernels for the hot loops NumPy cannot vectorise well (see lidarpkt/kernels.py).
 *
 * Built as the optional top-level extension module `_lidarpkt_native` (pyproject.toml); every
 * kernel has a pure-NumPy twin in the Python code and the tests check that both give the same
 * bytes. Arrays come in through the buffer protocol, so the build needs no NumPy headers.
 * The GIL is released around every loop, so the pcap read-ahead thread runs beside them.
 *
 * Compiled with -ffp-contract=off: `r * d + o` must round twice, as NumPy and ouster-sdk do.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

static int get_buffer(PyObject *obj, Py_buffer *view, int flags, Py_ssize_t itemsize, const char *what) {
    if (PyObject_GetBuffer(obj, view, flags) < 0) return -1;
    if (view->itemsize != itemsize) {
        PyErr_Format(PyExc_ValueError, "%s: expected items of %zd bytes, got %zd", what, itemsize, view->itemsize);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

/* A buffer format of one native-order item whose code is in `codes` ("q", "=q", "<q" on a
 * little-endian machine...); the callers check the item size. */
static int is_native(const char *format, const char *codes) {
    if (format == NULL) return 0;
    if (*format == '@' || *format == '=') format++;
#if PY_LITTLE_ENDIAN
    else if (*format == '<') format++;
#else
    else if (*format == '>' || *format == '!') format++;
#endif
    return format[0] != '\0' && format[1] == '\0' && strchr(codes, format[0]) != NULL;
}

#define INTEGER_CODES "bBhHiIlLqQnN"

#define PREFETCH_BYTES 8192

static inline uint32_t bswap32(uint32_t v) { return __builtin_bswap32(v); }

/* walk_pcap(buf, start, end, caplen_at, header_bytes, swap, max_cap, max_records, byte_limit, offsets)
 *
 * Walks classic pcap record headers in buf[start:end] and writes the offset of each whole record
 * to offsets (int64) until one needs a decision: 0 = max_records or byte_limit reached, 1 = the
 * next header is cut by `end`, 2 = its incl_len exceeds max_cap, 3 = its data is cut by `end`.
 * Returns (records, offset of the next record, reason).
 */
static PyObject *walk_pcap(PyObject *self, PyObject *args) {
    PyObject *buf_obj, *off_obj;
    Py_ssize_t start, end, caplen_at, hdr, max_records, byte_limit;
    int swap;
    unsigned long long max_cap;
    if (!PyArg_ParseTuple(args, "OnnnnpKnnO", &buf_obj, &start, &end, &caplen_at, &hdr, &swap, &max_cap,
                          &max_records, &byte_limit, &off_obj))
        return NULL;
    Py_buffer buf, offs;
    if (get_buffer(buf_obj, &buf, PyBUF_SIMPLE, 1, "walk_pcap buf") < 0) return NULL;
    if (get_buffer(off_obj, &offs, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 8, "walk_pcap offsets") < 0) {
        PyBuffer_Release(&buf);
        return NULL;
    }
    if (end > buf.len) end = buf.len;
    if (start < 0 || caplen_at < 0 || hdr < caplen_at + 4 || max_records > offs.len / 8 ||
        !is_native(offs.format, INTEGER_CODES)) {
        PyBuffer_Release(&buf);
        PyBuffer_Release(&offs);
        PyErr_SetString(PyExc_ValueError, "walk_pcap: bad arguments");
        return NULL;
    }
    const unsigned char *p = (const unsigned char *)buf.buf;
    int64_t *out = (int64_t *)offs.buf;
    Py_ssize_t rel = start, n = 0, ahead = start;
    int reason = 0;
    Py_BEGIN_ALLOW_THREADS
    while (n < max_records && rel < byte_limit) {
        /* one dependent load per record, each on a cold line: keep the lines PREFETCH_BYTES ahead
         * on their way into the cache (the payload copy that follows reads them anyway) */
        for (; ahead < rel + PREFETCH_BYTES && ahead < end; ahead += 64) __builtin_prefetch(p + ahead);
        if (rel + hdr > end) { reason = 1; break; }
        uint32_t cap;
        memcpy(&cap, p + rel + caplen_at, 4);
        if (swap) cap = bswap32(cap);
        if ((unsigned long long)cap > max_cap) { reason = 2; break; }
        if (rel + hdr + (Py_ssize_t)cap > end) { reason = 3; break; }
        out[n++] = rel;
        rel += hdr + (Py_ssize_t)cap;
    }
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&buf);
    PyBuffer_Release(&offs);
    return Py_BuildValue("nni", n, rel, reason);
}

/* walk_pcapng(buf, start, end, swap, interfaces, max_block, max_records, byte_limit,
 *             data_out, caplen_out, interface_out, timestamp_out)
 *
 * Walks the enhanced packet blocks (type 6) of one pcapng section in buf[start:end] and writes, for
 * each, the offset of its packet data, its captured length, its interface and its raw 64-bit time
 * stamp (int64, int64, int64, uint64 arrays).  It stops, without consuming it, at the first block
 * that needs a decision (any other block type, a length that is not a multiple of 4, below 12 or
 * above max_block, a block cut by `end`, a trailing length that differs, a body too short for the
 * EPB header, an interface >= `interfaces`, data longer than the block), and when max_records
 * records were written or the next block starts at or after byte_limit.
 * Returns (records, offset of the next block).
 */
static PyObject *walk_pcapng(PyObject *self, PyObject *args) {
    PyObject *b_obj, *d_obj, *c_obj, *i_obj, *t_obj;
    Py_ssize_t start, end, interfaces, max_block, max_records, byte_limit;
    int swap;
    if (!PyArg_ParseTuple(args, "OnnpnnnnOOOO", &b_obj, &start, &end, &swap, &interfaces, &max_block, &max_records,
                          &byte_limit, &d_obj, &c_obj, &i_obj, &t_obj))
        return NULL;
    Py_buffer b, d, c, i, t;
    int have = 0;
    PyObject *result = NULL;
    if (get_buffer(b_obj, &b, PyBUF_SIMPLE, 1, "walk_pcapng buf") < 0) goto done;
    have = 1;
    if (get_buffer(d_obj, &d, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 8, "walk_pcapng data") < 0) goto done;
    have = 2;
    if (get_buffer(c_obj, &c, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 8, "walk_pcapng caplen") < 0) goto done;
    have = 3;
    if (get_buffer(i_obj, &i, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 8, "walk_pcapng interface") < 0) goto done;
    have = 4;
    if (get_buffer(t_obj, &t, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 8, "walk_pcapng timestamp") < 0) goto done;
    have = 5;
    if (end > b.len) end = b.len;
    if (start < 0 || max_records < 0 || max_records > d.len / 8 || max_records > c.len / 8 || max_records > i.len / 8 ||
        max_records > t.len / 8 || !is_native(d.format, INTEGER_CODES) || !is_native(c.format, INTEGER_CODES) ||
        !is_native(i.format, INTEGER_CODES) || !is_native(t.format, INTEGER_CODES)) {
        PyErr_SetString(PyExc_ValueError, "walk_pcapng: bad arguments (outputs: native 64-bit integers, max_records each)");
        goto done;
    }
    {
        const unsigned char *p = (const unsigned char *)b.buf;
        int64_t *data = (int64_t *)d.buf, *caplen = (int64_t *)c.buf, *iface = (int64_t *)i.buf;
        uint64_t *stamp = (uint64_t *)t.buf;
        Py_ssize_t rel = start, n = 0, ahead = start;
        Py_BEGIN_ALLOW_THREADS
        while (n < max_records && rel < byte_limit && rel + 12 <= end) {
            for (; ahead < rel + PREFETCH_BYTES && ahead < end; ahead += 64) __builtin_prefetch(p + ahead);
            uint32_t w[7];  /* block type, length, interface, ts high, ts low, captured, original */
            memcpy(w, p + rel, 8);
            if (swap) { w[0] = bswap32(w[0]); w[1] = bswap32(w[1]); }
            Py_ssize_t blen = (Py_ssize_t)w[1];
            if (w[0] != 6 || blen < 12 + 20 || blen % 4 || blen > max_block || rel + blen > end) break;
            uint32_t trailer;
            memcpy(&trailer, p + rel + blen - 4, 4);
            if (swap) trailer = bswap32(trailer);
            if ((Py_ssize_t)trailer != blen) break;
            memcpy(w + 2, p + rel + 8, 20);
            if (swap) for (int k = 2; k < 7; k++) w[k] = bswap32(w[k]);
            Py_ssize_t body_end = rel + blen - 4, at = rel + 8 + 20;
            if ((Py_ssize_t)w[2] >= interfaces || at + (Py_ssize_t)w[5] > body_end) break;
            data[n] = at;
            caplen[n] = w[5];
            iface[n] = w[2];
            stamp[n] = ((uint64_t)w[3] << 32) | w[4];
            n++;
            rel += blen;
        }
        Py_END_ALLOW_THREADS
        result = Py_BuildValue("nn", n, rel);
    }
done:
    if (have >= 5) PyBuffer_Release(&t);
    if (have >= 4) PyBuffer_Release(&i);
    if (have >= 3) PyBuffer_Release(&c);
    if (have >= 2) PyBuffer_Release(&d);
    if (have >= 1) PyBuffer_Release(&b);
    return result;
}

/* gather_rows(buf, offsets, out)
 *
 * out[i, :] = buf[offsets[i] : offsets[i] + width] for uint8 out [n, width] (C-contiguous) and
 * int64 offsets, each checked against the buffer.  NumPy's fancy index pays ~10-20 ns per row;
 * header fields are 1-8 byte rows, so that overhead, not the bytes, was the cost.
 */
static PyObject *gather_rows(PyObject *self, PyObject *args) {
    PyObject *b_obj, *o_obj, *x_obj;
    if (!PyArg_ParseTuple(args, "OOO", &b_obj, &o_obj, &x_obj)) return NULL;
    Py_buffer b, o, x;
    if (get_buffer(b_obj, &b, PyBUF_SIMPLE, 1, "gather_rows buf") < 0) return NULL;
    if (get_buffer(o_obj, &o, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 8, "gather_rows offsets") < 0) {
        PyBuffer_Release(&b);
        return NULL;
    }
    if (get_buffer(x_obj, &x, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT, 1, "gather_rows out") < 0) {
        PyBuffer_Release(&b);
        PyBuffer_Release(&o);
        return NULL;
    }
    PyObject *result = NULL;
    Py_ssize_t n = o.len / 8;
    Py_ssize_t width = x.ndim == 2 ? x.shape[1] : -1;
    if (x.ndim != 2 || x.shape[0] != n || !is_native(o.format, INTEGER_CODES)) {
        PyErr_SetString(PyExc_ValueError, "gather_rows: offsets must be native int64 and out uint8 [len(offsets), width]");
        goto done;
    }
    const int64_t *offs = (const int64_t *)o.buf;
    for (Py_ssize_t i = 0; i < n; i++) {
        /* written so that no sum can overflow, whatever the offset */
        if (offs[i] < 0 || width > b.len || offs[i] > b.len - width) {
            PyErr_Format(PyExc_IndexError, "gather_rows: row at %lld of %zd bytes leaves the %zd-byte buffer",
                         (long long)offs[i], width, b.len);
            goto done;
        }
    }
    {
        const unsigned char *src = (const unsigned char *)b.buf;
        unsigned char *dst = (unsigned char *)x.buf;
        Py_BEGIN_ALLOW_THREADS
        switch (width) {  /* fixed sizes compile to single loads and stores */
        case 1: for (Py_ssize_t i = 0; i < n; i++) dst[i] = src[offs[i]]; break;
        case 2: for (Py_ssize_t i = 0; i < n; i++) memcpy(dst + 2 * i, src + offs[i], 2); break;
        case 4: for (Py_ssize_t i = 0; i < n; i++) memcpy(dst + 4 * i, src + offs[i], 4); break;
        case 8: for (Py_ssize_t i = 0; i < n; i++) memcpy(dst + 8 * i, src + offs[i], 8); break;
        default: for (Py_ssize_t i = 0; i < n; i++) memcpy(dst + width * i, src + offs[i], width);
        }
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;
done:
    PyBuffer_Release(&b);
    PyBuffer_Release(&o);
    PyBuffer_Release(&x);
    return result;
}

/* Per-function multiversioning: NumPy dispatches AVX2 at run time while this extension is built for
 * the portable baseline; the XYZ loop gets an AVX2 clone chosen when the module loads (GCC/clang
 * ifunc on x86-64 ELF), and the baseline stays for every other machine. No FMA in either clone
 * ("avx2" does not enable it, and -ffp-contract=off forbids contraction): the same two roundings. */
#if defined(__x86_64__) && defined(__ELF__) && (defined(__clang__) || (defined(__GNUC__) && __GNUC__ >= 6))
#define MULTIVERSION __attribute__((target_clones("avx2", "default")))
#else
#define MULTIVERSION
#endif

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
static PyObject *xyz_lut(PyObject *self, PyObject *args) {
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

/* velodyne_xyz(range, azimuth, cos, neg_sin, coef, has_dist, has_voff, out)
 *
 * range: uint32 [R, 16, W]; azimuth: uint16 [16, W] (0.01 degree, < 36000); cos, neg_sin: float64
 * [T, 36000] with T = 1 (one table) or 16 (one per row); coef: float64 [5, 16] (k_xy, k_z, dc_xy,
 * dc_z, vert_offset per row); out: float64 [R, 16, W, 3]; all C-contiguous. The operations and
 * their order are those of VelodyneGeometry._points (its NumPy twin), so the bytes are the same:
 *   hit = range > 0; dxy = range * k_xy; dz = range * k_z;
 *   if has_dist: dxy += hit * dc_xy; dz += hit * dc_z
 *   x = dxy * cos[a]; y = dxy * neg_sin[a]; if has_voff: dz = (dz + voff) * hit; z = dz
 * Raises IndexError for an azimuth of 36000 or more (as NumPy's table lookup does).
 */
MULTIVERSION
static void velodyne_xyz_rows(const uint32_t *restrict rng, const uint16_t *restrict az, const double *restrict cos_t,
                              const double *restrict nsin_t, double kxy, double kz, double dcxy, double dcz,
                              double voff, int has_dist, int has_voff, double *restrict out, Py_ssize_t w) {
    for (Py_ssize_t i = 0; i < w; i++) {
        uint32_t v = rng[i];
        double hit = v > 0 ? 1.0 : 0.0, s = (double)v;
        double dxy = s * kxy, dz = s * kz;
        if (has_dist) {
            dxy = dxy + hit * dcxy;
            dz = dz + hit * dcz;
        }
        out[3 * i] = dxy * cos_t[az[i]];
        out[3 * i + 1] = dxy * nsin_t[az[i]];
        if (has_voff) dz = (dz + voff) * hit;
        out[3 * i + 2] = dz;
    }
}

static PyObject *velodyne_xyz(PyObject *self, PyObject *args) {
    PyObject *objs[6];
    int has_dist, has_voff;
    if (!PyArg_ParseTuple(args, "OOOOOppO", &objs[0], &objs[1], &objs[2], &objs[3], &objs[4], &has_dist, &has_voff,
                          &objs[5]))
        return NULL;
    static const Py_ssize_t sizes[6] = {4, 2, 8, 8, 8, 8};
    static const char *codes[6] = {"IL", "H", "d", "d", "d", "d"};
    Py_buffer b[6];
    int got = 0;
    PyObject *result = NULL;
    for (; got < 6; got++) {
        int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (got == 5 ? PyBUF_WRITABLE : 0);
        if (get_buffer(objs[got], &b[got], flags, sizes[got], "velodyne_xyz") < 0) goto done;
        if (!is_native(b[got].format, codes[got])) {
            PyErr_SetString(PyExc_ValueError, "velodyne_xyz: range uint32, azimuth uint16, the rest float64");
            got++;
            goto done;
        }
    }
    {
        Py_ssize_t hw = b[1].len / 2, w = hw / 16, table = 36000;
        Py_ssize_t rows_t = b[2].len / 8 / table;
        if (hw % 16 || hw == 0 || (b[0].len / 4) % hw || b[5].len != (b[0].len / 4) * 24 || b[2].len != b[3].len ||
            (rows_t != 1 && rows_t != 16) || b[2].len != rows_t * table * 8 || b[4].len != 5 * 16 * 8) {
            PyErr_SetString(PyExc_ValueError, "velodyne_xyz: arrays of disagreeing sizes");
            goto done;
        }
        const uint16_t *az = (const uint16_t *)b[1].buf;
        for (Py_ssize_t i = 0; i < hw; i++) {
            if (az[i] >= table) {
                PyErr_Format(PyExc_IndexError, "velodyne_xyz: azimuth %d (0.01 degree) is 360 degrees or more", az[i]);
                goto done;
            }
        }
        Py_ssize_t returns = (b[0].len / 4) / hw;
        const uint32_t *rng = (const uint32_t *)b[0].buf;
        const double *cos_t = (const double *)b[2].buf, *nsin_t = (const double *)b[3].buf;
        const double *coef = (const double *)b[4].buf;
        double *out = (double *)b[5].buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t r = 0; r < returns; r++) {
            for (Py_ssize_t h = 0; h < 16; h++) {
                Py_ssize_t t = rows_t == 16 ? h * table : 0;
                velodyne_xyz_rows(rng + (r * 16 + h) * w, az + h * w, cos_t + t, nsin_t + t, coef[h], coef[16 + h],
                                  coef[32 + h], coef[48 + h], coef[64 + h], has_dist, has_voff,
                                  out + (r * 16 + h) * w * 3, w);
            }
        }
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;
done:
    for (int i = 0; i < got; i++) PyBuffer_Release(&b[i]);
    return result;
}

/* velodyne_columns(distance, reflectivity, firing_azimuth, lasers, slots, range_out, refl_out, az_out)
 *
 * The VLP-16 packets of a batch into range-image columns, as VelodyneDecoder._columns's NumPy path:
 * distance uint16 [N, 12, 32] and reflectivity uint8 [N, 12, 32] (any strides: views of the 3-byte
 * records of the payloads), firing_azimuth uint16 [N, 12 / slots, 32] (any strides), lasers int64
 * [16] (the laser of each row, each < 16), slots 1 or 2 (dual: block b is slot b % 2); outputs
 * C-contiguous range_out uint32 [slots, 16, W], refl_out uint8 [slots, 16, W], az_out uint16 [16, W]
 * with W = N * (12 / slots) * 2. Column (p * (12 / slots) + b / slots) * 2 + seq of row r holds
 * channel seq * 16 + lasers[r] of block b of packet p; range = 2 * distance (mm).
 */
static inline uint16_t load_u16(const char *p) {
    uint16_t v;
    memcpy(&v, p, 2);
    return v;
}

static PyObject *velodyne_columns(PyObject *self, PyObject *args) {
    PyObject *o[7];
    int slots;
    if (!PyArg_ParseTuple(args, "OOOOiOOO", &o[0], &o[1], &o[2], &o[3], &slots, &o[4], &o[5], &o[6])) return NULL;
    static const Py_ssize_t sizes[7] = {2, 1, 2, 8, 4, 1, 2};
    static const char *codes[7] = {"H", "B", "H", INTEGER_CODES, "IL", "B", "H"};
    Py_buffer b[7];
    int got = 0;
    PyObject *result = NULL;
    for (; got < 7; got++) {
        int flags = got < 3 ? PyBUF_STRIDES | PyBUF_FORMAT
                            : PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (got >= 4 ? PyBUF_WRITABLE : 0);
        if (get_buffer(o[got], &b[got], flags, sizes[got], "velodyne_columns") < 0) goto done;
        if (!is_native(b[got].format, codes[got])) {
            PyErr_SetString(PyExc_ValueError, "velodyne_columns: unexpected item types");
            got++;
            goto done;
        }
    }
    {
        if (slots != 1 && slots != 2) {
            PyErr_SetString(PyExc_ValueError, "velodyne_columns: slots must be 1 or 2");
            goto done;
        }
        Py_ssize_t bps = 12 / slots;
        Py_ssize_t n = b[0].ndim == 3 ? b[0].shape[0] : -1, w = n * bps * 2;
        if (n < 0 || b[0].shape[1] != 12 || b[0].shape[2] != 32 || b[1].ndim != 3 || b[1].shape[0] != n ||
            b[1].shape[1] != 12 || b[1].shape[2] != 32 || b[2].ndim != 3 || b[2].shape[0] != n ||
            b[2].shape[1] != bps || b[2].shape[2] != 32 || b[3].len != 16 * 8 || b[4].len != slots * 16 * w * 4 ||
            b[5].len != slots * 16 * w || b[6].len != 16 * w * 2) {
            PyErr_SetString(PyExc_ValueError, "velodyne_columns: arrays of disagreeing shapes");
            goto done;
        }
        const int64_t *lasers = (const int64_t *)b[3].buf;
        for (int r = 0; r < 16; r++) {
            if (lasers[r] < 0 || lasers[r] > 15) {
                PyErr_SetString(PyExc_ValueError, "velodyne_columns: a laser number outside 0-15");
                goto done;
            }
        }
        const char *dist = (const char *)b[0].buf, *refl = (const char *)b[1].buf, *fa = (const char *)b[2].buf;
        const Py_ssize_t *ds = b[0].strides, *rs = b[1].strides, *as = b[2].strides;
        uint32_t *rng_out = (uint32_t *)b[4].buf;
        uint8_t *refl_out = (uint8_t *)b[5].buf;
        uint16_t *az_out = (uint16_t *)b[6].buf;
        Py_BEGIN_ALLOW_THREADS
        /* packets in chunks whose records stay in L2 (64 x 1.2 kB); per chunk, row by row, so that
         * each output row is written contiguously (a packet at a time touched 80 rows ~300 kB apart) */
        for (Py_ssize_t p0 = 0; p0 < n; p0 += 64) {
            Py_ssize_t p1 = p0 + 64 < n ? p0 + 64 : n;
            for (int slot = 0; slot < slots; slot++) {
                for (int r = 0; r < 16; r++) {
                    Py_ssize_t laser = lasers[r];
                    uint32_t *ro = rng_out + ((Py_ssize_t)slot * 16 + r) * w;
                    uint8_t *fo = refl_out + ((Py_ssize_t)slot * 16 + r) * w;
                    for (Py_ssize_t p = p0; p < p1; p++) {
                        const char *dp = dist + p * ds[0] + slot * ds[1] + laser * ds[2];
                        const char *rp = refl + p * rs[0] + slot * rs[1] + laser * rs[2];
                        Py_ssize_t c = p * bps * 2;
                        for (Py_ssize_t bb = 0; bb < bps; bb++) {
                            const char *d = dp + bb * slots * ds[1], *f = rp + bb * slots * rs[1];
                            ro[c + 2 * bb] = 2u * (uint32_t)load_u16(d);
                            ro[c + 2 * bb + 1] = 2u * (uint32_t)load_u16(d + 16 * ds[2]);
                            fo[c + 2 * bb] = (uint8_t)f[0];
                            fo[c + 2 * bb + 1] = (uint8_t)f[16 * rs[2]];
                        }
                    }
                }
            }
            for (int r = 0; r < 16; r++) {
                uint16_t *ao = az_out + (Py_ssize_t)r * w;
                for (Py_ssize_t p = p0; p < p1; p++) {
                    const char *ap = fa + p * as[0] + lasers[r] * as[2];
                    Py_ssize_t c = p * bps * 2;
                    for (Py_ssize_t bb = 0; bb < bps; bb++) {
                        ao[c + 2 * bb] = load_u16(ap + bb * as[1]);
                        ao[c + 2 * bb + 1] = load_u16(ap + bb * as[1] + 16 * as[2]);
                    }
                }
            }
        }
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;
done:
    for (int i = 0; i < got; i++) PyBuffer_Release(&b[i]);
    return result;
}

static PyMethodDef methods[] = {
    {"walk_pcap", walk_pcap, METH_VARARGS, "Offsets of whole classic-pcap records; see lidarpkt/_native.c."},
    {"walk_pcapng", walk_pcapng, METH_VARARGS, "Enhanced packet blocks of a pcapng section; see lidarpkt/_native.c."},
    {"gather_rows", gather_rows, METH_VARARGS, "Rows of bytes at offsets of a buffer."},
    {"xyz_lut", xyz_lut, METH_VARARGS, "range * direction + offset, zero where range is 0."},
    {"velodyne_columns", velodyne_columns, METH_VARARGS, "VLP-16 packets into range-image columns; see _native.c."},
    {"velodyne_xyz", velodyne_xyz, METH_VARARGS, "VLP-16 XYZ from ranges and per-firing azimuths; see _native.c."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_lidarpkt_native",
                                    "Compiled kernels of lidarpkt (optional; see lidarpkt/kernels.py).", -1, methods};

PyMODINIT_FUNC PyInit__lidarpkt_native(void) { return PyModule_Create(&module); }
