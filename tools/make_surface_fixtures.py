#!/usr/bin/env python3
"""Writes tests/fixtures/surface/: one open tube in every surface format
nvtmm reads, by a program independent of nvtmm's readers (Python standard
library only), so tests/surface_readers_and_checks.rs can check that each
reader understands files it did not write.

The tube (millimetres): radius 5, length 40 along +z, N_THETA = 16 vertices
per ring, N_RINGS = 5 rings at z = 0, 10, ..., 40; vertex (ring j, angle k)
at (5 cos 2pi k/16, 5 sin 2pi k/16, 10 j). Each quad between rings j and
j+1 and angles k and k+1 is split along its diagonal (j,k)-(j+1,k+1), the
triangles ordered so normals point out of the tube. Formats that hold
polygons store the quads, listed from corner (j,k) so that a fan split
gives the same two triangles.

Format references: STL (3D Systems, "StereoLithography Interface
Specification", 1989), Wavefront OBJ (Appendix B1 of the Advanced
Visualizer manual), PLY (Turk, 1994), VTK legacy and XML ("VTK File
Formats", VTK User's Guide, 11th ed.).

Usage: python3 tools/make_surface_fixtures.py [output directory]
"""

import base64
import math
import os
import struct
import sys
import zlib

N_THETA = 16
N_RINGS = 5
RADIUS = 5.0
LENGTH = 40.0


def vertices():
    out = []
    for j in range(N_RINGS):
        z = LENGTH * j / (N_RINGS - 1)
        for k in range(N_THETA):
            a = 2.0 * math.pi * k / N_THETA
            out.append((RADIUS * math.cos(a), RADIUS * math.sin(a), z))
    return out


def idx(j, k):
    return j * N_THETA + (k % N_THETA)


def quads():
    """Quads (j,k), (j,k+1), (j+1,k+1), (j+1,k): outward normals."""
    return [
        (idx(j, k), idx(j, k + 1), idx(j + 1, k + 1), idx(j + 1, k))
        for j in range(N_RINGS - 1)
        for k in range(N_THETA)
    ]


def triangles():
    out = []
    for a, b, c, d in quads():
        out.append((a, b, c))
        out.append((a, c, d))
    return out


def normal(p, q, r):
    u = [q[i] - p[i] for i in range(3)]
    v = [r[i] - p[i] for i in range(3)]
    n = (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])
    s = math.sqrt(sum(x * x for x in n)) or 1.0
    return tuple(x / s for x in n)


def write(path, data):
    mode = "wb" if isinstance(data, bytes) else "w"
    with open(path, mode, newline="" if mode == "w" else None) as f:
        f.write(data)


def stl_ascii(v, t):
    lines = ["solid tube exported by make_surface_fixtures.py"]
    for a, b, c in t:
        n = normal(v[a], v[b], v[c])
        lines.append("  facet normal %e %e %e" % n)
        lines.append("    outer loop")
        for i in (a, b, c):
            lines.append("      vertex %.9e %.9e %.9e" % v[i])
        lines.append("    endloop")
        lines.append("  endfacet")
    lines.append("endsolid tube")
    return "\n".join(lines) + "\n"


def stl_binary(v, t):
    # The header starts with "solid", as many binary writers do: the reader
    # must tell binary from ASCII by the size.
    header = b"solid binary tube from make_surface_fixtures.py".ljust(80, b" ")
    out = [header, struct.pack("<I", len(t))]
    for a, b, c in t:
        out.append(struct.pack("<3f", *normal(v[a], v[b], v[c])))
        for i in (a, b, c):
            out.append(struct.pack("<3f", *v[i]))
        out.append(struct.pack("<H", 0))
    return b"".join(out)


def obj(v):
    lines = ["# tube, quads, from make_surface_fixtures.py", "mtllib tube.mtl", "o tube", "g wall"]
    for p in v:
        lines.append("v %r %r %r" % p)
    for j in range(N_RINGS):
        lines.append("vt 0 %r" % (j / (N_RINGS - 1)))
    lines.append("vn 0 0 1")
    lines.append("usemtl red")
    lines.append("s off")
    n = len(v)
    for q_i, (a, b, c, d) in enumerate(quads()):
        # Alternate the corner syntaxes: v, v/vt, v/vt/vn, v//vn, and
        # negative (relative) indices.
        form = q_i % 5
        if form == 0:
            corners = ["%d" % (i + 1) for i in (a, b, c, d)]
        elif form == 1:
            corners = ["%d/1" % (i + 1) for i in (a, b, c, d)]
        elif form == 2:
            corners = ["%d/1/1" % (i + 1) for i in (a, b, c, d)]
        elif form == 3:
            corners = ["%d//1" % (i + 1) for i in (a, b, c, d)]
        else:
            corners = ["%d" % (i - n) for i in (a, b, c, d)]
        lines.append("f " + " ".join(corners))
    lines.append("l 1 2")
    return "\r\n".join(lines) + "\r\n"


