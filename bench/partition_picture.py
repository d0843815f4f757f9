#!/usr/bin/python3
"""Render a mesh coloured by partition patch (like Fig. 6 of the paper), from the file
that `pipeline_partition_bench --dump=OUT.bin` writes: the real out-of-core path (load
into blocks, partition stage, every face classified from the blocks by its barycenter).
`partition_bench --dump-partition=OUT.bin` writes the same format from in-memory kernels.

    build/bench/pipeline_partition_bench ../shared/data/stanford-dragon.ply.zst \
        --clusters=8 --dump=/tmp/dragon.bin
    /usr/bin/python3 bench/partition_picture.py /tmp/dragon.bin bench/results/partition.png

Two views (front and back), flat Lambert shading, painter's algorithm on a 2D
PolyCollection with back faces culled: fine up to a million faces.
Needs numpy and matplotlib (Debian: python3-matplotlib).
"""
import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402


def read_partition(path):
    data = open(path, "rb").read()
    if data[:4] != b"QPRT":
        raise SystemExit(f"{path}: not a partition dump (no QPRT magic)")
    vertex_count, face_count = np.frombuffer(data, "<u4", 2, 4)
    at = 12
    vertices = np.frombuffer(data, "<f4", 3 * vertex_count, at).reshape(-1, 3).astype(np.float64)
    at += 12 * vertex_count
    faces = np.frombuffer(data, "<u4", 3 * face_count, at).reshape(-1, 3)
    at += 12 * face_count
    patches = np.frombuffer(data, "<u4", face_count, at)
    return vertices, faces, patches


def rotation(elev, azim):
    a, e = np.radians(azim), np.radians(elev)
    turn = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    tilt = np.array([[1, 0, 0], [0, np.cos(e), -np.sin(e)], [0, np.sin(e), np.cos(e)]])
    return tilt @ turn


def draw(ax, vertices, faces, patches, up_axis, elev, azim, palette):
    # Bring `up_axis` to z, then view along -y after turning and tilting.
    order = {"x": [1, 2, 0], "y": [2, 0, 1], "z": [0, 1, 2]}[up_axis]
    v = vertices[:, order] - vertices.mean(axis=0)[order]
    v = v @ rotation(elev, azim).T
    tri = v[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1)
    visible = (normal[:, 1] < 0) & (length > 0)
    tri, normal, length, patch = tri[visible], normal[visible], length[visible], patches[visible]
    light = np.array([-0.3, -1.0, 0.5])
    light /= np.linalg.norm(light)
    shade = 0.35 + 0.65 * np.clip((normal / length[:, None]) @ light, 0, 1)
    colour = palette[patch % len(palette)] * shade[:, None]
    depth = tri[:, :, 1].mean(axis=1)
    back_to_front = np.argsort(-depth)
    polygons = tri[back_to_front][:, :, [0, 2]]
    ax.add_collection(PolyCollection(polygons, facecolors=colour[back_to_front], edgecolors="none",
                                     antialiased=False))
    ax.set_xlim(v[:, 0].min(), v[:, 0].max())
    ax.set_ylim(v[:, 2].min(), v[:, 2].max())
    ax.set_aspect("equal")
    ax.axis("off")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dump")
    parser.add_argument("png")
    parser.add_argument("--up", default="y", choices=["x", "y", "z"], help="the model's up axis")
    parser.add_argument("--elev", type=float, default=15)
    parser.add_argument("--azim", type=float, default=0)
    parser.add_argument("--title", default=None)
    args = parser.parse_args()
    vertices, faces, patches = read_partition(args.dump)
    palette = np.array(plt.get_cmap("tab20").colors)[[0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 1, 3, 5, 7, 9, 11,
                                                         13, 15, 17, 19]]
    figure, axes = plt.subplots(1, 2, figsize=(9, 4.6), dpi=100)
    for ax, turn in zip(axes, (args.azim, args.azim + 180)):
        draw(ax, vertices, faces, patches, args.up, args.elev, turn, palette)
    count = len(np.unique(patches))
    figure.suptitle(args.title or f"{len(faces)} faces, {count} patches (ν-SVM linear planes, DAG)")
    figure.tight_layout()
    figure.savefig(args.png)


if __name__ == "__main__":
    main()
