#!/usr/bin/env python3
"""Writes tests/data/cube_with_hole_20mm.stl: a 20 x 20 x 10 mm block with a 10 x 10 mm square
through-hole along Z, binary STL, winding counter-clockwise seen from outside. Used by the
README's main job and by tests that must run without ../shared/models."""
import struct, pathlib

def quad(tris, a, b, c, d):
    """Two triangles for the planar quad a-b-c-d given counter-clockwise from outside."""
    tris.append((a, b, c))
    tris.append((a, c, d))

def block_with_hole(size=20.0, hole=10.0, height=10.0):
    o0, o1 = 0.0, size
    i0, i1 = (size - hole) / 2, (size + hole) / 2
    outer = [(o0, o0), (o1, o0), (o1, o1), (o0, o1)]  # counter-clockwise from above
    inner = [(i0, i0), (i1, i0), (i1, i1), (i0, i1)]
    tris = []
    for k in range(4):
        (ax, ay), (bx, by) = outer[k], outer[(k + 1) % 4]
        quad(tris, (ax, ay, 0), (bx, by, 0), (bx, by, height), (ax, ay, height))  # outer wall, faces out
        (cx, cy), (dx, dy) = inner[k], inner[(k + 1) % 4]
        quad(tris, (dx, dy, 0), (cx, cy, 0), (cx, cy, height), (dx, dy, height))  # hole wall, faces the hole
        # top ring piece between outer edge k and inner edge k (faces +z), bottom ring faces -z
        quad(tris, (ax, ay, height), (bx, by, height), (dx, dy, height), (cx, cy, height))
        quad(tris, (cx, cy, 0), (dx, dy, 0), (bx, by, 0), (ax, ay, 0))
    return tris

def write_binary(path, tris, header=b"strata sample: 20 mm block with 10 mm square hole"):
    with open(path, "wb") as f:
        f.write(header.ljust(80, b" "))
        f.write(struct.pack("<I", len(tris)))
        for a, b, c in tris:
            u = [b[i] - a[i] for i in range(3)]
            v = [c[i] - a[i] for i in range(3)]
            n = (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])
            ln = sum(x * x for x in n) ** 0.5
            f.write(struct.pack("<3f", *(x / ln for x in n)))
            for p in (a, b, c):
                f.write(struct.pack("<3f", *p))
            f.write(b"\0\0")

if __name__ == "__main__":
    root = pathlib.Path(__file__).resolve().parents[2]
    write_binary(root / "tests/data/cube_with_hole_20mm.stl", block_with_hole())
