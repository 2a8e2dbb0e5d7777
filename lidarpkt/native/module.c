/* The one extension module `lidarpkt._native`: its method table (kernels in the other files). */
#include "common.h"

static PyMethodDef methods[] = {
    {"walk_pcap", lp_walk_pcap, METH_VARARGS, "Offsets of whole classic-pcap records; see lidarpkt/native/walk.c."},
    {"walk_pcapng", lp_walk_pcapng, METH_VARARGS, "Enhanced packet blocks of a pcapng section; see lidarpkt/native/walk.c."},
    {"gather_rows", lp_gather_rows, METH_VARARGS, "Rows of bytes at offsets of a buffer."},
    {"xyz_lut", lp_xyz_lut, METH_VARARGS, "range * direction + offset, zero where range is 0."},
    {"velodyne_columns", lp_velodyne_columns, METH_VARARGS, "VLP-16 packets into range-image columns; see native/velodyne.c."},
    {"velodyne_layout_columns", lp_velodyne_layout_columns, METH_VARARGS,
     "Any Velodyne model's packets into range-image columns by its layout table; see native/velodyne.c."},
    {"velodyne_xyz", lp_velodyne_xyz, METH_VARARGS, "VLP-16 XYZ from ranges and per-firing azimuths; see native/velodyne.c."},
    {"dual_mark", lp_dual_mark, METH_VARARGS, "VLP-16 dual return: slot 1 holds the second strongest; see native/velodyne.c."},
    {"ouster_scatter", lp_ouster_scatter, METH_VARARGS, "Ouster packets into a frame's [H, W] field arrays; see native/ouster.c."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "lidarpkt._native",
                                    "Compiled kernels of lidarpkt (optional; see lidarpkt/core/kernels.py).", -1, methods};

PyMODINIT_FUNC PyInit__native(void) { return PyModule_Create(&module); }
