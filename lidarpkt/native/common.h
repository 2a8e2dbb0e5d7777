/* Shared helpers of the compiled kernels (see lidarpkt/core/kernels.py), one file per concern:
 *   walk.c      pcap / pcapng record walks and row gathers (packet walk)
 *   xyz.c       Ouster XYZ (range * direction + offset)
 *   velodyne.c  VLP-16 columns, XYZ and the dual-return mark
 *   ouster.c    Ouster packets scattered into frame field arrays
 *   module.c    the method table of the one extension module `_lidarpkt_native`
 *
 * Every kernel has a pure-NumPy twin in the Python code and the tests check that both give the
 * same bytes. Arrays come in through the buffer protocol, so the build needs no NumPy headers.
 * The GIL is released around every loop, so the pcap read-ahead thread runs beside them.
 *
 * Compiled with -ffp-contract=off: `r * d + o` must round twice, as NumPy and ouster-sdk do.
 */
#ifndef LIDARPKT_NATIVE_COMMON_H
#define LIDARPKT_NATIVE_COMMON_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

static inline int get_buffer(PyObject *obj, Py_buffer *view, int flags, Py_ssize_t itemsize, const char *what) {
    if (PyObject_GetBuffer(obj, view, flags) < 0) return -1;
    if (view->itemsize != itemsize) {
        PyErr_Format(PyExc_ValueError, "%s: expected items of %zd bytes, got %zd", what, itemsize, view->itemsize);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

/* The epilogue of a kernel that took `got` buffers: release them, return `result` (NULL on error). */
static inline PyObject *release_buffers(Py_buffer *b, int got, PyObject *result) {
    for (int i = 0; i < got; i++) PyBuffer_Release(&b[i]);
    return result;
}

/* A buffer format of one native-order item whose code is in `codes` ("q", "=q", "<q" on a
 * little-endian machine...); the callers check the item size. */
static inline int is_native(const char *format, const char *codes) {
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

static inline uint32_t bswap32(uint32_t v) { return __builtin_bswap32(v); }

static inline uint16_t load_u16(const char *p) {
    uint16_t v;
    memcpy(&v, p, 2);
    return v;
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

/* The kernels, each in the file of its concern; module.c lists them. */
PyObject *lp_walk_pcap(PyObject *self, PyObject *args);
PyObject *lp_walk_pcapng(PyObject *self, PyObject *args);
PyObject *lp_gather_rows(PyObject *self, PyObject *args);
PyObject *lp_xyz_lut(PyObject *self, PyObject *args);
PyObject *lp_velodyne_xyz(PyObject *self, PyObject *args);
PyObject *lp_velodyne_columns(PyObject *self, PyObject *args);
PyObject *lp_velodyne_layout_columns(PyObject *self, PyObject *args);
PyObject *lp_ouster_scatter(PyObject *self, PyObject *args);
PyObject *lp_dual_mark(PyObject *self, PyObject *args);

#endif
