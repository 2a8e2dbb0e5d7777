/* Ouster: the pixels of lidar packets scattered straight into a frame's [H, W] field arrays.
 *
 * A packet holds C columns, each of H pixels of `pixel_bytes` (column-major on the wire); a frame's
 * field arrays are row-major [H, W]. The NumPy twin (lidarpkt/vendors/ouster/frames.py) transposes the
 * pixel words into word planes [words, H, W] and then extracts each field from its plane; this
 * kernel does both in one pass, so no plane is written or read again.
 *
 * Packets go GROUP at a time, in blocks of BLOCK_ROWS rows. The block's pixel words are transposed
 * into an L1 scratch (16 columns: 16-byte loads and 4x4 transposes in SSE2 registers, gather16;
 * otherwise, and where such a load would end past the packet row, scalar copies); then each field
 * is extracted from its word's scratch rows, 16 columns at a time with SSE2 and only the operations
 * the field needs (vector_kind, chosen once per call). When the group's packets sit side by side in
 * the frame (16 consecutive columns each, the next packet's right after: the common case), the
 * whole group shares the scratch and each field takes one pass over its 64 columns; otherwise each
 * packet goes alone, by scalar code when C != 16 or its columns are not consecutive. The loop
 * (scatter_packets) has an AVX2 clone (MULTIVERSION): the same SSE2 operations, VEX-encoded; the
 * baseline build stays SSE2.
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

/* Two steps per block: the pixels' words are copied into a small row-major scratch
 * (words[k][row][column]), then each field is extracted from its word's contiguous rows. Reading each
 * field straight from the column-major pixels cannot be vectorised (every load is a column apart):
 * that took more instructions than NumPy's transposing copy and field passes. */
#define MAX_WORDS 4    /* 16-byte pixels (RNG19 dual) */
#define MAX_COLUMNS 64 /* columns per packet: 16 on every firmware so far */
/* BLOCK_ROWS: a multiple of 4 (gather16). 8 is faster on one frame scattered again and again (in cache),
 * but decoding writes fresh frames: there 16 took 20-30% less time than 8 on RNG19 and LEGACY (cProfile
 * of lidarpkt.open over 300 OS-2-128 frames: 0.11-0.12 s against 0.15-0.18 s), and 32 no less than 16. */
#define BLOCK_ROWS 16
#define GROUP 4       /* packets per block of rows: 64 columns (GROUP * 16 <= MAX_COLUMNS: the scratch holds
                         a group side by side), a cache line of an 8-bit field's row */

typedef uint32_t scratch_t[MAX_WORDS][BLOCK_ROWS][MAX_COLUMNS];

/* The scalar copy: rows [r0, rows) of the block, any C, into scratch columns j0... */
static inline __attribute__((always_inline)) void gather(const unsigned char *restrict s, Py_ssize_t cstride,
                                                         Py_ssize_t pstride, Py_ssize_t r0, Py_ssize_t rows,
                                                         Py_ssize_t c, Py_ssize_t nwords, scratch_t words,
                                                         Py_ssize_t j0) {
    for (Py_ssize_t r = r0; r < rows; r++)
        for (Py_ssize_t j = 0; j < c; j++)
#pragma GCC unroll 4
            for (Py_ssize_t k = 0; k < nwords; k++)
                words[k][r][j0 + j] = load_le32(s + r * pstride + j * cstride + 4 * k);
}

#if defined(__SSE2__) && PY_LITTLE_ENDIAN
#include <emmintrin.h>
#define VECTOR_GATHER 1

/* The vector copy of rows [0, rows) of 16 columns into scratch columns j0...: one 16-byte load per
 * column reads `4 / nwp` consecutive pixels of nwp words (nwp = 1, 2 or 4; 3-word pixels are read as
 * 4, the 4th word, from the next pixel, is dropped), and a 4x4 transpose of 4 columns' loads gives
 * 4 columns of each (row, word). The caller checks that every 16 bytes read are inside the packet
 * row, and that rows is a multiple of 4 / nwp. */
