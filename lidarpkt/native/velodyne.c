/* Velodyne: packets into range-image columns (the VLP-16's, and any model's from its layout table), and XYZ
 * from ranges and firing azimuths. */
#include "common.h"

/* velodyne_xyz(range, azimuth, cos, neg_sin, coef, has_dist, has_voff, out)
 *
 * range: uint32 [R, H, W]; azimuth: uint16 [H, W] (0.01 degree, < 36000); cos, neg_sin: float64
 * [T, 36000] with T = 1 (one table) or H (one per row); coef: float64 [5, H] (k_xy, k_z, dc_xy,
 * dc_z, vert_offset per row) or [7, H] (and cos r, sin r of each row's azimuth correction r, with
 * one table: cos(a - r) = cos a cos r - neg_sin a sin r, neg_sin(a - r) = neg_sin a cos r + cos a sin r);
 * out: float64 [R, H, W, 3]; range and azimuth any row strides with each row contiguous (a frame's views of
 * its columns), the rest C-contiguous. The operations and their order are those of
 * VelodyneGeometry._points (its NumPy twin), so the bytes are the same:
 *   hit = range > 0; dxy = range * k_xy; dz = range * k_z;
 *   if has_dist: dxy += hit * dc_xy; dz += hit * dc_z
 *   x = dxy * cos[a]; y = dxy * neg_sin[a]; if has_voff: dz = (dz + voff) * hit; z = dz
 * Raises IndexError for an azimuth of 36000 or more (as NumPy's table lookup does).
 */
/* A double written past the caches (x86-64: MOVNTI of its bits): a frame's points are written once and not
 * read by the kernel, and an ordinary store first reads the line it writes (twice the memory traffic for
 * an image larger than the caches). Elsewhere an ordinary store. velodyne_xyz fences them before it returns. */
#if defined(__x86_64__)
#include <emmintrin.h>
static inline void store_nt(double *p, double v) {
    long long bits;
    memcpy(&bits, &v, 8);
    _mm_stream_si64((long long *)p, bits);
}
#define STORE_FENCE() _mm_sfence()
#else
static inline void store_nt(double *p, double v) { *p = v; }
#define STORE_FENCE() ((void)0)
#endif

MULTIVERSION
static void velodyne_xyz_rows(const uint32_t *restrict rng, const uint16_t *restrict az, const double *restrict cos_t,
                              const double *restrict nsin_t, double kxy, double kz, double dcxy, double dcz,
                              double voff, int has_dist, int has_voff, int has_rot, double cr, double sr,
                              double *restrict out, Py_ssize_t w) {
    for (Py_ssize_t i = 0; i < w; i++) {
        uint32_t v = rng[i];
        double hit = v > 0 ? 1.0 : 0.0, s = (double)v;
        double dxy = s * kxy, dz = s * kz;
        if (has_dist) {
            dxy = dxy + hit * dcxy;
            dz = dz + hit * dcz;
        }
        double c = cos_t[az[i]], ns = nsin_t[az[i]];
        if (has_rot) {
            double c2 = c * cr - ns * sr;
            ns = ns * cr + c * sr;
            c = c2;
        }
        if (has_voff) dz = (dz + voff) * hit;
        store_nt(out + 3 * i, dxy * c);
        store_nt(out + 3 * i + 1, dxy * ns);
        store_nt(out + 3 * i + 2, dz);
    }
}

/* The largest of n uint16 (0 for none): a reduction the compiler vectorises, where a loop that stops at the
 * first bad azimuth is not. */
static uint16_t max_u16(const uint16_t *restrict v, Py_ssize_t n) {
    uint16_t m = 0;
    for (Py_ssize_t i = 0; i < n; i++) m = v[i] > m ? v[i] : m;
    return m;
}

