"""Will the mesh fit? The memory a run needs for its mesh and render buffers, estimated from the
mesh file's header before anything is loaded, against the memory this machine has available.

```python
counts = read_mesh_counts("scan.ply")           # vertex / face counts from the PLY header
need = estimate_run_memory(counts, 640, 480, workers=2)
check_memory_fits("scan.ply", 640, 480, workers=2)   # SetupError with one line if it cannot fit
```

Counts come from the PLY header, the glTF/GLB accessors, or a line count of an OBJ file; any
other format is guessed from the file size (``exact=False``, a deliberately low guess so that
only clear cases are refused). Texture images are not counted.

The per-vertex and per-face costs are measured (``reports/scaling.md``, mesh size): peak RSS of
``load_mesh`` followed by the first render on the moderngl backend, whose CPU (llvmpipe) driver
keeps its own copy of the vertex and index buffers, on subdivided 7-Scenes meshes of 0.15-15 M
faces.
"""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass
from pathlib import Path

from pgt_check.errors import SetupError

#: peak bytes per vertex / per face of loading a mesh and uploading it to the renderer (trimesh
#: parse in float64 / int64, the flattened float64 + int32 ``MeshData``, the interleaved float32
#: vertex buffer and the driver's copies): fitted to the measured peak RSS (15 M faces, 7.6 M
#: vertices: 2.08 GiB above the process's base, 149 bytes a face; the fit gives 2.23 GiB)
PEAK_BYTES_PER_VERTEX = 130
PEAK_BYTES_PER_FACE = 85
#: fixed bytes of a renderer (GL context, llvmpipe driver state, shaders) and of a worker
#: process's own imports (numpy, OpenCV, moderngl, trimesh)
RENDERER_BASE_BYTES = 128 * 2**20
WORKER_BASE_BYTES = 256 * 2**20
#: bytes per vertex / face that stay resident while the mesh is loaded (``MeshData``: float64
#: vertices, float32 colours, int32 faces) without a renderer: what the run's main process keeps
#: while worker processes render
RESIDENT_BYTES_PER_VERTEX = 24 + 12
RESIDENT_BYTES_PER_FACE = 12
#: bytes per pixel of one frame's render and image buffers (GL colour, z and depth attachments,
#: the float32 RGB / depth read back, the photo and the matcher's working copies)
BYTES_PER_PIXEL = 64
#: bytes a face takes in a mesh file of unknown layout: high, so the guessed face count is low
GUESS_FILE_BYTES_PER_FACE = 40


@dataclass(frozen=True)
class MeshCounts:
    """Vertex and face counts of a mesh file; ``exact`` False when guessed from its size."""

    n_vertices: int
    n_faces: int
    exact: bool = True