static inline __attribute__((always_inline)) void gather16(const unsigned char *restrict s, Py_ssize_t cstride,
                                                           Py_ssize_t pstride, Py_ssize_t rows, int nwp,
                                                           Py_ssize_t nwords, scratch_t words, Py_ssize_t j0) {
    const int per = 4 / nwp; /* pixels per load */
    const Py_ssize_t cstride3 = 3 * cstride;
    for (Py_ssize_t r = 0; r < rows; r += per) {
        const unsigned char *q = s + r * pstride;
        for (int g = 0; g < 16; g += 4, q += 4 * cstride) { /* few address registers: no spills */
            __m128i a = _mm_loadu_si128((const __m128i *)q);
            __m128i b = _mm_loadu_si128((const __m128i *)(q + cstride));
            __m128i c = _mm_loadu_si128((const __m128i *)(q + 2 * cstride));
            __m128i d = _mm_loadu_si128((const __m128i *)(q + cstride3));
            __m128i ab0 = _mm_unpacklo_epi32(a, b), cd0 = _mm_unpacklo_epi32(c, d);
            __m128i ab1 = _mm_unpackhi_epi32(a, b), cd1 = _mm_unpackhi_epi32(c, d);
            __m128i t[4] = {_mm_unpacklo_epi64(ab0, cd0), _mm_unpackhi_epi64(ab0, cd0), _mm_unpacklo_epi64(ab1, cd1),
                            _mm_unpackhi_epi64(ab1, cd1)};
            /* t[i] = word i % nwp of pixel r + i / nwp, in columns g..g+3 */
            for (int i = 0; i < 4; i++)
                if (i % nwp < nwords) _mm_storeu_si128((__m128i *)&words[i % nwp][r + i / nwp][j0 + g], t[i]);
        }
    }
}
#endif

/* Rows [0, rows) of a block into the scratch; the first `fast` rows (0 unless c == 16, a multiple
 * of the pixels per vector load, and in bounds) with gather16, the others with the scalar copy,
 * with the sizes of every current firmware as constants so that the compiler unrolls it. */
static inline __attribute__((always_inline)) void gather_block(const unsigned char *s, Py_ssize_t cstride,
                                                               Py_ssize_t pstride, Py_ssize_t fast, Py_ssize_t rows,
                                                               Py_ssize_t c, Py_ssize_t nwords, scratch_t words,
                                                               Py_ssize_t j0) {
#ifdef VECTOR_GATHER
    if (fast > 0) {
        if (nwords == 3) gather16(s, cstride, pstride, fast, 4, 3, words, j0);
        else if (nwords == 1) gather16(s, cstride, pstride, fast, 1, 1, words, j0);
        else if (nwords == 2) gather16(s, cstride, pstride, fast, 2, 2, words, j0);
        else gather16(s, cstride, pstride, fast, 4, 4, words, j0);
    }
#endif
    if (fast == rows) return;
    if (c != 16) gather(s, cstride, pstride, fast, rows, c, nwords, words, j0);
    else if (nwords == 3) gather(s, cstride, pstride, fast, rows, 16, 3, words, j0);
    else if (nwords == 1) gather(s, cstride, pstride, fast, rows, 16, 1, words, j0);
    else if (nwords == 2) gather(s, cstride, pstride, fast, rows, 16, 2, words, j0);
    else gather(s, cstride, pstride, fast, rows, 16, nwords, words, j0);
}

/* d[j] = ((word[j] >> off) & mask) << upshift in 32 bits, then narrowed to the field's type: the same
 * bits as the NumPy twin's narrowing before the up-shift (a left shift only moves bits up). */
#define VALUE(TYPE, x) ((TYPE)((((x) >> off) & mask) << upshift))

