"""
Convex hulls of meshes for contact: read a mesh file, take its hull, pack it for the kernels.

A mesh collision shape is simulated as the convex hull of its vertices (as MuJoCo
and Bullet do): a hull is what the kernels' support-function narrow phases
(:mod:`.kernels.convex`: GJK, EPA, features) take, and a robot's collision meshes
are usually drawn convex for this reason. The hull is Qhull's (``scipy.spatial.
ConvexHull``, already a dependency), its coplanar triangles merged into one face each
(a box's hull has six four-cornered faces), so a hull's face lying on another
face gives the corners of their overlap, as a box's does.

Files: STL (binary or ASCII) and Wavefront OBJ (its ``v`` lines), read here (both
are a list of vertices for a hull; no mesh library is needed for that). Other
formats (COLLADA ``.dae``...) are refused with an error naming the file.

The packed record (:func:`hull_record`) is one float64 array per hull, laid out as
:mod:`.kernels.convex` reads it (``H_*``).
"""

from __future__ import annotations

from pathlib import Path
import struct
from typing import Any

import numpy as np

from .errors import SpecError
from .kernels.convex import CORNERS, H_NF, H_NV, H_VERTS

#: File name endings read (lower case).
FORMATS = ('.stl', '.obj')


def read_vertices(path: Any, field: str = 'mesh') -> np.ndarray:
    """
    Return the vertices (N, 3) of a mesh file (STL binary or ASCII, OBJ), in its units.

    Raises :class:`.SpecError` naming ``field`` for a missing file, another format,
    or a file that holds no vertex.
    """
    p = Path(path)
    if p.suffix.lower() not in FORMATS:
        raise SpecError(field, f'{str(path)!r}: mesh format {p.suffix or "(none)"!r} not '
                               f'read (STL and OBJ are)')
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise SpecError(field, f'{str(path)!r}: {exc.strerror or exc}') from None
    if p.suffix.lower() == '.obj':
        verts = _obj(data)
    else:
        verts = _stl(data)
    if verts is None or len(verts) == 0:
        raise SpecError(field, f'{str(path)!r}: no vertices read (not a valid '
                               f'{p.suffix[1:].upper()} file)')
    return verts


def _stl(data: bytes):
    """Return an STL file's triangle corners (3T, 3), binary or ASCII; None if neither."""
    if len(data) >= 84:
        count = struct.unpack_from('<I', data, 80)[0]
        # Binary: 50 bytes a triangle after an 84-byte head; bytes beyond are padding
        # (an ASCII file begins 'solid', as some binary heads do: those by their size).
        if count > 0 and (len(data) == 84 + 50 * count or len(data) > 84 + 50 * count
                          and data[:5].lower() != b'solid'):
            rec = np.frombuffer(data, dtype=np.dtype([('n', '<f4', 3), ('v', '<f4', (3, 3)),
                                                      ('attr', '<u2')]), count=count,
                                offset=84)
            return rec['v'].reshape(-1, 3).astype(np.float64)
    try:
        text = data.decode('ascii')
    except UnicodeDecodeError:
        return None
    rows = [line.split()[1:4] for line in text.splitlines()
            if line.strip().lower().startswith('vertex')]
    try:
        return np.array(rows, dtype=np.float64).reshape(-1, 3)
    except ValueError:
        return None


def _obj(data: bytes):
    """Return an OBJ file's ``v`` vertices (N, 3); None if a line does not parse."""
    rows = []
    for line in data.decode('utf-8', errors='replace').splitlines():
        parts = line.split()
        if len(parts) >= 4 and parts[0] == 'v':
            rows.append(parts[1:4])
    try:
        return np.array(rows, dtype=np.float64).reshape(-1, 3)
    except ValueError:
        return None


def hull_triangles(rec: np.ndarray) -> np.ndarray:
    """Return a packed hull's surface as triangles (T, 3, 3): each face fanned from corner 0."""
    nv, nf = int(rec[H_NV]), int(rec[H_NF])
    v = rec[H_VERTS:H_VERTS + 3 * nv].reshape(nv, 3)
    out = []
    for f in range(nf):
        o = int(rec[H_VERTS + 3 * nv + f])
        idx = rec[o + 4:o + 4 + int(rec[o + 3])].astype(int)
        out.extend([v[idx[0]], v[idx[q]], v[idx[q + 1]]] for q in range(1, len(idx) - 1))
    return np.array(out).reshape(-1, 3, 3)


def centred_hull(rec: np.ndarray) -> tuple:
    """
    Return ``(record, centre)``: a packed hull about its vertices' box's centre.

    ``centre`` (3,) is that box's centre in the shape's frame; the record's vertices are
    moved by ``−centre`` and its half extents (``[0:3]``) are the box's about it. The
    broad phase's bounds and the contacts' size scale are then the part's own: a 2 cm
    part 0.5 m from its link's origin (as URDF meshes often are, drawn in the link's
    frame) is a 2 cm box, not a 1 m one about the origin.
    """
    nv = int(rec[H_NV])
    v = rec[H_VERTS:H_VERTS + 3 * nv].reshape(nv, 3)
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    out = rec.copy()
    moved = v - centre
    out[H_VERTS:H_VERTS + 3 * nv] = moved.ravel()
    out[:3] = np.max(np.abs(moved), axis=0)
    return out, centre


