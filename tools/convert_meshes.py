#!/usr/bin/env python3
"""Fetch the CGAL demo meshes (bunny, armadillo, cow) and convert them to OBJ.

Source: Debian's `libcgal-demo` package, version 5.5.1-2 (architecture `all`). Its data
archive holds usr/share/doc/libcgal-dev/data.tar.gz, which holds data/meshes/*.off.

Steps (all with the Python 3.11 standard library; no extra packages):

1. Get the .deb: `--deb PATH` uses a local copy; otherwise `apt-get download
   libcgal-demo=5.5.1-2` is run in a temporary directory (Debian's ordinary client; run
   `apt-get update` first on a fresh machine).
2. Check its SHA-256 against the pinned value below; stop on a mismatch.
3. Extract the three OFF files (ar archive -> data.tar.xz -> data.tar.gz -> data/meshes/).
4. Convert each to OBJ: the vertex coordinates are copied verbatim (same decimal text, so
   the geometry is bit-identical after parsing); polygons with more than three corners are
   fan-triangulated; OFF colours are dropped. The mesh is checked for closedness (every
   undirected edge in exactly two triangles, every directed edge in at most one). If it is
   not closed, exact duplicate vertices are welded and the check repeated (recorded in
   ORIGIN.md). If the signed volume is negative, every triangle's orientation is flipped so
   that the normals point outwards.
5. Write assets/meshes/{bunny,armadillo,cow}.obj and assets/meshes/ORIGIN.md.

Usage: python3 tools/convert_meshes.py [--deb PATH] [--out DIR]
"""
from __future__ import annotations

import argparse
import hashlib
import io
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

PACKAGE = "libcgal-demo"
VERSION = "5.5.1-2"
DEB_NAME = f"{PACKAGE}_{VERSION}_all.deb"
SHA256 = "78b09b23d4d6d1bf15552a1060b419ab3fc09918486462faed197e5fc6ac3735"
INNER_ARCHIVE = "usr/share/doc/libcgal-dev/data.tar.gz"

# (output name, path inside data.tar.gz, original source for the licence note)
MESHES = [
    ("bunny", "data/meshes/bunny00.off",
     "a closed (hole-free) version, as distributed by CGAL, of the Stanford Bunny from The "
     "Stanford 3D Scanning Repository (Turk & Levoy 1994)"),
    ("armadillo", "data/meshes/armadillo.off",
     "Armadillo, The Stanford 3D Scanning Repository (Krishnamurthy & Levoy 1996)"),
    ("cow", "data/meshes/cow.off",
     "the classic 'cow' test model, usually attributed to Viewpoint Datalabs / "
     "Viewpoint Animation Engineering (origin not documented in the package)"),
]

REPO = Path(__file__).resolve().parent.parent


def fail(msg: str) -> None:
    print(f"convert_meshes: error: {msg}", file=sys.stderr)
    sys.exit(1)


def fetch_deb(tmp: Path) -> Path:
    cmd = ["apt-get", "download", f"{PACKAGE}={VERSION}"]
    print("running:", " ".join(cmd))
    r = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True)
    deb = tmp / DEB_NAME
    if r.returncode != 0 or not deb.is_file():
        fail(f"`{' '.join(cmd)}` failed ({r.returncode}): {r.stderr.strip()}\n"
             "Run `apt-get update` first, or pass a downloaded copy with --deb PATH.")
    return deb


def ar_members(data: bytes) -> dict[str, bytes]:
    """Members of a Unix `ar` archive (the .deb container)."""
    if not data.startswith(b"!<arch>\n"):
        fail("not an ar archive (bad .deb)")
    out, pos = {}, 8
    while pos + 60 <= len(data):
        header = data[pos:pos + 60]
        name = header[:16].decode().strip().rstrip("/")
        size = int(header[48:58].decode().strip())
        pos += 60
        out[name] = data[pos:pos + size]
        pos += size + (size & 1)
    return out


def extract_offs(deb_bytes: bytes) -> dict[str, bytes]:
    members = ar_members(deb_bytes)
    data_name = next((n for n in members if n.startswith("data.tar")), None)
    if data_name is None:
        fail("the .deb has no data.tar.* member")
    with tarfile.open(fileobj=io.BytesIO(members[data_name])) as outer:
        inner_member = outer.getmember("./" + INNER_ARCHIVE)
        inner_bytes = outer.extractfile(inner_member).read()
    files = {}
    with tarfile.open(fileobj=io.BytesIO(inner_bytes)) as inner:
        for _, path, _ in MESHES:
            files[path] = inner.extractfile(inner.getmember(path)).read()
    return files