PyObject *lp_velodyne_xyz(PyObject *self, PyObject *args) {
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
        /* range and azimuth may be views of a frame's columns: rows apart, each row contiguous */
        int flags = (got < 2 ? PyBUF_STRIDES : PyBUF_C_CONTIGUOUS) | PyBUF_FORMAT | (got == 5 ? PyBUF_WRITABLE : 0);
        if (get_buffer(objs[got], &b[got], flags, sizes[got], "velodyne_xyz") < 0) goto done;
        if (!is_native(b[got].format, codes[got])) {
            PyErr_SetString(PyExc_ValueError, "velodyne_xyz: range uint32, azimuth uint16, the rest float64");
            got++;
            goto done;
        }
    }
    {
        if (b[0].ndim != 3 || b[1].ndim != 2 || b[0].strides[2] != 4 || b[1].strides[1] != 2) {
            PyErr_SetString(PyExc_ValueError, "velodyne_xyz: range [R, H, W] and azimuth [H, W], rows contiguous");
            goto done;
        }
        Py_ssize_t returns = b[0].shape[0], h_rows = b[0].shape[1], w = b[0].shape[2];
        Py_ssize_t ncoef = b[4].len / 8, table = 36000;
        int has_rot = h_rows > 0 && ncoef == 7 * h_rows;
        Py_ssize_t rows_t = b[2].len / 8 / table;
        if (h_rows == 0 || w == 0 || b[1].shape[0] != h_rows || b[1].shape[1] != w ||
            (ncoef != 5 * h_rows && !has_rot) || b[5].len != returns * h_rows * w * 24 || b[2].len != b[3].len ||
            (rows_t != 1 && rows_t != h_rows) || (has_rot && rows_t != 1) || b[2].len != rows_t * table * 8) {
            PyErr_SetString(PyExc_ValueError, "velodyne_xyz: arrays of disagreeing sizes");
            goto done;
        }
        const char *az_rows = (const char *)b[1].buf, *rng_rows = (const char *)b[0].buf;
        Py_ssize_t az_stride = b[1].strides[0], r_stride = b[0].strides[0], h_stride = b[0].strides[1];
        for (Py_ssize_t h = 0; h < h_rows; h++) {
            const uint16_t *az = (const uint16_t *)(az_rows + h * az_stride);
            if (max_u16(az, w) >= table) {
                Py_ssize_t i = 0;
                while (az[i] < table) i++;
                PyErr_Format(PyExc_IndexError, "velodyne_xyz: azimuth %d (0.01 degree) is 360 degrees or more", az[i]);
                goto done;
            }
        }
        const double *cos_t = (const double *)b[2].buf, *nsin_t = (const double *)b[3].buf;
        const double *coef = (const double *)b[4].buf;
        double *out = (double *)b[5].buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t r = 0; r < returns; r++) {
            for (Py_ssize_t h = 0; h < h_rows; h++) {
                Py_ssize_t t = rows_t == h_rows && rows_t > 1 ? h * table : 0;
                velodyne_xyz_rows((const uint32_t *)(rng_rows + r * r_stride + h * h_stride),
                                  (const uint16_t *)(az_rows + h * az_stride), cos_t + t, nsin_t + t, coef[h],
                                  coef[h_rows + h], coef[2 * h_rows + h], coef[3 * h_rows + h], coef[4 * h_rows + h],
                                  has_dist, has_voff, has_rot, has_rot ? coef[5 * h_rows + h] : 1.0,
                                  has_rot ? coef[6 * h_rows + h] : 0.0, out + (r * h_rows + h) * w * 3, w);
            }
        }
        STORE_FENCE();
        Py_END_ALLOW_THREADS
    }
    result = Py_NewRef(Py_None);
done:
    return release_buffers(b, got, result);
}

/* velodyne_columns(distance, reflectivity, azimuth, rate, dt, lasers, slots, range_out, refl_out, az_out)
 *
 * The VLP-16 packets of a batch into range-image columns, as lidarpkt.vendors.velodyne.decode.column_pixels's
 * NumPy twin: distance uint16 [N, 12, 32] and reflectivity uint8 [N, 12, 32] (any strides: views of the
 * 3-byte records of the payloads), azimuth uint16 [N, 12] (the block azimuths, any strides), rate float32
 * [N] (each packet's rotation rate, 0.01 degree per second), dt float32 [12 / slots, 32] (the delay of each
 * firing after its block's first, seconds), lasers int64 [16] (the laser of each row, each < 16), slots 1
 * or 2 (dual: block b is slot b % 2); outputs C-contiguous range_out uint32 [slots, 16, W], refl_out uint8
 * [slots, 16, W], az_out uint16 [16, W] with W = N * (12 / slots) * 2. Column (p * B + bb) * 2 + seq of row
 * r (B = 12 / slots) holds channel seq * 16 + lasers[r] of block bb * slots + slot of packet p; range = 2 *
 * distance (mm); its firing azimuth is lround(azimuth[p][bb * slots] + rate[p] * dt[bb][channel]) mod 36000,
 * summed in float32 in lidarpkt.vendors.velodyne.timing.firing_azimuths's order (rate * dt, + azimuth,
 * + 36000, + 0.5, truncated): one firing-azimuth tile per packet in L1, then spread over the rows.
 */
