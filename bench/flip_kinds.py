#!/usr/bin/python3
"""Which kind of flipped faces a simplification has: a face of SIMPLIFIED whose normal
opposes the nearest ORIGINAL face's (what `qemflow compare` counts, here without its
tie tolerance), and of those, how many are folded onto a neighbour (a cosine below -0.5
with a face sharing an edge) rather than lying near a thin part of the original.

    bench/flip_kinds.py ORIGINAL.obj SIMPLIFIED.obj     (Wavefront OBJ, e.g. written by
        qemflow simplify IN ORIGINAL.obj --ratio 1 --in-core; numpy and scipy)
Prints the counts, then up to 25 flipped faces: cosine to the nearest original face,
distance to it / mean edge, cosines to the neighbours."""
import sys
from collections import defaultdict

import numpy as np
from scipy.spatial import cKDTree


def load(path):
    v, f = [], []
    for line in open(path):
        if line.startswith("v "):
            v.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            f.append([int(x.split("/")[0]) - 1 for x in line.split()[1:4]])
    return np.array(v), np.array(f)


def point_triangle_distance(p, a, b, c):
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab @ ap, ac @ ap
    if d1 <= 0 and d2 <= 0:
        return np.linalg.norm(p - a)
    bp = p - b
    d3, d4 = ab @ bp, ac @ bp
    if d3 >= 0 and d4 <= d3:
        return np.linalg.norm(p - b)
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        return np.linalg.norm(p - (a + d1 / (d1 - d3) * ab))
    cp = p - c
    d5, d6 = ab @ cp, ac @ cp
    if d6 >= 0 and d5 <= d6:
        return np.linalg.norm(p - c)
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        return np.linalg.norm(p - (a + d2 / (d2 - d6) * ac))
    va = d3 * d6 - d5 * d4
    if va <= 0 and (d4 - d3) >= 0 and (d5 - d6) >= 0:
        return np.linalg.norm(p - (b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b)))
    denom = 1 / (va + vb + vc)
    return np.linalg.norm(p - (a + ab * vb * denom + ac * vc * denom))


def unit(n):
    length = np.linalg.norm(n)
    return n / length if length > 0 else n


def main():
    np.seterr(all="ignore")  # degenerate original faces: their distances are NaN, never the nearest
    a, af = load(sys.argv[1])
    b, bf = load(sys.argv[2])
    an = np.cross(a[af[:, 1]] - a[af[:, 0]], a[af[:, 2]] - a[af[:, 0]])
    bn = np.cross(b[bf[:, 1]] - b[bf[:, 0]], b[bf[:, 2]] - b[bf[:, 0]])
    tree = cKDTree(a[af].mean(1))
    edge = np.mean(np.linalg.norm(b[bf[:, 0]] - b[bf[:, 1]], axis=1))
    faces_of_edge = defaultdict(list)
    for f, t in enumerate(bf):
        for k in range(3):
            faces_of_edge[frozenset((t[k], t[(k + 1) % 3]))].append(f)
    rows, folded = [], 0
    for f, t in enumerate(bf):
        if np.linalg.norm(bn[f]) == 0:
            continue
        centroid = b[t].mean(0)
        _, near = tree.query(centroid, k=40)
        dist = np.array([point_triangle_distance(centroid, *a[af[g]]) for g in near])
        g = near[int(np.argmin(dist))]
        cosine = unit(bn[f]) @ unit(an[g])
        if cosine >= 0:
            continue
        neighbours = [h for k in range(3) for h in faces_of_edge[frozenset((t[k], t[(k + 1) % 3]))] if h != f]
        cosines = [float(unit(bn[f]) @ unit(bn[h])) for h in neighbours]
        folded += min(cosines, default=1.0) < -0.5
        rows.append((round(float(cosine), 2), round(float(dist.min() / edge), 3), [round(c, 2) for c in cosines]))
    print(f"flipped {len(rows)}, folded onto a neighbour (cosine < -0.5) {folded}, others {len(rows) - folded}")
    for row in rows[:25]:
        print(row)


if __name__ == "__main__":
    main()