#: Qhull's merging of coplanar facets, relative to the vertices' size (float32's rounding
#: of coordinates is 6e-8 of it: 1e-6 with room; a face bent by less is one face).
MERGE = 1e-6


def _outline(xy: np.ndarray) -> np.ndarray:
    """Return the indices of the 2-D convex outline of ``xy`` (k, 2), counter-clockwise."""
    order = np.lexsort((xy[:, 1], xy[:, 0]))
    span = float(np.max(np.ptp(xy, axis=0), initial=0.0))

    def chain(seq):
        out: list = []
        for i in seq:
            while len(out) >= 2:
                a, b = xy[out[-2]], xy[out[-1]]
                turn = (b[0] - a[0]) * (xy[i][1] - a[1]) - (b[1] - a[1]) * (xy[i][0] - a[0])
                if turn > 1e-9 * span * span:
                    break
                out.pop()
            out.append(i)
        return out
    lower, upper = chain(order), chain(order[::-1])
    return np.array(lower[:-1] + upper[:-1], dtype=int)


def hull_record(vertices: Any, field: str = 'mesh') -> np.ndarray:
    """
    Return the packed record of the convex hull of ``vertices`` (N, 3), in the shape's frame.

    Layout (:mod:`.kernels.convex`): ``[0:3]`` the half extents of the box about the
    shape's origin that holds the hull (``max |v|`` per axis: the broad phase's bounds and
    the size scale), ``[H_NV]`` the hull's vertex count, ``[H_NF]`` its face count,
    ``[H_VERTS:]`` the vertices, then the faces' starts (``nf`` indices into the record),
    then
    each face: its outward unit normal, its corner count ``k``, and its ``k`` vertex
    indices counter-clockwise about the normal.

    Coplanar triangles are merged within the rounding of the file's numbers (float32
    in binary STL: 1e-6 of the size), and a face's corners are its merged points' 2-D
    convex outline (a point inside a face or on an edge is no corner). A face of more
    than :data:`.convex.CORNERS` corners keeps that many of them, evenly spaced (a
    polygon inside it: the contacts' region a little smaller than the face).

    Raises :class:`.SpecError` naming ``field`` for non-finite vertices or a flat or
    degenerate set (no volume).
    """
    from scipy.spatial import ConvexHull, QhullError

    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
        raise SpecError(field, f'expected at least 4 vertices (N, 3), got shape {v.shape}')
    if not np.all(np.isfinite(v)):
        raise SpecError(field, 'vertices must be finite')
    size = float(np.max(np.ptp(v, axis=0)))
    try:
        # On coordinates scaled to the set's size, Qhull merges facets whose centrums lie
        # within MERGE of their neighbours (C-n): coplanar to the numbers' rounding
        # (float32 from a binary STL: 6e-8 of the size), a point inside a face is no
        # vertex. Its merged facets come triangulated (Qt), each triangle with the
        # facet's own equation.
        hull = ConvexHull(v / size if size > 0.0 else v, qhull_options=f'Qt C-{MERGE!r}')
    except (QhullError, ValueError):
        raise SpecError(field, f'the {len(v)} vertices span no volume (flat or '
                               f'degenerate): a hull needs a solid') from None
    if hull.volume <= 1e-12:
        raise SpecError(field, f'the hull has no volume ({hull.volume * size ** 3:.3g}): a '
                               f'hull needs a solid')
    keep = hull.vertices
    index = np.full(len(v), -1)
    index[keep] = np.arange(len(keep))
    hv = v[keep]
    _, facet = np.unique(hull.equations, axis=0, return_inverse=True)
    facet = facet.ravel()
    by_facet = np.argsort(facet, kind='stable')
    starts = np.flatnonzero(np.r_[True, np.diff(facet[by_facet]) != 0, True])
    out_faces = []
    for a, b in zip(starts[:-1], starts[1:]):
        tris = hull.simplices[by_facet[a:b]]
        normal = hull.equations[by_facet[a], :3]
        normal = normal / np.linalg.norm(normal)
        idx = index[np.unique(tris)]
        pts = hv[idx]
        centre = pts.mean(axis=0)
        u = pts[np.argmax(np.linalg.norm(pts - centre, axis=1))] - centre
        u /= np.linalg.norm(u)
        w = np.cross(normal, u)
        idx = idx[_outline(np.c_[(pts - centre) @ u, (pts - centre) @ w])]   # (CCW)
        if len(idx) > CORNERS:
            idx = idx[np.linspace(0, len(idx), CORNERS, endpoint=False).astype(int)]
        out_faces.append((normal, idx))
    nv, nf = len(hv), len(out_faces)
    starts = H_VERTS + 3 * nv
    body = sum(4 + len(idx) for _, idx in out_faces)
    rec = np.zeros(starts + nf + body)
    rec[0:3] = np.max(np.abs(hv), axis=0)
    rec[H_NV], rec[H_NF] = nv, nf
    rec[H_VERTS:H_VERTS + 3 * nv] = hv.ravel()
    at = starts + nf
    for f, (normal, idx) in enumerate(out_faces):
        rec[starts + f] = at
        rec[at:at + 3] = normal
        rec[at + 3] = len(idx)
        rec[at + 4:at + 4 + len(idx)] = idx
        at += 4 + len(idx)
    rec.setflags(write=False)
    return rec