/* floor(rate * dt + az + 36000 + 0.5) summed in float32 in the twin's order (rate * dt, + az, + 36000, + 0.5,
 * truncated) less 36000, then the floor modulo 36000 by three subtractions: exact for sums below 4 * 36000;
 * outside [0, 36000) the caller redoes the pixel with azimuth_mod (no valid azimuth gets there) */
static inline int32_t firing_azimuth(float rate, float dt, float az) {
    float v = rate * dt;
    v += az;
    v += 36000.0f;
    v += 0.5f;
    int32_t r = (int32_t)v - 36000;
    r = r >= 36000 ? r - 36000 : r;
    r = r >= 36000 ? r - 36000 : r;
    return r >= 36000 ? r - 36000 : r;
}

/* The firing azimuths of one packet: tile[bb * 32 + k] for the blocks' azimuths az[bb] (bps of them) */
MULTIVERSION
static void firing_tile(const float *restrict dt, float rate, const float *restrict az, Py_ssize_t bps,
                        int32_t *restrict tile) {
    for (Py_ssize_t bb = 0; bb < bps; bb++) {
        const float *d = dt + bb * 32;
        int32_t *out = tile + bb * 32;
        float a = az[bb];
        for (int k = 0; k < 32; k++) out[k] = firing_azimuth(rate, d[k], a);  /* in [0, 36000) for 16-bit azimuths */
    }
}

static inline void columns_chunk(const char *dist, const char *refl, Py_ssize_t ds0, Py_ssize_t ds1, Py_ssize_t ds2,
                                 Py_ssize_t rs0, Py_ssize_t rs1, Py_ssize_t rs2, const int64_t *lasers, int slots,
                                 Py_ssize_t p0, Py_ssize_t p1, Py_ssize_t w, uint32_t *rng_out, uint8_t *refl_out) {
    Py_ssize_t bps = 12 / slots;
    for (int slot = 0; slot < slots; slot++) {
        for (int r = 0; r < 16; r++) {
            Py_ssize_t laser = lasers[r];
            uint32_t *ro = rng_out + ((Py_ssize_t)slot * 16 + r) * w;
            uint8_t *fo = refl_out + ((Py_ssize_t)slot * 16 + r) * w;
            for (Py_ssize_t p = p0; p < p1; p++) {
                const char *dp = dist + p * ds0 + slot * ds1 + laser * ds2;
                const char *rp = refl + p * rs0 + slot * rs1 + laser * rs2;
                Py_ssize_t c = p * bps * 2;
                for (Py_ssize_t bb = 0; bb < bps; bb++) {
                    const char *d = dp + bb * slots * ds1, *f = rp + bb * slots * rs1;
                    ro[c + 2 * bb] = 2u * (uint32_t)load_u16(d);
                    ro[c + 2 * bb + 1] = 2u * (uint32_t)load_u16(d + 16 * ds2);
                    fo[c + 2 * bb] = (uint8_t)f[0];
                    fo[c + 2 * bb + 1] = (uint8_t)f[16 * rs2];
                }
            }
        }
    }
}

