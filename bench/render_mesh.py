#!/usr/bin/python3
"""Render a small triangle mesh (ascii OBJ or ascii PLY) to a PNG with flat Lambert
shading, to eyeball generated shapes and simplification results.

    /usr/bin/python3 bench/render_mesh.py MESH.obj OUT.png [--elev 25] [--azim -60] [--title T] [--edges]

Meant for meshes up to ~100k faces (matplotlib sorts every face by depth). Needs
matplotlib and numpy (Debian: python3-matplotlib).
"""
import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402


def read_obj(path):
    vertices, faces = [], []
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                vertices.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("f "):
                idx = [int(x.split("/")[0]) for x in line.split()[1:]]
                for k in range(1, len(idx) - 1):
                    faces.append([idx[0] - 1, idx[k] - 1, idx[k + 1] - 1])
    return np.array(vertices), np.array(faces)


def read_ascii_ply(path):
    with open(path) as f:
        if f.readline().strip() != "ply":
            raise SystemExit(f"{path}: not a PLY file")
        counts = {}
        element = None
        for line in f:
            words = line.split()
            if words[:2] == ["format", "binary_little_endian"] or words[:2] == ["format", "binary_big_endian"]:
                raise SystemExit(f"{path}: only ascii PLY is supported here")
            if words and words[0] == "element":
                element = words[1]
                counts[element] = int(words[2])
            if words and words[0] == "end_header":
                break
        vertices = [[float(x) for x in f.readline().split()[:3]] for _ in range(counts.get("vertex", 0))]
        faces = []
        for _ in range(counts.get("face", 0)):
            idx = [int(x) for x in f.readline().split()]
            for k in range(2, idx[0]):
                faces.append([idx[1], idx[k], idx[k + 1]])
    return np.array(vertices), np.array(faces)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh")
    parser.add_argument("png")
    parser.add_argument("--elev", type=float, default=25)
    parser.add_argument("--azim", type=float, default=-60)
    parser.add_argument("--title", default=None)
    parser.add_argument("--edges", action="store_true", help="draw triangle edges (small meshes)")
    parser.add_argument("--size", type=float, default=6, help="figure size in inches (100 dpi)")
    args = parser.parse_args()

    vertices, faces = read_obj(args.mesh) if args.mesh.endswith(".obj") else read_ascii_ply(args.mesh)
    triangles = vertices[faces]
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-300
    # A key light from the camera's upper left plus ambient, so relief reads clearly.
    elev, azim = np.radians(args.elev), np.radians(args.azim)
    view = np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])
    light = view + np.array([-np.sin(azim), np.cos(azim), 0.0]) * -0.6 + np.array([0, 0, 0.8])
    light /= np.linalg.norm(light)
    shade = 0.2 + 0.8 * np.clip(normals @ light, 0, 1)
    colours = np.outer(shade, np.array([0.85, 0.78, 0.66]))

    fig = plt.figure(figsize=(args.size, args.size), dpi=100)
    ax = fig.add_subplot(projection="3d")
    ax.add_collection3d(Poly3DCollection(triangles, facecolors=colours, edgecolors="k" if args.edges else "none",
                                          linewidths=0.2 if args.edges else 0))
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    for set_lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        set_lim(c - half, c + half)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=args.elev, azim=args.azim)
    ax.set_axis_off()
    ax.set_title(args.title or f"{args.mesh.split('/')[-1]}: {len(faces)} faces")
    fig.tight_layout()
    fig.savefig(args.png)


if __name__ == "__main__":
    main()