def ply_header(fmt, nv, nf, vprops, fprop, extra=""):
    h = ["ply", "format %s 1.0" % fmt, "comment tube from make_surface_fixtures.py",
         "obj_info mm", "element vertex %d" % nv]
    h += ["property %s %s" % p for p in vprops]
    h += ["element face %d" % nf, "property %s" % fprop]
    h += [x for x in extra.split("\n") if x]
    h.append("end_header")
    return ("\n".join(h) + "\n").encode("ascii")


def ply_ascii(v):
    q = quads()
    head = ply_header(
        "ascii", len(v), len(q),
        [("float", "nx"), ("double", "x"), ("double", "y"), ("double", "z"), ("uchar", "red")],
        "list uchar int vertex_indices",
        "property float quality\nelement edge 2\nproperty int vertex1\nproperty int vertex2",
    )
    body = []
    for p in v:
        body.append("%r %r %r %r %d" % (p[0] / RADIUS, p[0], p[1], p[2], 200))
    for a, b, c, d in q:
        body.append("4 %d %d %d %d 0.5" % (a, b, c, d))
    body.append("0 1")
    body.append("1 2")
    return head + ("\n".join(body) + "\n").encode("ascii")


def ply_binary(v, endian):
    e = "<" if endian == "little" else ">"
    t = triangles()
    head = ply_header(
        "binary_%s_endian" % endian, len(v), len(t),
        [("float32", "x"), ("float32", "y"), ("float32", "z"), ("uint8", "alpha"), ("int16", "label")],
        "list uint8 uint32 vertex_index",
        "property list uchar float texcoord\nelement material 1\nproperty list int uchar name",
    )
    out = [head]
    for p in v:
        out.append(struct.pack(e + "3fBh", p[0], p[1], p[2], 255, -3))
    for a, b, c in t:
        out.append(struct.pack(e + "B3I", 3, a, b, c))
        out.append(struct.pack(e + "B2f", 2, 0.25, 0.75))
    out.append(struct.pack(e + "i", 3) + b"red")
    return b"".join(out)


def vtk_ascii(v):
    q = quads()
    lines = ["# vtk DataFile Version 4.2", "tube from make_surface_fixtures.py", "ASCII", "DATASET POLYDATA",
             "POINTS %d float" % len(v)]
    for p in v:
        lines.append("%r %r %r" % p)
    lines.append("LINES 1 3")
    lines.append("2 0 1")
    lines.append("POLYGONS %d %d" % (len(q), 5 * len(q)))
    for a, b, c, d in q:
        lines.append("4 %d %d %d %d" % (a, b, c, d))
    lines.append("POINT_DATA %d" % len(v))
    lines.append("SCALARS radius float 1")
    lines.append("LOOKUP_TABLE default")
    for _ in v:
        lines.append("5")
    lines.append("NORMALS n float")
    for p in v:
        lines.append("%r %r 0" % (p[0] / RADIUS, p[1] / RADIUS))
    lines.append("CELL_DATA %d" % (len(q) + 1))
    lines.append("FIELD FieldData 1")
    lines.append("id 1 %d int" % (len(q) + 1))
    lines.append(" ".join(str(i) for i in range(len(q) + 1)))
    return "\n".join(lines) + "\n"


def vtk_binary(v):
    """VTK 5.1 layout (OFFSETS/CONNECTIVITY), big-endian, as VTK 9 writes."""
    t = triangles()
    out = [b"# vtk DataFile Version 5.1\ntube from make_surface_fixtures.py\nBINARY\nDATASET POLYDATA\n"]
    out.append(b"POINTS %d double\n" % len(v))
    out.append(b"".join(struct.pack(">3d", *p) for p in v) + b"\n")
    out.append(b"POLYGONS %d %d\n" % (len(t) + 1, 3 * len(t)))
    out.append(b"OFFSETS vtktypeint64\n")
    out.append(b"".join(struct.pack(">q", 3 * i) for i in range(len(t) + 1)) + b"\n")
    out.append(b"CONNECTIVITY vtktypeint64\n")
    out.append(b"".join(struct.pack(">3q", *tri) for tri in t) + b"\n")
    out.append(b"CELL_DATA %d\nSCALARS id int 1\nLOOKUP_TABLE default\n" % len(t))
    out.append(b"".join(struct.pack(">i", i) for i in range(len(t))) + b"\n")
    return b"".join(out)


def vtk_strips(v):
    """One triangle strip per band between rings (a different diagonal)."""
    lines = ["# vtk DataFile Version 3.0", "tube as strips", "ASCII", "DATASET POLYDATA",
             "POINTS %d double" % len(v)]
    for p in v:
        lines.append("%r %r %r" % p)
    strips = []
    for j in range(N_RINGS - 1):
        s = []
        for k in range(N_THETA + 1):
            s += [idx(j + 1, k), idx(j, k)]
        strips.append(s)
    size = sum(len(s) + 1 for s in strips)
    lines.append("TRIANGLE_STRIPS %d %d" % (len(strips), size))
    for s in strips:
        lines.append(" ".join(str(x) for x in [len(s)] + s))
    return "\n".join(lines) + "\n"