PyObject *lp_velodyne_columns(PyObject *self, PyObject *args) {
    PyObject *o[9];
    int slots;
    if (!PyArg_ParseTuple(args, "OOOOOOiOOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &slots, &o[6], &o[7], &o[8]))
        return NULL;
    static const Py_ssize_t sizes[9] = {2, 1, 2, 4, 4, 8, 4, 1, 2};
    static const char *codes[9] = {"H", "B", "H", "f", "f", INTEGER_CODES, "IL", "B", "H"};
    Py_buffer b[9];
    int got = 0;
    PyObject *result = NULL;
    for (; got < 9; got++) {
        int flags = got < 3 ? PyBUF_STRIDES | PyBUF_FORMAT
                            : PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (got >= 6 ? PyBUF_WRITABLE : 0);
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
            b[1].shape[1] != 12 || b[1].shape[2] != 32 || b[2].ndim != 2 || b[2].shape[0] != n ||
            b[2].shape[1] != 12 || b[3].len != n * 4 || b[4].len != bps * 32 * 4 || b[5].len != 16 * 8 ||
            b[6].len != slots * 16 * w * 4 || b[7].len != slots * 16 * w || b[8].len != 16 * w * 2) {
            PyErr_SetString(PyExc_ValueError, "velodyne_columns: arrays of disagreeing shapes");
            goto done;
        }
        const int64_t *lasers = (const int64_t *)b[5].buf;
        for (int r = 0; r < 16; r++) {
            if (lasers[r] < 0 || lasers[r] > 15) {
                PyErr_SetString(PyExc_ValueError, "velodyne_columns: a laser number outside 0-15");
                goto done;
            }
        }
        const char *dist = (const char *)b[0].buf, *refl = (const char *)b[1].buf, *azb = (const char *)b[2].buf;
        const Py_ssize_t *ds = b[0].strides, *rs = b[1].strides, *as = b[2].strides;
        const float *rate = (const float *)b[3].buf, *dt = (const float *)b[4].buf;
        uint32_t *rng_out = (uint32_t *)b[6].buf;
        uint8_t *refl_out = (uint8_t *)b[7].buf;
        uint16_t *az_out = (uint16_t *)b[8].buf;
        /* the records of packets viewed in place (strides 1206, 100, 3): constant strides let the compiler
         * fold the address arithmetic */
        int packed = ds[0] == 1206 && ds[1] == 100 && ds[2] == 3 && rs[0] == 1206 && rs[1] == 100 && rs[2] == 3;
        Py_BEGIN_ALLOW_THREADS
        int32_t tile[12 * 32];
        /* packets in chunks whose records stay in L2 (64 x 1.2 kB); per chunk, row by row, so that each output
         * row is written contiguously (a packet at a time touched 80 rows ~300 kB apart) */
        for (Py_ssize_t p0 = 0; p0 < n; p0 += 64) {
            Py_ssize_t p1 = p0 + 64 < n ? p0 + 64 : n;
            if (packed)
                columns_chunk(dist, refl, 1206, 100, 3, 1206, 100, 3, lasers, slots, p0, p1, w, rng_out, refl_out);
            else
                columns_chunk(dist, refl, ds[0], ds[1], ds[2], rs[0], rs[1], rs[2], lasers, slots, p0, p1, w, rng_out,
                              refl_out);
            for (Py_ssize_t p = p0; p < p1; p++) {
                float azf[12];
                for (Py_ssize_t bb = 0; bb < bps; bb++) azf[bb] = (float)load_u16(azb + p * as[0] + bb * slots * as[1]);
                firing_tile(dt, rate[p], azf, bps, tile);
                Py_ssize_t c = p * bps * 2;
                for (int r = 0; r < 16; r++) {
                    uint16_t *ao = az_out + (Py_ssize_t)r * w + c;
                    const int32_t *t = tile + lasers[r];
                    for (Py_ssize_t bb = 0; bb < bps; bb++) {
                        ao[2 * bb] = (uint16_t)t[bb * 32];
                        ao[2 * bb + 1] = (uint16_t)t[bb * 32 + 16];
                    }
                }
            }
        }
        Py_END_ALLOW_THREADS
    }
    result = Py_NewRef(Py_None);
done:
    return release_buffers(b, got, result);
}

/* velodyne_layout_columns(distance, reflectivity, azimuth, source, azimuth_block, dt, rate, unit, range_out,
 *                         refl_out, az_out)
 *
 * Any model's packets into range-image columns, as lidarpkt.vendors.velodyne.decode.layout_pixels (its NumPy twin):
 * distance uint16 [N, 12, 32], reflectivity uint8 [N, 12, 32], azimuth uint16 [N, 12] (any strides: views
 * of the payloads); source int64 [S, L, C] (channel b * 32 + j of every pixel, rows in frame order),
 * azimuth_block int64 [L, C] and dt float32 [L, C] (the block whose azimuth a row's firing takes, and its
 * delay after that block's reference firing, float32 seconds), rate float32 [N] (0.01 degree per second),
 * unit: mm per distance unit; outputs C-contiguous range_out uint32 [S, L, N * C], refl_out uint8
 * [S, L, N * C], az_out uint16 [L, N * C]. Azimuth = lround(block azimuth + rate * dt) mod 36000 in
 * float32, summed in the twin's order (rate * dt, + azimuth, + 36000, + 0.5, truncated).
 */
/* One pixel of m packets (records `dstride` / `rstride` bytes apart) into every c-th element of a row: scalar
 * (vectorised, the strided loads and stores cost GCC's SSE2 code several times more instructions) */
__attribute__((optimize("no-tree-vectorize")))
static void strided_pixels(const char *dp, Py_ssize_t dstride, const char *rp, Py_ssize_t rstride, uint32_t unit,
                           Py_ssize_t m, uint32_t *ro, uint8_t *fo, Py_ssize_t c) {
    for (Py_ssize_t p = 0; p < m; p++) {
        ro[p * c] = unit * (uint32_t)load_u16(dp + p * dstride);
        fo[p * c] = (uint8_t)rp[p * rstride];
    }
}

/* One pixel's firing azimuth in m packets: out[p] = firing_azimuth(rate[p], dt, az[p]) (rate and the pixel's
 * block azimuths contiguous, so the loop vectorises); whether one fell outside [0, 36000) (then the caller redoes
 * them with azimuth_mod) */
MULTIVERSION
static int firing_run(const float *restrict rate, float dt, const float *restrict az, Py_ssize_t m,
                      int32_t *restrict out) {
    int32_t outside = 0;
    for (Py_ssize_t p = 0; p < m; p++) {
        int32_t v = firing_azimuth(rate[p], dt, az[p]);
        outside |= (v < 0) | (v >= 36000);
        out[p] = v;
    }
    return outside != 0;
}

static int32_t azimuth_mod(float rate, float dt, float az) {
    float v = rate * dt;
    v += az;
    v += 36000.0f;
    v += 0.5f;
    int32_t t = (int32_t)v;
    return ((t % 36000) + 36000) % 36000;
}

PyObject *lp_velodyne_layout_columns(PyObject *self, PyObject *args) {
    PyObject *o[10];
    unsigned int unit;
    if (!PyArg_ParseTuple(args, "OOOOOOOIOOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &unit, &o[7], &o[8],
                          &o[9]))
        return NULL;
    static const Py_ssize_t sizes[10] = {2, 1, 2, 8, 8, 4, 4, 4, 1, 2};
    static const char *codes[10] = {"H", "B", "H", INTEGER_CODES, INTEGER_CODES, "f", "f", "IL", "B", "H"};
    Py_buffer b[10];
    int got = 0;
    PyObject *result = NULL;
    for (; got < 10; got++) {
        int flags = got < 3 ? PyBUF_STRIDES | PyBUF_FORMAT
                            : PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (got >= 7 ? PyBUF_WRITABLE : 0);
        if (get_buffer(o[got], &b[got], flags, sizes[got], "velodyne_layout_columns") < 0) goto done;
        if (!is_native(b[got].format, codes[got])) {
            PyErr_SetString(PyExc_ValueError, "velodyne_layout_columns: unexpected item types");
            got++;
            goto done;
        }
    }
    {
        Py_ssize_t n = b[0].ndim == 3 ? b[0].shape[0] : -1;
        Py_ssize_t s = b[3].ndim == 3 ? b[3].shape[0] : 0, l = b[3].ndim == 3 ? b[3].shape[1] : 0;
        Py_ssize_t c = b[3].ndim == 3 ? b[3].shape[2] : 0, w = n * c;
        if (n < 0 || b[0].shape[1] != 12 || b[0].shape[2] != 32 || b[1].ndim != 3 || b[1].shape[0] != n ||
            b[1].shape[1] != 12 || b[1].shape[2] != 32 || b[2].ndim != 2 || b[2].shape[0] != n ||
            b[2].shape[1] != 12 || s < 1 || b[4].len != l * c * 8 || b[5].len != l * c * 4 || b[6].len != n * 4 ||
            b[7].len != s * l * w * 4 || b[8].len != s * l * w || b[9].len != l * w * 2) {
            PyErr_SetString(PyExc_ValueError, "velodyne_layout_columns: arrays of disagreeing shapes");
            goto done;
        }
        const int64_t *src = (const int64_t *)b[3].buf, *azb = (const int64_t *)b[4].buf;
        for (Py_ssize_t i = 0; i < s * l * c; i++) {
            if (src[i] < 0 || src[i] >= 12 * 32 || (i < l * c && (azb[i] < 0 || azb[i] >= 12))) {
                PyErr_SetString(PyExc_ValueError, "velodyne_layout_columns: a channel or block outside the packet");
                goto done;
            }
        }
        const char *dist = (const char *)b[0].buf, *refl = (const char *)b[1].buf, *azp = (const char *)b[2].buf;
        const Py_ssize_t *ds = b[0].strides, *rs = b[1].strides, *as = b[2].strides;
        const float *dt = (const float *)b[5].buf, *rate = (const float *)b[6].buf;
        uint32_t *rng_out = (uint32_t *)b[7].buf;
        uint8_t *refl_out = (uint8_t *)b[8].buf;
        uint16_t *az_out = (uint16_t *)b[9].buf;
        Py_BEGIN_ALLOW_THREADS
        float azt[12 * 64]; /* a chunk's block azimuths, block by block */
        int32_t run[64]; /* one pixel's firing azimuths in the chunk's packets */
        /* packets in chunks of 64 (their records stay in L2); per chunk, pixel (row, k) by pixel with the packets
         * in the inner loop: a pixel's offsets are constant there, and each row is written in order */
        for (Py_ssize_t p0 = 0; p0 < n; p0 += 64) {
            Py_ssize_t m = (p0 + 64 < n ? p0 + 64 : n) - p0;
            for (Py_ssize_t row = 0; row < s * l; row++) {
                for (Py_ssize_t k = 0; k < c; k++) {
                    Py_ssize_t blk = src[row * c + k] >> 5, ch = src[row * c + k] & 31;
                    const char *dp = dist + p0 * ds[0] + blk * ds[1] + ch * ds[2];
                    const char *rp = refl + p0 * rs[0] + blk * rs[1] + ch * rs[2];
                    strided_pixels(dp, ds[0], rp, rs[0], unit, m, rng_out + row * w + p0 * c + k,
                                   refl_out + row * w + p0 * c + k, c);
                }
            }
            /* the chunk's block azimuths block-major, as float: azt[blk][p] */
            for (int blk = 0; blk < 12; blk++)
                for (Py_ssize_t p = 0; p < m; p++) azt[blk * 64 + p] = (float)load_u16(azp + (p0 + p) * as[0] + blk * as[1]);
            for (Py_ssize_t row = 0; row < l; row++) {
                for (Py_ssize_t k = 0; k < c; k++) {
                    Py_ssize_t i = row * c + k;
                    const float *a = azt + azb[i] * 64;
                    if (firing_run(rate + p0, dt[i], a, m, run))
                        for (Py_ssize_t p = 0; p < m; p++) run[p] = azimuth_mod(rate[p0 + p], dt[i], a[p]);
                    uint16_t *ao = az_out + row * w + p0 * c + k;
                    for (Py_ssize_t p = 0; p < m; p++) ao[p * c] = (uint16_t)run[p];
                }
            }
        }
        Py_END_ALLOW_THREADS
    }
    result = Py_NewRef(Py_None);
done:
    return release_buffers(b, got, result);
}

/* dual_mark(range, reflectivity, out) -> bool
 *
 * The rule of lidarpkt.core.dual.second_strongest_mark (its NumPy twin) in one pass: range uint32 [2, H, W]
 * (slot 0 the last return, slot 1 the other, mm) and reflectivity uint8 [2, H, W], any strides (a frame's
 * views of its columns); out bool [H, W], C-contiguous. out = both ranges non-zero and different, and
 * refl0 * range1^2 > refl1 * range0^2: exact in double for ranges below 2^22 mm (255 * 2^44 < 2^53), which
 * vectorises where 64-bit integer products do not. Returns False, out unspecified, when a range is 2^22 or
 * more (the caller then takes the twin), True otherwise.
 */
static inline uint8_t dual_mark_one(uint32_t a, uint32_t c, uint8_t f0, uint8_t f1) {
    double da = (double)(int32_t)(a & 0x3FFFFF), dc = (double)(int32_t)(c & 0x3FFFFF);
    return (uint8_t)((a != c) & (a != 0) & (c != 0) & ((double)f0 * dc * dc > (double)f1 * da * da));
}

/* one row; the unit-stride case (a frame's rows) in a loop the compiler vectorises */
MULTIVERSION
static uint32_t dual_mark_row(const char *r0, const char *r1, Py_ssize_t rs, const char *f0, const char *f1,
                              Py_ssize_t fs, uint8_t *restrict out, Py_ssize_t w) {
    uint32_t large = 0;
    if (rs == 4 && fs == 1) {
        const uint32_t *a = (const uint32_t *)r0, *c = (const uint32_t *)r1;
        const uint8_t *g0 = (const uint8_t *)f0, *g1 = (const uint8_t *)f1;
        for (Py_ssize_t i = 0; i < w; i++) {
            large |= a[i] | c[i];
            out[i] = dual_mark_one(a[i], c[i], g0[i], g1[i]);
        }
        return large;
    }
    for (Py_ssize_t i = 0; i < w; i++) {
        uint32_t a, c;
        memcpy(&a, r0 + i * rs, 4);
        memcpy(&c, r1 + i * rs, 4);
        large |= a | c;
        out[i] = dual_mark_one(a, c, (uint8_t)f0[i * fs], (uint8_t)f1[i * fs]);
    }
    return large;
}

PyObject *lp_dual_mark(PyObject *self, PyObject *args) {
    PyObject *objs[3];
    if (!PyArg_ParseTuple(args, "OOO", &objs[0], &objs[1], &objs[2])) return NULL;
    static const Py_ssize_t sizes[3] = {4, 1, 1};
    static const char *codes[3] = {"IL", "B", "?"};
    Py_buffer b[3];
    int got = 0;
    PyObject *result = NULL;
    for (; got < 3; got++) {
        int flags = got == 2 ? (PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | PyBUF_WRITABLE) : (PyBUF_STRIDES | PyBUF_FORMAT);
        if (get_buffer(objs[got], &b[got], flags, sizes[got], "dual_mark") < 0) goto done;
        if (!is_native(b[got].format, codes[got])) {
            PyErr_SetString(PyExc_ValueError, "dual_mark: range uint32, reflectivity uint8, out bool");
            got++;
            goto done;
        }
    }
    {
        if (b[0].ndim != 3 || b[1].ndim != 3 || b[0].shape[0] != 2 || b[1].shape[0] != 2 ||
            b[0].shape[1] != b[1].shape[1] || b[0].shape[2] != b[1].shape[2] ||
            b[2].len != b[0].shape[1] * b[0].shape[2]) {
            PyErr_SetString(PyExc_ValueError, "dual_mark: range and reflectivity must be [2, H, W] for out [H, W]");
            goto done;
        }
        Py_ssize_t h = b[0].shape[1], w = b[0].shape[2];
        const Py_ssize_t *rs = b[0].strides, *fs = b[1].strides;
        const char *rb = (const char *)b[0].buf, *fb = (const char *)b[1].buf;
        uint8_t *out = (uint8_t *)b[2].buf;
        uint32_t large = 0;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t row = 0; row < h; row++)
            large |= dual_mark_row(rb + row * rs[1], rb + rs[0] + row * rs[1], rs[2], fb + row * fs[1],
                                   fb + fs[0] + row * fs[1], fs[2], out + row * w, w);
        Py_END_ALLOW_THREADS
        result = PyBool_FromLong((large >> 22) == 0);
    }
done:
    return release_buffers(b, got, result);
}