/* One field of a block of rows, scalar: out[row * w + mids[j]] for rows [0, rows) of the scratch. */
#define EXTRACT(NAME, TYPE)                                                                                       \
    static void NAME(const uint32_t (*restrict word)[MAX_COLUMNS], Py_ssize_t rows, Py_ssize_t c,              \
                     const int64_t *restrict mids, int consecutive, unsigned off, uint32_t mask,               \
                     unsigned upshift, TYPE *restrict out, Py_ssize_t w) {                                       \
        if (!consecutive) { /* columns out of order within the packet: rare */                                  \
            for (Py_ssize_t r = 0; r < rows; r++)                                                               \
                for (Py_ssize_t j = 0; j < c; j++) out[r * w + mids[j]] = VALUE(TYPE, word[r][j]);              \
            return;                                                                                             \
        }                                                                                                       \
        out += mids[0];                                                                                         \
        for (Py_ssize_t r = 0; r < rows; r++)                                                                   \
            for (Py_ssize_t j = 0; j < c; j++) out[r * w + j] = VALUE(TYPE, word[r][j]);                        \
    }

EXTRACT(extract_u8, uint8_t)
EXTRACT(extract_u16, uint16_t)
EXTRACT(extract_u32, uint32_t)

#if defined(__SSE2__)
/* The vector extraction of 16 consecutive columns does only the operations a field needs, chosen
 * once per call (vector_kind): */
enum {
    SRL = 1,  /* x >> off */
    SRA = 2,  /* x >> 16 arithmetic: a 16-bit field at the top, already sign-extended for the pack */
    AND = 4,  /* & mask, the mask cut to the type's width (so the packs never saturate) */
    SHL = 8,  /* << upshift */
    SEXT = 16 /* 16-bit values of 0x8000 or more sign-extended from bit 15, so that the signed
                 saturating pack gives back those 16 bits */
};

/* The kind of a field and its mask cut to the type: the value before narrowing is then < 2^(8 bytes). */
static int vector_kind(Py_ssize_t bytes, unsigned off, uint32_t mask, unsigned upshift, uint32_t *cut) {
    uint32_t present = 0xFFFFFFFFu >> off;
    uint32_t type = bytes == 4 ? 0xFFFFFFFFu : (0xFFFFFFFFu >> (32 - 8 * bytes)) >> upshift;
    uint32_t m = mask & type;
    int kind = (off ? SRL : 0) | ((m & present) != present ? AND : 0) | (upshift ? SHL : 0);
    *cut = m;
    if (bytes == 2 && (uint64_t)(m & present) << upshift > 0x7FFF) {
        if (kind == SRL && off == 16) kind = SRA;
        else kind |= SEXT;
    }
    return kind;
}

/* Rows [0, rows) of one field, columns [0, ncols) (a multiple of 16), from the scratch to out[row * w]. */
static inline __attribute__((always_inline)) void extract_rows(const uint32_t (*restrict word)[MAX_COLUMNS],
                                                               Py_ssize_t rows, Py_ssize_t ncols, int bytes, int kind,
                                                               __m128i sr, __m128i m, __m128i sl,
                                                               unsigned char *restrict out, Py_ssize_t w) {
    for (Py_ssize_t r = 0; r < rows; r++)
    for (Py_ssize_t j = 0; j < ncols; j += 16) {
        __m128i v[4];
        for (int i = 0; i < 4; i++) {
            __m128i x = _mm_loadu_si128((const __m128i *)(word[r] + j + 4 * i));
            if (kind & SRL) x = _mm_srl_epi32(x, sr);
            if (kind & SRA) x = _mm_srai_epi32(x, 16);
            if (kind & AND) x = _mm_and_si128(x, m);
            if (kind & SHL) x = _mm_sll_epi32(x, sl);
            if (kind & SEXT) x = _mm_srai_epi32(_mm_slli_epi32(x, 16), 16);
            v[i] = x;
        }
        __m128i *d = (__m128i *)(out + (r * w + j) * bytes);
        if (bytes == 4) {
            for (int i = 0; i < 4; i++) _mm_storeu_si128(d + i, v[i]);
        } else if (bytes == 2) {
            _mm_storeu_si128(d, _mm_packs_epi32(v[0], v[1]));
            _mm_storeu_si128(d + 1, _mm_packs_epi32(v[2], v[3]));
        } else {
            _mm_storeu_si128(d, _mm_packus_epi16(_mm_packs_epi32(v[0], v[1]), _mm_packs_epi32(v[2], v[3])));
        }
    }
}

