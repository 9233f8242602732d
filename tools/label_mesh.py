#!/usr/bin/env python3
"""Writes assets/meshes/label.obj: a stamp with the raised letters "MPM" on a backing plate,
for the label stamped into the bunny pile (scenes/stamping_label.ron, [Su21] Fig. 1).

The stamp is a union of voxels (a blocky 5 x 7 font extruded downwards under a plate), written
as the boundary faces between filled and empty voxels, with shared vertices: a closed,
consistently oriented mesh (outward normals). The font has no two letter pixels that touch only
at a corner, so every edge has exactly two faces (the script checks it).

Frame: y up; the letters' bottom faces lie at y = 0 and read "MPM" seen from above (x to the
right, z towards the viewer's bottom edge); the origin is the centre of the letters' footprint.
Usage: python3 tools/label_mesh.py [OUT]   (default assets/meshes/label.obj)
"""
import sys
from collections import Counter

FONT = {
    "M": ["#####", "#.#.#", "#.#.#", "#.#.#", "#...#", "#...#", "#...#"],
    "P": ["#####", "#...#", "#...#", "#####", "#....", "#....", "#...."],
}
TEXT = "MPM"
PIXEL = 0.018  # m, in x and z
RELIEF = 0.03  # m, letter height below the plate
PLATE = 0.015  # m, plate thickness
MARGIN = 1  # pixels of plate around the text


def bitmap():
    rows = ["" for _ in range(7)]
    for i, ch in enumerate(TEXT):
        for r in range(7):
            rows[r] += FONT[ch][r] + ("." if i + 1 < len(TEXT) else "")
    return rows


def main(out):
    rows = bitmap()
    nzt, nxt = len(rows), len(rows[0])
    nx, nz = nxt + 2 * MARGIN, nzt + 2 * MARGIN
    # filled[(i, j, k)]: i along x, j = 0 letters layer, 1 plate layer, k along z.
    filled = set()
    for r, row in enumerate(rows):
        for c, ch in enumerate(row):
            if ch == "#":
                filled.add((c + MARGIN, 0, r + MARGIN))
    for i in range(nx):
        for k in range(nz):
            filled.add((i, 1, k))
    # No corner-only contacts between letter pixels (non-manifold edges).
    for (i, j, k) in list(filled):
        if j != 0:
            continue
        for di, dk in ((1, 1), (1, -1)):
            if (i + di, 0, k + dk) in filled and (i + di, 0, k) not in filled and (i, 0, k + dk) not in filled:
                raise SystemExit(f"corner-only contact at pixel {(i, k)}")
    x0 = -(MARGIN + nxt / 2) * PIXEL
    z0 = -(MARGIN + nzt / 2) * PIXEL
    ys = [0.0, RELIEF, RELIEF + PLATE]

    def corner(i, j, k):
        return (round(x0 + i * PIXEL, 9), ys[j], round(z0 + k * PIXEL, 9))

    verts, index, faces = [], {}, []

    def vid(p):
        if p not in index:
            index[p] = len(verts) + 1
            verts.append(p)
        return index[p]

    # For each filled voxel and each of its 6 faces whose neighbour is empty: a quad, corners
    # ordered counter-clockwise seen from outside.
    for (i, j, k) in sorted(filled):
        for axis in range(3):
            for side in (0, 1):
                n = [i, j, k]
                n[axis] += 1 if side else -1
                if tuple(n) in filled:
                    continue
                lo = [i, j, k]
                lo[axis] += side
                a, b = [(1, 2), (2, 0), (0, 1)][axis]
                quad = []
                for da, db in ((0, 0), (1, 0), (1, 1), (0, 1)):
                    p = list(lo)
                    p[a] += da
                    p[b] += db
                    quad.append(vid(corner(*p)))
                if not side:
                    quad.reverse()
                faces.append((quad[0], quad[1], quad[2]))
                faces.append((quad[0], quad[2], quad[3]))
    edges = Counter()
    for f in faces:
        for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
            edges[e] += 1
    bad = [e for e, n in edges.items() if n != 1 or edges[(e[1], e[0])] != 1]
    if bad:
        raise SystemExit(f"{len(bad)} edges not shared by exactly two opposite faces")
    with open(out, "w") as f:
        f.write(f"# Stamp with the raised letters \"{TEXT}\" (tools/label_mesh.py); metres, y up.\n")
        for v in verts:
            f.write(f"v {v[0]:.6f} {v[1]:.6f} {v[2]:.6f}\n")
        for t in faces:
            f.write(f"f {t[0]} {t[1]} {t[2]}\n")
    w, d = nx * PIXEL, nz * PIXEL
    print(f"{out}: {len(verts)} vertices, {len(faces)} triangles, {w:.3f} x {RELIEF + PLATE:.3f} x {d:.3f} m")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "assets/meshes/label.obj")
