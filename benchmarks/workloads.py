"""One measured workload per process, for ``run_all.py``: ``python benchmarks/workloads.py KIND ARGS...``.

Each run is a whole process (interpreter start, imports and the work), so that start-up counts as a user
sees it; the last line printed is a JSON object: what was produced (frames, points) for a check that both
sides did the same work, the process's peak RSS (``VmHWM``, MB) and the largest peak RSS of its worker
processes (``children_hwm_mb``; 0 without any).

Kinds (every point or field is touched on both sides: lidarpkt frames are no lazier than the reference's):

- ``velodyne PATH [WORKERS]``: ``lidarpkt.open`` → frames, ``xyz()`` and the returns counted per frame;
- ``velodyne_decoder PATH [vlp16|auto]``: ``velodyne_decoder.read_pcap`` (point structs), points counted;
- ``ouster PATH METADATA [none|xyz32|xyz64] [WORKERS]``: ``lidarpkt.open`` → frames, one element of every
  field array read (and ``xyz(float32)`` / ``xyz()`` of each frame);
- ``ouster_sdk PATH METADATA``: ouster-sdk ``PcapFrameSetSource``, one element of every field read;
- ``osf PATH`` / ``osf_sdk PATH``: an OSF file, every stored field, by each;
- ``decode ARGS...``: ``lidarpkt decode ARGS`` (the CLI, in this process).

``WORKERS`` is ``lidarpkt.open``'s ``workers`` (``default`` leaves it to the library).
"""

from __future__ import annotations

import json
import resource
import sys
import warnings


def _workers(args: list[str], i: int):
    value = args[i] if len(args) > i else "default"
    return None if value == "default" else int(value)


def _touch(arrays) -> int:
    """Read the last element of each array (a lazily made array would be made here); their count."""
    n = 0
    for a in arrays:
        if a is not None and getattr(a, "size", 0):
            a[(-1,) * a.ndim]
            n += 1
    return n


def velodyne(path: str, workers: str = "default") -> dict:
    import numpy as np

    import lidarpkt

    frames = points = 0
    for f in lidarpkt.open(path, workers=_workers([workers], 0)):
        f.xyz()
        frames += 1
        points += int(np.count_nonzero(f.range_mm))
    return {"frames": frames, "points": points}


def velodyne_decoder(path: str, model: str = "vlp16") -> dict:
    import velodyne_decoder as vd

    cfg = vd.Config(model=vd.Model.VLP16) if model == "vlp16" else vd.Config()  # else: from the factory byte
    frames = points = 0
    for _, cloud in vd.read_pcap(path, cfg, as_pcl_structs=True):
        frames += 1
        points += len(cloud)
    return {"frames": frames, "points": points}


OUSTER_ARRAYS = ("range_mm", "reflectivity", "signal", "near_ir", "flags", "column_timestamp_ns", "measurement_id",
                 "status", "column_valid")


def ouster(path: str, metadata: str, xyz: str = "none", workers: str = "default") -> dict:
    import numpy as np

    import lidarpkt

    dtype = {"none": None, "xyz32": np.float32, "xyz64": np.float64}[xyz]
    frames = fields = 0
    for f in lidarpkt.open(path, metadata=metadata, workers=_workers([workers], 0)):
        fields += _touch([getattr(f, k) for k in OUSTER_ARRAYS] + list(f.extra.values()))
        if dtype is not None:
            f.xyz(dtype)
        frames += 1
    return {"frames": frames, "fields": fields}


def _sdk_fields(scan) -> list:
    return [scan.field(name) for name in scan.fields] + [scan.timestamp, scan.measurement_id, scan.status]


def ouster_sdk(path: str, metadata: str) -> dict:
    from ouster.sdk import pcap

    frames = fields = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for scans in pcap.PcapFrameSetSource(path, meta=[metadata]):
            scan = scans[0]
            if scan is not None:
                fields += _touch(_sdk_fields(scan))
                frames += 1
    return {"frames": frames, "fields": fields}


def osf(path: str) -> dict:
    import lidarpkt

    frames = fields = 0
    for f in lidarpkt.open(path):
        fields += _touch([getattr(f, k) for k in OUSTER_ARRAYS] + list(f.extra.values()))
        frames += 1
    return {"frames": frames, "fields": fields}


def osf_sdk(path: str) -> dict:
    from ouster.sdk import osf as sdk_osf

    frames = fields = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for scans in sdk_osf.OsfFrameSetSource(path):
            for scan in scans:
                if scan is not None:
                    fields += _touch(_sdk_fields(scan))
                    frames += 1
    return {"frames": frames, "fields": fields}


def decode(*argv: str) -> dict:
    from lidarpkt.cli import main

    return {"status": main(["decode", *argv])}


KINDS = {"velodyne": velodyne, "velodyne_decoder": velodyne_decoder, "ouster": ouster, "ouster_sdk": ouster_sdk,
         "osf": osf, "osf_sdk": osf_sdk, "decode": decode}


def main(argv: list[str]) -> int:
    result = KINDS[argv[0]](*argv[1:])
    hwm = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM"))
    result["hwm_mb"] = hwm / 1024
    result["children_hwm_mb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
