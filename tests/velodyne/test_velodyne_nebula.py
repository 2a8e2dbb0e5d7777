"""The nebula dual-return bag against nebula's own decoded cloud (the .pcd stored next to it).

nebula (tier4) decoded the bag's 4th message with return mode Dual, its ``VLP16.yaml``,
0.3–300 m and cloud angles 0–359°. Its conventions differ from velodyne_decoder's (our
compatibility target) in two documented ways, so this test checks what both must share:

- every nebula point is one of our returns of the same rotation: same ring, same distance to
  the millimetre, same intensity, same z within 1 mm (z does not depend on the azimuth);
- its azimuth agrees within 0.5°: nebula interpolates the first and last firings of a packet
  with the neighbouring blocks' azimuth step, velodyne_decoder (and we) with the packet's mean rate;
- the point counts agree within 0.2 % (nebula labels a pair with one empty slot "identical"
  where velodyne_decoder keeps two labels, and cuts at 359° on its own interpolated azimuth).
"""

from __future__ import annotations

import numpy as np

import lidarpkt
from lidarpkt.vendors.velodyne import frame_points

PCD_DTYPE = np.dtype([
    ("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1"), ("return_type", "u1"), ("channel", "<u2"),
    ("azimuth", "<f4"), ("elevation", "<f4"), ("distance", "<f4"), ("time_stamp", "<u4"),
])


def read_pcd(path) -> np.ndarray:
    raw = path.read_bytes()
    head, _, body = raw.partition(b"DATA binary\n")
    assert b"FIELDS x y z intensity return_type channel azimuth elevation distance time_stamp" in head
    return np.frombuffer(body, PCD_DTYPE)


def test_nebula_cloud_is_contained_in_our_rotation(ext):
    neb = read_pcd(ext("nebula/vlp16/1673400472138016708.pcd"))
    assert len(neb) == 14831
    frames = list(lidarpkt.open(ext("nebula/vlp16/1673400471837873222"), metadata=ext("nebula/VLP16.yaml")))
    f = frames[3]  # the rotation of the 4th message: nebula's cloud spans 0.31°–358.98°
    slot, row, col = np.nonzero(f.range_mm)
    xyz = f.xyz()[slot, row, col]
    ours = {}
    for i, key in enumerate(zip((15 - row).tolist(), f.range_mm[slot, row, col].tolist(),
                                f.reflectivity[slot, row, col].tolist())):
        ours.setdefault(key, []).append(i)
    az_ours = f.extra["azimuth_cdeg"][row, col] / 100.0
    dist_mm = np.rint(neb["distance"].astype(np.float64) * 1000).astype(int)
    az_neb = np.degrees(neb["azimuth"].astype(np.float64))
    worst_az = worst_z = 0.0
    for k in range(len(neb)):
        candidates = ours.get((int(neb["channel"][k]), int(dist_mm[k]), int(neb["intensity"][k])))
        assert candidates, f"nebula point {k} is none of our returns"
        d_az = np.abs((az_ours[candidates] - az_neb[k] + 180) % 360 - 180)
        best = candidates[int(np.argmin(d_az))]
        worst_az = max(worst_az, float(d_az.min()))
        worst_z = max(worst_z, abs(float(xyz[best, 2]) - float(neb["z"][k])))
    assert worst_az < 0.5
    assert worst_z < 1e-3
    pts = frame_points(f, min_range_m=0.3, max_range_m=300)
    az = np.degrees(np.arctan2(-pts["y"], pts["x"])) % 360
    n_ours = int(np.count_nonzero(az < 359))
    assert abs(n_ours - len(neb)) <= 0.002 * len(neb)
