"""Checks of point-cloud and mesh files (PLY, PCD, XYZ, OBJ) against what they declare, made before a
reader sees them: a truncated file would otherwise be read as a smaller (or zero-padded) cloud, and a face
index outside the vertex list is silently wrapped, dropped, or kills the process inside PyMeshLab.

Every check raises ``ValueError`` naming the file (and the line or face) and saying what to do. Only the
structure is checked here; coordinates are checked by their readers (:mod:`dpsi.pointclouds`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
"""PLY property types → NumPy type codes (byte order added per file)."""

FACE_INDICES = ("vertex_indices", "vertex_index")
"""Names of the face property listing a face's vertices (0-based indices into the vertex element)."""


@dataclass(frozen=True)
class PlyProperty:
    """One property of a PLY element: a scalar of ``type``, or a list (``count_type`` count, then items
    of ``type``)."""

    name: str
    type: str
    count_type: str | None = None


@dataclass(frozen=True)
class PlyElement:
    name: str
    count: int
    properties: tuple[PlyProperty, ...]


def ply_header(path: str | os.PathLike) -> tuple[str, list[PlyElement], bytes]:
    """Format, elements and the data after the header of a PLY file; ``ValueError`` naming ``path`` if the
    header is bad."""
    path = Path(path)
    raw = path.read_bytes()
    end = raw.find(b"end_header")
    newline = raw.find(b"\n", end)
    if not raw.startswith(b"ply") or end < 0 or newline < 0:
        raise ValueError(f"{path}: not a PLY file (no 'ply' … 'end_header' header)")
    fmt, elements = "", []
    try:
        for line in raw[:end].decode("ascii").splitlines():
            words = line.split()
            if words[:1] == ["format"]:
                fmt = words[1]
            elif words[:1] == ["element"]:
                elements.append(PlyElement(words[1], int(words[2]), ()))
            elif words[:2] == ["property", "list"]:
                prop = PlyProperty(words[4], _PLY_TYPES[words[3]], _PLY_TYPES[words[2]])
                elements[-1] = PlyElement(elements[-1].name, elements[-1].count, (*elements[-1].properties, prop))
            elif words[:1] == ["property"]:
                prop = PlyProperty(words[2], _PLY_TYPES[words[1]])
                elements[-1] = PlyElement(elements[-1].name, elements[-1].count, (*elements[-1].properties, prop))
    except (UnicodeDecodeError, IndexError, KeyError, ValueError) as e:
        raise ValueError(f"{path}: malformed PLY header ({type(e).__name__}: {e})") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ValueError(f"{path}: unknown PLY format {fmt!r}")
    return fmt, elements, raw[newline + 1:]


class _Truncated(Exception):
    """The data ends inside an element's rows."""


def _item_size(code: str) -> int:
    return np.dtype(code).itemsize