def parse_off(text: str, name: str):
    """Vertex coordinate tokens and polygon faces of an OFF file."""
    tokens = []
    for line in text.splitlines():
        line = line.split("#", 1)[0]
        tokens.extend(line.split())
    if not tokens or tokens[0] != "OFF":
        fail(f"{name}: not an OFF file")
    nv, nf = int(tokens[1]), int(tokens[2])
    pos = 4
    verts = []
    for _ in range(nv):
        xyz = tokens[pos:pos + 3]
        [float(t) for t in xyz]  # validate
        verts.append(xyz)
        pos += 3
    faces = []
    # Faces: "n i0 ... i(n-1) [colour...]"; colours are on the same line, so re-read lines.
    lines = [l.split("#", 1)[0].split() for l in text.splitlines()]
    lines = [l for l in lines if l]
    # header line 0 ("OFF"), counts line 1, then nv vertex lines, then nf face lines.
    first_face = 2 + nv
    if lines[0] != ["OFF"]:
        fail(f"{name}: expected `OFF` alone on the first line")
    for l in lines[first_face:first_face + nf]:
        n = int(l[0])
        faces.append([int(i) for i in l[1:1 + n]])
    if len(faces) != nf:
        fail(f"{name}: expected {nf} faces, found {len(faces)}")
    return verts, faces


def triangulate(faces):
    tris = []
    for f in faces:
        for k in range(1, len(f) - 1):
            tris.append((f[0], f[k], f[k + 1]))
    return tris


def topology(tris):
    """(open or non-manifold undirected edges, repeated directed edges)."""
    und, directed = {}, {}
    for t in tris:
        for k in range(3):
            a, b = t[k], t[(k + 1) % 3]
            und[(min(a, b), max(a, b))] = und.get((min(a, b), max(a, b)), 0) + 1
            directed[(a, b)] = directed.get((a, b), 0) + 1
    bad_und = sum(1 for c in und.values() if c != 2)
    bad_dir = sum(1 for c in directed.values() if c != 1)
    return bad_und, bad_dir


def weld(verts, tris):
    """Merge vertices with identical coordinates (exact, after float parsing)."""
    key_to_new, remap, new_verts = {}, [], []
    for v in verts:
        key = tuple(float(t) for t in v)
        if key not in key_to_new:
            key_to_new[key] = len(new_verts)
            new_verts.append(v)
        remap.append(key_to_new[key])
    new_tris = [tuple(remap[i] for i in t) for t in tris]
    new_tris = [t for t in new_tris if len(set(t)) == 3]
    return new_verts, new_tris


def measures(verts, tris):
    p = [tuple(float(t) for t in v) for v in verts]
    vol, area = 0.0, 0.0
    used = set()
    for a, b, c in tris:
        used.update((a, b, c))
        pa, pb, pc = p[a], p[b], p[c]
        cx = pb[1] * pc[2] - pb[2] * pc[1]
        cy = pb[2] * pc[0] - pb[0] * pc[2]
        cz = pb[0] * pc[1] - pb[1] * pc[0]
        vol += pa[0] * cx + pa[1] * cy + pa[2] * cz
        u = [pb[i] - pa[i] for i in range(3)]
        w = [pc[i] - pa[i] for i in range(3)]
        n = (u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0])
        area += 0.5 * (n[0] ** 2 + n[1] ** 2 + n[2] ** 2) ** 0.5
    lo = [min(p[i][k] for i in used) for k in range(3)]
    hi = [max(p[i][k] for i in used) for k in range(3)]
    return vol / 6.0, area, lo, hi


