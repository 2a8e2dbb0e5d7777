"""The optional C extension; everything else about the package is in pyproject.toml.

``lidarpkt._native`` (``lidarpkt/native/*.c``, one file per concern) holds the compiled kernels of lidarpkt/core/kernels.py (the pcap record walk,
row gathers, Ouster and VLP-16 XYZ, the XYZ loops with an AVX2 clone). ``optional=True``: on a machine without a C compiler the install
still succeeds and lidarpkt runs the pure-NumPy twins of the same kernels (same results, slower).
``-ffp-contract=off`` keeps ``r * d + o`` rounded twice, bit-identical to NumPy and ouster-sdk.
"""

from pathlib import Path

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "lidarpkt._native",
            sources=sorted(str(p) for p in Path("lidarpkt/native").glob("*.c")),
            depends=["lidarpkt/native/common.h"],
            optional=True,
            extra_compile_args=["-O3", "-ffp-contract=off"],
        )
    ]
)