def read_mesh_counts(path: str | Path) -> MeshCounts:
    """Vertex and face counts of the mesh file at ``path`` without loading it: the PLY header,
    the glTF / GLB accessors, a line count of an OBJ file; otherwise (or for a header it
    cannot read) a guess from the file size. A polygon counts as one face (a quad mesh needs
    about twice the estimate once triangulated)."""
    path = Path(path)
    suffix = path.suffix.lower()
    counts: MeshCounts | None = None
    try:
        if suffix == ".ply":
            with path.open("rb") as fh:
                counts = ply_header_counts(fh.read(65536))
        elif suffix == ".obj":
            counts = obj_counts(path)
        elif suffix in (".glb", ".gltf"):
            counts = gltf_counts(path)
    except (OSError, ValueError, KeyError, TypeError, struct.error):
        counts = None
    if counts is None:
        size = path.stat().st_size
        faces = size // GUESS_FILE_BYTES_PER_FACE
        counts = MeshCounts(n_vertices=faces // 2, n_faces=faces, exact=False)
    return counts


def ply_header_counts(head: bytes) -> MeshCounts | None:
    """Counts from the start of a PLY file (``element vertex N`` / ``element face N``); None if
    ``head`` is not a complete PLY header."""
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return None
    text = head[:end].decode("ascii", errors="replace")
    found = dict(re.findall(r"^element\s+(\w+)\s+(\d+)\s*$", text, flags=re.MULTILINE))
    if "vertex" not in found:
        return None
    return MeshCounts(int(found["vertex"]), int(found.get("face", 0)))


def obj_counts(path: Path, chunk: int = 1 << 24) -> MeshCounts:
    """Counts of ``v`` and ``f`` lines of an OBJ file (read in chunks, nothing kept)."""
    n_v = n_f = 0
    carry = b"\n"  # a line start before the first line; then the unfinished last line
    with path.open("rb") as fh:
        while True:
            block = fh.read(chunk)
            data = carry + block
            # lines that start in data[:cut] end before it: count there, carry the rest
            cut = data.rfind(b"\n") if block else len(data)
            done, carry = data[:cut], data[cut:]
            n_v += done.count(b"\nv ") + done.count(b"\nv\t")
            n_f += done.count(b"\nf ") + done.count(b"\nf\t")
            if not block:
                return MeshCounts(n_v, n_f)


def gltf_counts(path: Path) -> MeshCounts | None:
    """Counts from a glTF / GLB file's accessors: each primitive's POSITION count and its
    indices count / 3 (non-indexed: positions / 3); mesh instancing by nodes is not counted."""
    raw = path.read_bytes() if path.suffix.lower() == ".gltf" else _glb_json(path)
    if raw is None:
        return None
    doc = json.loads(raw)
    accessors = doc.get("accessors", [])
    n_v = n_f = 0
    for mesh in doc.get("meshes", []):
        for prim in mesh.get("primitives", []):
            if prim.get("mode", 4) != 4:  # not a triangle list
                continue
            nv = int(accessors[prim["attributes"]["POSITION"]]["count"])
            n_v += nv
            idx = prim.get("indices")
            n_f += (int(accessors[idx]["count"]) if idx is not None else nv) // 3
    return MeshCounts(n_v, n_f)


def _glb_json(path: Path) -> bytes | None:
    with path.open("rb") as fh:
        head = fh.read(20)
        if len(head) < 20 or head[:4] != b"glTF":
            return None
        length, kind = struct.unpack("<II", head[12:20])
        if kind != 0x4E4F534A:  # "JSON"
            return None
        return fh.read(length)


def estimate_mesh_bytes(counts: MeshCounts) -> tuple[int, int]:
    """(peak, resident) bytes of one process that loads the mesh and renders it (peak, with the
    renderer's fixed cost) and of one that keeps it loaded without a renderer (resident)."""
    peak = (counts.n_vertices * PEAK_BYTES_PER_VERTEX + counts.n_faces * PEAK_BYTES_PER_FACE
            + RENDERER_BASE_BYTES)
    resident = (counts.n_vertices * RESIDENT_BYTES_PER_VERTEX
                + counts.n_faces * RESIDENT_BYTES_PER_FACE)
    return peak, resident


def estimate_run_memory(counts: MeshCounts, width: int, height: int, workers: int = 0) -> int:
    """Bytes a run needs for its mesh and render buffers at ``width`` x ``height`` px, beyond
    what the calling process already uses.

    ``workers`` = 0: this process loads and renders the mesh (serial executor). ``workers`` > 0:
    this process loads the mesh once (preflight: peak) and keeps it (resident) while each of
    ``workers`` new worker processes on this machine imports the pipeline, loads and renders
    its own copy."""
    if workers < 0 or width <= 0 or height <= 0:
        raise ValueError(f"need workers >= 0 and a positive size, got {workers}, {width}x{height}")
    from pgt_check.render.cache import DEFAULT_MAX_BYTES

    peak, resident = estimate_mesh_bytes(counts)
    # one frame's buffers, and the renders a checker keeps (``render.cache``)
    frame = width * height * BYTES_PER_PIXEL + DEFAULT_MAX_BYTES
    if workers == 0:
        return peak + frame
    return max(peak, resident + workers * (WORKER_BASE_BYTES + peak + frame))


def parse_meminfo(text: str) -> int | None:
    """``MemAvailable`` of a /proc/meminfo text, in bytes (None if absent)."""
    m = re.search(r"^MemAvailable:\s+(\d+)\s*kB", text, flags=re.MULTILINE)
    return int(m.group(1)) * 1024 if m else None


def parse_cgroup_room(limit_text: str, usage_text: str) -> int | None:
    """Room left under a cgroup v2 memory limit (``memory.max`` minus ``memory.current``), in
    bytes; None without a limit ("max")."""
    limit = limit_text.strip()
    if not limit or limit == "max":
        return None
    return max(0, int(limit) - int(usage_text.strip()))


def available_memory(proc: Path = Path("/proc"), cgroup: Path = Path("/sys/fs/cgroup")) -> int | None:
    """Bytes available to a new allocation here: /proc/meminfo ``MemAvailable``, lowered to the
    room left under this cgroup's memory limit where one is set; None where neither is known."""
    values = []
    try:
        values.append(parse_meminfo((proc / "meminfo").read_text()))
    except OSError:
        pass
    try:
        values.append(parse_cgroup_room((cgroup / "memory.max").read_text(),
                                        (cgroup / "memory.current").read_text()))
    except (OSError, ValueError):
        pass
    known = [v for v in values if v is not None]
    return min(known) if known else None


def _gib(n: int) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


def check_memory_fits(
    path: str | Path, width: int, height: int, workers: int = 0, available: int | None = None,
) -> tuple[MeshCounts, int, int | None]:
    """Raise SetupError (one line) when the estimated memory of a run on the mesh at ``path``
    (``estimate_run_memory``) exceeds the available memory (``available``, default: measured
    with ``available_memory``); returns (counts, estimate, available) otherwise. Unknown
    available memory never refuses."""
    counts = read_mesh_counts(path)
    need = estimate_run_memory(counts, width, height, workers)
    if available is None:
        available = available_memory()
    if available is not None and need > available:
        how = "" if counts.exact else " (guessed from the file size)"
        procs = f", {workers} worker processes" if workers else ""
        fixes = "a decimated mesh" + (", fewer --workers" if workers > 1 else "")
        raise SetupError(
            f"{path}: not enough memory for this mesh: about {_gib(need)} needed "
            f"({counts.n_faces:,} faces, {counts.n_vertices:,} vertices{how}{procs}, "
            f"{width}x{height} px) but {_gib(available)} available; use {fixes} or free memory"
        )
    return counts, need, available


__all__ = [
    "MeshCounts", "available_memory", "check_memory_fits", "estimate_mesh_bytes",
    "estimate_run_memory", "gltf_counts", "obj_counts", "parse_cgroup_room", "parse_meminfo",
    "ply_header_counts", "read_mesh_counts",
]
