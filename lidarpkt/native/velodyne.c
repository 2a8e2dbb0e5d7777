/* VLP-16: packets into range-image columns, and XYZ from ranges and firing azimuths. */
#include "common.h"

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
    result = Py_NewRef(Py_None);
done:
    return release_buffers(b, got, result);
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

PyObject *lp_velodyne_columns(PyObject *self, PyObject *args) {
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
    result = Py_NewRef(Py_None);
done:
    return release_buffers(b, got, result);
}