def vtp_ascii(v):
    q = quads()
    conn = " ".join("%d %d %d %d" % x for x in q)
    offs = " ".join(str(4 * (i + 1)) for i in range(len(q)))
    pts = "\n".join("%r %r %r" % p for p in v)
    return """<?xml version="1.0"?>
<!-- tube from make_surface_fixtures.py -->
<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian">
  <PolyData>
    <Piece NumberOfPoints="%d" NumberOfVerts="0" NumberOfLines="1" NumberOfStrips="0" NumberOfPolys="%d">
      <PointData Scalars="r">
        <DataArray type="Float32" Name="r" format="ascii">%s</DataArray>
      </PointData>
      <Points>
        <DataArray type="Float64" Name="Points" NumberOfComponents="3" format="ascii">
%s
        </DataArray>
      </Points>
      <Lines>
        <DataArray type="Int32" Name="connectivity" format="ascii">0 1</DataArray>
        <DataArray type="Int32" Name="offsets" format="ascii">2</DataArray>
      </Lines>
      <Polys>
        <DataArray type="Int32" Name="connectivity" format="ascii">%s</DataArray>
        <DataArray type="Int32" Name="offsets" format="ascii">%s</DataArray>
      </Polys>
    </Piece>
  </PolyData>
</VTKFile>
""" % (len(v), len(q), " ".join("5" for _ in v), pts, conn, offs)


def b64_block(raw):
    """An inline binary array: UInt32 byte count then the data, each base64
    encoded separately (as VTK writes)."""
    return (base64.b64encode(struct.pack("<I", len(raw))) + base64.b64encode(raw)).decode("ascii")


def vtp_base64(v):
    t = triangles()
    pts = b"".join(struct.pack("<3f", *p) for p in v)
    conn = b"".join(struct.pack("<3q", *x) for x in t)
    offs = b"".join(struct.pack("<q", 3 * (i + 1)) for i in range(len(t)))
    return """<?xml version="1.0"?>
<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian" header_type="UInt32">
  <PolyData>
    <Piece NumberOfPoints="%d" NumberOfPolys="%d">
      <Points>
        <DataArray type="Float32" Name="Points" NumberOfComponents="3" format="binary">
          %s
        </DataArray>
      </Points>
      <Polys>
        <DataArray type="Int64" Name="connectivity" format="binary">%s</DataArray>
        <DataArray type="Int64" Name="offsets" format="binary">%s</DataArray>
      </Polys>
    </Piece>
  </PolyData>
</VTKFile>
""" % (len(v), len(t), b64_block(pts), b64_block(conn), b64_block(offs))


def zlib_block(raw):
    """A compressed array, one block: UInt64 header [1, size, size, csize]."""
    c = zlib.compress(raw)
    return struct.pack("<4Q", 1, len(raw), len(raw), len(c)) + c


def vtp_appended_zlib(v):
    t = triangles()
    arrays = [
        b"".join(struct.pack("<3d", *p) for p in v),
        b"".join(struct.pack("<3i", *x) for x in t),
        b"".join(struct.pack("<i", 3 * (i + 1)) for i in range(len(t))),
    ]
    blocks = [zlib_block(a) for a in arrays]
    offsets = [0, len(blocks[0]), len(blocks[0]) + len(blocks[1])]
    head = """<?xml version="1.0"?>
<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" header_type="UInt64" compressor="vtkZLibDataCompressor">
  <PolyData>
    <Piece NumberOfPoints="%d" NumberOfPolys="%d">
      <Points>
        <DataArray type="Float64" Name="Points" NumberOfComponents="3" format="appended" offset="%d"/>
      </Points>
      <Polys>
        <DataArray type="Int32" Name="connectivity" format="appended" offset="%d"/>
        <DataArray type="Int32" Name="offsets" format="appended" offset="%d"/>
      </Polys>
    </Piece>
  </PolyData>
  <AppendedData encoding="raw">
   _""" % (len(v), len(t), offsets[0], offsets[1], offsets[2])
    return head.encode("ascii") + b"".join(blocks) + b"\n  </AppendedData>\n</VTKFile>\n"


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(here, "..", "tests", "fixtures", "surface")
    os.makedirs(out, exist_ok=True)
    v, t = vertices(), triangles()
    files = {
        "tube_ascii.stl": stl_ascii(v, t),
        "tube_binary.stl": stl_binary(v, t),
        "tube_quads.obj": obj(v),
        "tube_ascii.ply": ply_ascii(v),
        "tube_binary_le.ply": ply_binary(v, "little"),
        "tube_binary_be.ply": ply_binary(v, "big"),
        "tube_ascii.vtk": vtk_ascii(v),
        "tube_binary51.vtk": vtk_binary(v),
        "tube_strips.vtk": vtk_strips(v),
        "tube_ascii.vtp": vtp_ascii(v),
        "tube_base64.vtp": vtp_base64(v),
        "tube_appended_zlib.vtp": vtp_appended_zlib(v),
    }
    for name, data in sorted(files.items()):
        write(os.path.join(out, name), data)
        print(name)


if __name__ == "__main__":
    main()
