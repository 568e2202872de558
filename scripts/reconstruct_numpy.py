#!/usr/bin/env python3
"""The reference `deltaz bench-reconstruct` times `deltaz reconstruct --method paper` against:
numpy's loadtxt and the paper's equations, vectorised over every dot.

    reconstruct_numpy.py SYSTEM.json DOTS.csv OUT.npy

DOTS.csv is `image,point,col,row` (pixels, (0, 0) the centre of the top-left pixel; `point` the
ray id). OUT.npy gets one row X, Y, Z (mm, the system's frame) per dot, in the file's order.
Prints the number of dots and the seconds spent after Python started (reading, computing,
writing).
"""
import json
import sys
import time

import numpy as np


def rotation(kappa, phi, omega):
    """Eq. (2): R = M_z(kappa) M_y(phi) M_x(omega), world -> camera."""
    sk, ck = np.sin(kappa), np.cos(kappa)
    sp, cp = np.sin(phi), np.cos(phi)
    so, co = np.sin(omega), np.cos(omega)
    return np.array([
        [cp * ck, co * sk + so * sp * ck, so * sk - co * sp * ck],
        [-cp * sk, co * ck - so * sp * sk, so * ck + co * sp * sk],
        [sp, -so * cp, co * cp],
    ])


def main(system_path, dots_path, out_path):
    start = time.perf_counter()
    with open(system_path) as f:
        system = json.load(f)
    grid = system["camera"]["grid"]
    inner = system["camera"]["inner"]
    pose = system["camera"]["pose"]
    projector = system["projector"]
    dots = np.loadtxt(dots_path, delimiter=",", skiprows=1, usecols=(1, 2, 3),
                      comments="#", ndmin=2)
    ids = dots[:, 0].astype(np.int64)
    col, row = dots[:, 1], dots[:, 2]
    # Photo coordinates reduced to the principal point (mm, y up), then image refinement.
    x = (col - grid["origin_col"]) * grid["pixel_size"] - inner["cx"]
    y = -(row - grid["origin_row"]) * grid["pixel_size"] - inner["cy"]
    r2 = x * x + y * y
    radial = r2 * (inner["k1"] + r2 * (inner["k2"] + r2 * inner["k3"]))
    p1, p2 = inner["p1"], inner["p2"]
    xr = x + x * radial + p1 * (r2 + 2 * x * x) + 2 * p2 * x * y
    yr = y + y * radial + p2 * (r2 + 2 * y * y) + 2 * p1 * x * y
    # Eq. (7): (u, v, w) = R^T (x, y, -f), as rows: (x, y, -f) R.
    r = rotation(pose["kappa"], pose["phi"], pose["omega"])
    camera = np.column_stack([xr, yr, np.full_like(xr, -inner["f"])]) @ r
    x0 = np.array(pose["centre"])
    # Eq. (5): the projector rays by id.
    table = np.zeros((max(ray["id"] for ray in projector["rays"]) + 1, 6))
    for ray in projector["rays"]:
        table[ray["id"], :3] = (ray["l"], ray["m"], ray["n"])
        table[ray["id"], 3:] = ray.get("offset") or (0.0, 0.0, 0.0)
    lmn = table[ids, :3]
    xp = np.array(projector["centre"]) + table[ids, 3:]
    # Eqs (8)-(9): lambda and lambda_p from the X and Z equations; the point is the average.
    u, w = camera[:, 0], camera[:, 2]
    l, n = lmn[:, 0], lmn[:, 2]
    d = xp - x0
    denominator = n * u - w * l
    lam = (d[:, 0] * n - d[:, 2] * l) / denominator
    lam_p = (d[:, 0] * w - d[:, 2] * u) / denominator
    points = 0.5 * (x0 + lam[:, None] * camera + xp + lam_p[:, None] * lmn)
    np.save(out_path, points)
    print(f"{len(points)} dots in {time.perf_counter() - start:.3f} s")


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    main(*sys.argv[1:])