/* extract_rows with the kind and width as constants, so that each variant has only its operations. */
static inline __attribute__((always_inline)) void extract16_rows(const uint32_t (*restrict word)[MAX_COLUMNS],
                                                                 Py_ssize_t rows, Py_ssize_t ncols, int bytes,
                                                                 int kind, unsigned off,
                                                                 uint32_t mask, unsigned upshift,
                                                                 unsigned char *restrict out, Py_ssize_t w) {
    const __m128i sr = _mm_cvtsi32_si128((int)off), sl = _mm_cvtsi32_si128((int)upshift), m = _mm_set1_epi32((int)mask);
#define KIND(B, K)                                                                                                    \
    case (B) * 32 + (K):                                                                                              \
        if (ncols == 16 * GROUP) /* a whole group, the common case: the constant unrolls the columns */       \
            extract_rows(word, rows, 16 * GROUP, B, K, sr, m, sl, out, w);                                           \
        else                                                                                                          \
            extract_rows(word, rows, ncols, B, K, sr, m, sl, out, w);                                                \
        return;
#define KINDS(B)                                                                                                      \
    KIND(B, 0) KIND(B, SRL) KIND(B, AND) KIND(B, SRL | AND) KIND(B, SHL) KIND(B, SRL | SHL) KIND(B, AND | SHL)        \
    KIND(B, SRL | AND | SHL)
    switch (bytes * 32 + kind) {
        KINDS(1)
        KINDS(4)
        KINDS(2)
        KIND(2, SRA)
        KIND(2, SEXT) KIND(2, SRL | SEXT) KIND(2, AND | SEXT) KIND(2, SRL | AND | SEXT) KIND(2, SHL | SEXT)
        KIND(2, SRL | SHL | SEXT) KIND(2, AND | SHL | SEXT) KIND(2, SRL | AND | SHL | SEXT)
    }
#undef KINDS
#undef KIND
}
#endif

#define MAX_FIELDS 16

typedef struct {
    Py_ssize_t word, itemsize;
    unsigned off, upshift;
    uint32_t mask;
    void *out;
#if defined(__SSE2__)
    int kind;     /* see vector_kind */
    uint32_t cut; /* the mask cut to the type */
#endif
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
        field_plan *f = &plans[i];
        *f = (field_plan){.word = s[0], .itemsize = v->itemsize, .off = (unsigned)s[1], .upshift = (unsigned)s[3],
                          .mask = s[2] ? (uint32_t)s[2] : 0xFFFFFFFFu, .out = v->buf};
#if defined(__SSE2__)
        f->kind = vector_kind(f->itemsize, f->off, f->mask, f->upshift, &f->cut);
#endif
    }
    return 0;
}

/* The packets into the fields (arguments checked). MULTIVERSION: the AVX2 clone's three-operand VEX
 * encoding needs fewer register copies (about 15% fewer instructions). */