def convert(name: str, off_path: str, text: str, out_dir: Path):
    verts, faces = parse_off(text, off_path)
    polys = sum(1 for f in faces if len(f) > 3)
    tris = triangulate(faces)
    notes = []
    if polys:
        notes.append(f"{polys} polygons fan-triangulated")
    bad_und, bad_dir = topology(tris)
    if bad_und or bad_dir:
        nv0 = len(verts)
        verts, tris = weld(verts, tris)
        notes.append(f"not closed as given ({bad_und} bad edges); welded "
                     f"{nv0 - len(verts)} duplicate vertices")
        bad_und, bad_dir = topology(tris)
    if bad_und or bad_dir:
        fail(f"{off_path}: not a closed oriented surface even after welding "
             f"({bad_und} open/non-manifold edges, {bad_dir} inconsistent directed edges)")
    vol, area, lo, hi = measures(verts, tris)
    if vol < 0:
        tris = [(a, c, b) for a, b, c in tris]
        vol = -vol
        notes.append("orientation flipped (signed volume was negative)")
    if not notes:
        notes.append("closed and outward-oriented as given; converted unchanged")
    lines = [
        f"# {name}.obj: converted by tools/convert_meshes.py from {off_path}",
        f"# in Debian package {PACKAGE} {VERSION}; see ORIGIN.md for source and licence.",
        f"# {len(verts)} vertices, {len(tris)} triangles",
    ]
    lines += [f"v {v[0]} {v[1]} {v[2]}" for v in verts]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in tris]
    (out_dir / f"{name}.obj").write_text("\n".join(lines) + "\n")
    return {
        "name": name, "off": off_path, "vertices": len(verts), "triangles": len(tris),
        "faces_in_off": len(faces), "volume": vol, "area": area, "lo": lo, "hi": hi,
        "notes": "; ".join(notes),
    }


def fmt3(v):
    return "(" + ", ".join(f"{x:.6g}" for x in v) + ")"


def write_origin(out_dir: Path, stats):
    rows = "\n".join(
        f"| `{s['name']}.obj` | `{s['off']}` | {s['vertices']} | {s['triangles']} | "
        f"{fmt3(s['lo'])} – {fmt3(s['hi'])} | {s['volume']:.6g} | {s['area']:.6g} | "
        f"{s['notes']} |"
        for s in stats
    )
    sources = "\n".join(f"- `{name}.obj`: {src}." for name, _, src in MESHES)
    text = f"""# Origin of the CGAL demo meshes

`bunny.obj`, `armadillo.obj` and `cow.obj` were produced by `tools/convert_meshes.py`
(re-run it to reproduce them byte for byte) from Debian's **`{PACKAGE}`** package:

- version **{VERSION}** (architecture `all`, file `{DEB_NAME}`, fetched with
  `apt-get download {PACKAGE}={VERSION}`);
- SHA-256 of the .deb: `{SHA256}`;
- path: `data.tar.xz` → `{INNER_ARCHIVE}` → `data/meshes/*.off`.

Conversion: vertex coordinates copied verbatim (same decimal text); polygons fan-triangulated;
closedness checked (every edge in exactly two triangles, consistently oriented); orientation
flipped if the signed volume was negative. Units are those of the source files (none);
scale them in the scene file. Self-intersections are not checked.

| file | original | vertices | triangles | bounding box (min – max) | volume | surface area | notes |
|---|---|---|---|---|---|---|---|
{rows}

Volume by the divergence theorem, area as the sum of triangle areas (both in `f64` from the
decimal coordinates).

## Licence

The CGAL data files carry no copyright notice of their own; CGAL's `LICENSE` (quoted in the
package's `copyright` file) states that files without an explicit copyright notice are
licensed under Creative Commons **CC0 1.0**. The models themselves come from older sources,
whose terms should be respected and acknowledged:

{sources}

The Stanford 3D Scanning Repository asks that the source of its models be acknowledged; its
terms welcome research use and free redistribution and ask to be contacted for other (e.g.
commercial) uses. These meshes ship only as test and demonstration data (scenes, tests); they
are not part of the treacle library code.
"""
    (out_dir / "ORIGIN.md").write_text(text)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--deb", type=Path, help=f"local copy of {DEB_NAME}")
    ap.add_argument("--out", type=Path, default=REPO / "assets" / "meshes")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        deb = args.deb if args.deb else fetch_deb(Path(tmp))
        deb_bytes = deb.read_bytes()
    digest = hashlib.sha256(deb_bytes).hexdigest()
    if digest != SHA256:
        fail(f"SHA-256 mismatch for {deb}: got {digest}, expected {SHA256}")
    print(f"{DEB_NAME}: sha256 ok")
    offs = extract_offs(deb_bytes)
    args.out.mkdir(parents=True, exist_ok=True)
    stats = []
    for name, path, _ in MESHES:
        s = convert(name, path, offs[path].decode("ascii"), args.out)
        print(f"{name}.obj: {s['vertices']} vertices, {s['triangles']} triangles, "
              f"volume {s['volume']:.6g}, bbox {fmt3(s['lo'])}–{fmt3(s['hi'])}; {s['notes']}")
        stats.append(s)
    write_origin(args.out, stats)
    print(f"wrote {args.out}/ORIGIN.md")


if __name__ == "__main__":
    main()
