/* Packet walk: offsets of pcap / pcapng records and rows of bytes at offsets. */
#include "common.h"

#define PREFETCH_BYTES 8192

/* walk_pcap(buf, start, end, caplen_at, header_bytes, swap, max_cap, max_records, byte_limit, offsets)
 *
 * Walks classic pcap record headers in buf[start:end] and writes the offset of each whole record
 * to offsets (int64) until one needs a decision: 0 = max_records or byte_limit reached, 1 = the
 * next header is cut by `end`, 2 = its incl_len exceeds max_cap, 3 = its data is cut by `end`.
 * Returns (records, offset of the next record, reason).
 */
PyObject *lp_walk_pcap(PyObject *self, PyObject *args) {
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
PyObject *lp_walk_pcapng(PyObject *self, PyObject *args) {
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
PyObject *lp_gather_rows(PyObject *self, PyObject *args) {
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