MULTIVERSION
static void scatter_packets(const unsigned char *base, Py_ssize_t stride, Py_ssize_t n, Py_ssize_t c, Py_ssize_t h,
                            Py_ssize_t w, Py_ssize_t at, Py_ssize_t column_bytes, Py_ssize_t pixel_bytes,
                            Py_ssize_t fast_h, const int64_t *mids, const field_plan *plans, Py_ssize_t nf) {
    Py_ssize_t nwords = pixel_bytes / 4;
    scratch_t words;
    /* A block of rows of GROUP packets in turn, then the next block: the rows of GROUP * 16 columns
     * are written while their cache lines are in L1 (one packet's row is 16 or 32 bytes of a line
     * for 8- and 16-bit fields), and each pixel still gets the last packet's value. */
    for (Py_ssize_t p0 = 0; p0 < n; p0 += GROUP) {
        Py_ssize_t p1 = p0 + GROUP < n ? p0 + GROUP : n;
        int consecutive[GROUP], run = c == 16;
        for (Py_ssize_t p = p0; p < p1; p++) {
            const int64_t *m = mids + p * c;
            int k = m[c - 1] - m[0] == c - 1;
            for (Py_ssize_t j = 1; k && j < c; j++) k = m[j] == m[j - 1] + 1;
            consecutive[p - p0] = k;
            run = run && k && m[0] == mids[p0 * c] + 16 * (p - p0);
        }
        for (Py_ssize_t row = 0; row < h; row += BLOCK_ROWS) {
            Py_ssize_t rows = h - row < BLOCK_ROWS ? h - row : BLOCK_ROWS;
            Py_ssize_t fast = fast_h - row < 0 ? 0 : fast_h - row < rows ? fast_h - row : rows;
#if defined(__SSE2__)
            if (run) { /* the group's 16 * (p1 - p0) columns side by side in the frame: one pass per field */
                for (Py_ssize_t p = p0; p < p1; p++)
                    gather_block(base + p * stride + at + row * pixel_bytes, column_bytes, pixel_bytes, fast, rows, 16,
                                 nwords, words, 16 * (p - p0));
                for (Py_ssize_t i = 0; i < nf; i++) {
                    const field_plan *f = &plans[i];
                    extract16_rows(words[f->word], rows, 16 * (p1 - p0), (int)f->itemsize, f->kind, f->off, f->cut,
                                   f->upshift, (unsigned char *)f->out + (row * w + mids[p0 * c]) * f->itemsize, w);
                }
                continue;
            }
#endif
            for (Py_ssize_t p = p0; p < p1; p++) {
                const int64_t *m = mids + p * c;
                const unsigned char *col0 = base + p * stride + at;
                gather_block(col0 + row * pixel_bytes, column_bytes, pixel_bytes, fast, rows, c, nwords, words, 0);
                for (Py_ssize_t i = 0; i < nf; i++) {
                    const field_plan *f = &plans[i];
                    int cons = consecutive[p - p0];
#if defined(__SSE2__)
                    if (c == 16 && cons) {
                        extract16_rows(words[f->word], rows, 16, (int)f->itemsize, f->kind, f->off, f->cut, f->upshift,
                                       (unsigned char *)f->out + (row * w + m[0]) * f->itemsize, w);
                        continue;
                    }
#endif
                    if (f->itemsize == 1)
                        extract_u8(words[f->word], rows, c, m, cons, f->off, f->mask, f->upshift,
                                   (uint8_t *)f->out + row * w, w);
                    else if (f->itemsize == 2)
                        extract_u16(words[f->word], rows, c, m, cons, f->off, f->mask, f->upshift,
                                    (uint16_t *)f->out + row * w, w);
                    else
                        extract_u32(words[f->word], rows, c, m, cons, f->off, f->mask, f->upshift,
                                    (uint32_t *)f->out + row * w, w);
                }
            }
        }
    }
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
    if (n < 0 || c < 1 || c > MAX_COLUMNS || pixel_bytes > 4 * MAX_WORDS || pb.strides[1] != 1 || mb.ndim != 2 || mb.shape[0] != n || !is_native(mb.format, INTEGER_CODES) ||
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
        Py_ssize_t nf = got, fast_h = 0;
#ifdef VECTOR_GATHER
        Py_ssize_t nwords = pixel_bytes / 4;
        /* fast_h: the leading rows that gather16 reads, in loads of `per` pixels; the last load of the
         * last column must end inside the packet row (L bytes), else those rows take the scalar copy */
        Py_ssize_t per = nwords == 3 ? 1 : 4 / nwords;
        Py_ssize_t room = pb.shape[1] - 16 - (columns_at + 15 * column_bytes + pixels_at);
        if (c == 16 && pixel_bytes % 4 == 0 && room >= 0) {
            fast_h = room / (per * pixel_bytes) + 1;
            fast_h = per * (fast_h < h / per ? fast_h : h / per);
        }
#endif
        Py_BEGIN_ALLOW_THREADS
        scatter_packets(base, pb.strides[0], n, c, h, w, columns_at + pixels_at, column_bytes, pixel_bytes, fast_h,
                        mids, plans, nf);
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