def _binary_element(data: bytes, offset: int, element: PlyElement, order: str) -> tuple[int, dict[str, list]]:
    """Read one element's rows from binary ``data`` at ``offset``: (offset after them, each list property's
    (items, counts) as flat arrays). Rows whose lists all have the first row's lengths are read at once."""
    props, count = element.properties, element.count
    lists = [p for p in props if p.count_type]
    if not lists:
        end = offset + count * sum(_item_size(p.type) for p in props)
        if end > len(data):
            raise _Truncated
        return end, {}
    if count == 0:
        return offset, {p.name: (np.zeros(0, np.int64), np.zeros(0, np.int64)) for p in lists}
    fields, lengths, position = [], {}, offset  # the first row's layout, and the length of each of its lists
    for k, p in enumerate(props):
        if p.count_type is None:
            fields.append((f"s{k}", order + p.type))
            position += _item_size(p.type)
            continue
        if position + _item_size(p.count_type) > len(data):
            raise _Truncated
        lengths[k] = n = int(np.frombuffer(data, order + p.count_type, 1, position)[0])
        fields += [(f"n{k}", order + p.count_type), (f"i{k}", order + p.type, (n,))]
        position += _item_size(p.count_type) + n * _item_size(p.type)
    row = np.dtype(fields)
    rows = np.frombuffer(data, row, min(count, (len(data) - offset) // row.itemsize), offset)
    if len(rows) == count and all((rows[f"n{k}"] == n).all() for k, n in lengths.items()):
        return offset + count * row.itemsize, {props[k].name: (rows[f"i{k}"].reshape(-1).astype(np.int64),
                                                               np.full(count, n)) for k, n in lengths.items()}
    values = {p.name: ([], []) for p in lists}
    position = offset
    for _ in range(count):
        for p in props:
            size = _item_size(p.count_type or p.type)
            if position + size > len(data):
                raise _Truncated
            if p.count_type is None:
                position += size
                continue
            n = int(np.frombuffer(data, order + p.count_type, 1, position)[0])
            position += size
            if position + n * _item_size(p.type) > len(data):
                raise _Truncated
            values[p.name][0].append(np.frombuffer(data, order + p.type, n, position))
            values[p.name][1].append(n)
            position += n * _item_size(p.type)
    return position, {name: (np.concatenate(items).astype(np.int64) if items else np.zeros(0, np.int64),
                             np.asarray(counts)) for name, (items, counts) in values.items()}


def _ascii_element(tokens: list[bytes], start: int, element: PlyElement) -> tuple[int, dict[str, list]]:
    """As :func:`_binary_element`, for the whitespace-separated ``tokens`` of an ASCII PLY's data."""
    props, count = element.properties, element.count
    if not any(p.count_type for p in props):
        end = start + count * len(props)
        if end > len(tokens):
            raise _Truncated
        return end, {}
    if count == 0:
        return start, {p.name: (np.zeros(0, np.int64), np.zeros(0, np.int64)) for p in props if p.count_type}
    columns, position = [], start  # the first row's layout: (property, column of its count, its length)
    try:
        for p in props:
            n = int(tokens[position]) if p.count_type else 0
            columns.append((p, position - start, n))
            position += 1 + n if p.count_type else 1
    except IndexError:
        raise _Truncated from None
    width = position - start
    block = tokens[start:start + count * width]
    if len(block) == count * width:
        rows = np.asarray(block, dtype=float).reshape(count, width)
        if all((rows[:, c] == n).all() for p, c, n in columns if p.count_type):
            return start + count * width, {p.name: (rows[:, c + 1:c + 1 + n].reshape(-1).astype(np.int64),
                                                    np.full(count, n)) for p, c, n in columns if p.count_type}
    values = {p.name: ([], []) for p in props if p.count_type}
    position = start
    try:
        for _ in range(count):
            for p in props:
                if p.count_type is None:
                    position += 1
                    continue
                n = int(tokens[position])
                items = tokens[position + 1: position + 1 + n]
                if len(items) < n:
                    raise _Truncated
                values[p.name][0].extend(int(t) for t in items)
                values[p.name][1].append(n)
                position += 1 + n
    except IndexError:
        raise _Truncated from None
    if position > len(tokens):
        raise _Truncated
    return position, {name: (np.asarray(items, np.int64), np.asarray(counts, np.int64))
                      for name, (items, counts) in values.items()}


def _ply_lists(path: Path) -> tuple[dict[str, int], dict[str, dict[str, tuple[np.ndarray, np.ndarray]]]]:
    """The element counts of a PLY file and, per element, its list properties' (items, counts) after
    checking that its data holds every row its header declares."""
    fmt, elements, data = ply_header(path)
    declared = {e.name: e.count for e in elements}
    lists = {}
    try:
        if fmt == "ascii":
            tokens, position = data.split(), 0
            for e in elements:
                position, lists[e.name] = _ascii_element(tokens, position, e)
        else:
            order, offset = "<" if fmt == "binary_little_endian" else ">", 0
            for e in elements:
                offset, lists[e.name] = _binary_element(data, offset, e, order)
    except _Truncated:
        raise ValueError(f"{path}: truncated PLY file: the header declares {sum(declared.values())} rows "
                         f"({declared}) but its data ends before them; export it again") from None
    except ValueError as e:
        raise ValueError(f"{path}: malformed PLY data ({e}); export it again") from None
    return declared, lists


def check_ply(path: str | os.PathLike) -> dict[str, int]:
    """The element counts of a PLY file (e.g. ``{"vertex": n, "face": m}``) after checking that its data
    holds everything its header declares and that every face index names one of its vertices;
    ``ValueError`` naming the file (and the face) otherwise."""
    path = Path(path)
    declared, lists = _ply_lists(path)
    n = declared.get("vertex", 0)
    for name in FACE_INDICES:
        if name in lists.get("face", {}):
            items, counts = lists["face"][name]
            bad = np.flatnonzero((items < 0) | (items >= n))
            if bad.size:
                face = int(np.searchsorted(np.cumsum(counts), bad[0], side="right"))
                raise ValueError(f"{path}: face {face} refers to vertex {items[bad[0]]}, but the file has {n} "
                                 f"vertices (indices 0 … {n - 1}); the mesh is damaged: export it again")
    return declared


def ply_has_faces(path: str | os.PathLike) -> bool:
    """Whether a PLY file's header declares at least one face (a mesh, not a point cloud)."""
    _, elements, _ = ply_header(path)
    return any(e.name == "face" and e.count > 0 for e in elements)


def check_obj(path: str | os.PathLike) -> int:
    """The number of vertices (``v`` lines) of an OBJ file after checking that each is three finite numbers
    (a mesh reader would drop it and shift the faces) and that every face (``f`` line) refers to an existing
    vertex (1 … n, or −1 … −k for the k vertices before it); ``ValueError`` naming the file and line."""
    path = Path(path)
    count, highest = 0, (0, 0)
    with open(path, errors="replace") as f:
        for number, line in enumerate(f, start=1):
            words = line.split()
            if words[:1] == ["v"]:
                try:
                    xyz = [float(w) for w in words[1:4]]
                except ValueError:
                    xyz = []
                if len(xyz) != 3 or not np.isfinite(xyz).all():
                    raise ValueError(f"{path}, line {number}: vertex {' '.join(words[1:4])!r} is not three finite "
                                     "numbers (m); fix the vertex and export the mesh again")
                count += 1
            elif words[:1] == ["f"]:
                for word in words[1:]:
                    try:
                        index = int(word.split("/")[0])
                    except ValueError:
                        raise ValueError(f"{path}, line {number}: face corner {word!r} does not start with a "
                                         "vertex number; export the mesh again") from None
                    if index == 0 or -index > count:
                        raise ValueError(f"{path}, line {number}: face refers to vertex {index}, which does not "
                                         f"exist ({count} vertices precede it; OBJ counts from 1, or back from "
                                         "−1); the mesh is damaged: export it again")
                    highest = max(highest, (index, number))
    if highest[0] > count:
        raise ValueError(f"{path}, line {highest[1]}: face refers to vertex {highest[0]}, but the file has {count} "
                         "vertices; the mesh is damaged: export it again")
    return count


_PCD_KEYS = ("FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "POINTS", "DATA")


def check_pcd(path: str | os.PathLike) -> int:
    """The number of points a PCD file declares, after checking that its data holds them all (ASCII: one
    complete row per point; binary: the bytes; compressed: the compressed block); ``ValueError`` naming
    the file otherwise (Open3D pads a truncated ASCII file with zeros and reads a truncated binary one as
    nothing)."""
    path = Path(path)
    raw = path.read_bytes()
    header, position = {}, 0
    try:
        while "DATA" not in header:
            newline = raw.index(b"\n", position)
            words = raw[position:newline].decode("ascii").split()
            position = newline + 1
            if words and words[0] in _PCD_KEYS:
                header[words[0]] = words[1:]
        sizes = [int(s) for s in header["SIZE"]]
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(sizes))]
        points = int(header["POINTS"][0]) if "POINTS" in header else \
            int(header["WIDTH"][0]) * int(header["HEIGHT"][0])
        kind = header["DATA"][0]
    except (ValueError, KeyError, IndexError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: malformed PCD header ({type(e).__name__}: {e}); it needs SIZE, POINTS (or "
                         "WIDTH and HEIGHT) and DATA lines") from None
    data, row = raw[position:], sum(s * c for s, c in zip(sizes, counts))
    if kind == "ascii":
        rows = [line.split() for line in data.splitlines() if line.strip()]
        complete = sum(1 for r in rows if len(r) >= sum(counts))
        if complete < points or len(rows) > complete:
            raise ValueError(f"{path}: truncated PCD file: the header declares {points} points but the file holds "
                             f"{complete} complete rows of {sum(counts)} values; export it again")
    elif kind == "binary":
        if len(data) < points * row:
            raise ValueError(f"{path}: truncated PCD file: the header declares {points} points ({points * row} "
                             f"bytes) but the file holds {len(data)} bytes of data; export it again")
    elif kind == "binary_compressed":
        stored = int.from_bytes(data[:4], "little") if len(data) >= 8 else None
        if stored is None or len(data) < 8 + stored:
            raise ValueError(f"{path}: truncated PCD file: its compressed data block is cut off; export it again")
    else:
        raise ValueError(f"{path}: unknown PCD data format {kind!r} (ascii, binary or binary_compressed)")
    return points


def check_xyz(path: str | os.PathLike) -> int:
    """The number of points (lines) of an XYZ file after checking that each non-empty line starts with three
    numbers; ``ValueError`` naming the file and line otherwise (a file cut inside a line). XYZ declares no
    point count, so a file cut exactly at a line break cannot be told from a shorter one."""
    path = Path(path)
    count = 0
    with open(path, errors="replace") as f:
        for number, line in enumerate(f, start=1):
            words = line.split()
            if not words:
                continue
            try:
                [float(w) for w in words[:3]]
            except ValueError:
                words = []
            if len(words) < 3:
                raise ValueError(f"{path}, line {number}: {line.strip()!r} is not three numbers x y z (m): the file "
                                 "is truncated or malformed; export it again")
            count += 1
    return count


__all__ = ["FACE_INDICES", "PlyProperty", "PlyElement", "ply_header", "check_ply", "ply_has_faces", "check_obj",
           "check_pcd", "check_xyz"]
