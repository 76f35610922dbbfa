"""Content hashes of a run's input files, and which of them changed since a run measured them.

Cheap and mtime-independent (``content_hash``); a mesh hashes with the side files its loader read
(``mesh_content_hash``). run.json keeps them (``INPUT_FILES_KEY``) so that ``pgt-check report``
can say which input changed (``changed_inputs``). Split out of ``store.py`` (its size).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

#: files up to this size are hashed whole; bigger ones by size + first/last MiB + 64 samples
FULL_HASH_MAX_BYTES = 256 << 20
_SAMPLE_BYTES = 1 << 20


def content_hash(path: str | Path) -> str:
    """A cheap, mtime-independent hash of a file's content (or a directory's files).

    A file of at most ``FULL_HASH_MAX_BYTES`` (256 MiB): sha256 of its bytes. A bigger file:
    sha256 of its size, its first and last MiB and 64 evenly spaced 4 KiB samples (an edit
    that keeps the size and touches none of those bytes goes unnoticed: documented trade-off
    for multi-GB meshes). A directory (a COLMAP model): the hashes of its files by name.
    Returns "missing" for a path that does not exist.
    """
    import hashlib

    path = Path(path)
    if path.is_dir():
        h = hashlib.sha256()
        for child in sorted(p for p in path.iterdir() if p.is_file()):
            h.update(f"{child.name}={content_hash(child)};".encode())
        return "dir:" + h.hexdigest()[:32]
    if not path.is_file():
        return "missing"
    size = path.stat().st_size
    h = hashlib.sha256(f"{size};".encode())
    with open(path, "rb") as f:
        if size <= FULL_HASH_MAX_BYTES:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        else:
            h.update(f.read(_SAMPLE_BYTES))
            for i in range(64):
                f.seek(size * i // 64)
                h.update(f.read(4096))
            f.seek(size - _SAMPLE_BYTES)
            h.update(f.read(_SAMPLE_BYTES))
    return h.hexdigest()[:32]


def mesh_content_hash(path: str | Path, side_files: Iterable[str] = ()) -> str:
    """The content hash of a mesh as its loader read it: ``content_hash`` of the mesh file and
    of each side file it read (``MeshData.side_files``: OBJ materials and textures, glTF
    buffers and images; ``"missing:<name>"`` entries are hashed as the name). A mesh without
    side files (PLY, GLB) hashes as its file alone."""
    import hashlib

    main = content_hash(path)
    side = list(side_files)
    if not side:
        return main
    h = hashlib.sha256(f"{main};".encode())
    folder = Path(path).absolute().parent
    for name in side:
        if name.startswith("missing:"):
            key, digest = name, "missing"
        else:  # named relative to the mesh: a moved dataset folder keeps its hash
            key, digest = os.path.relpath(name, folder), content_hash(name)
        h.update(f"{key}={digest};".encode())
    return "mesh+side:" + h.hexdigest()[:32]


#: run.json's key of the input files' content hashes (absolute path -> ``content_hash``)
INPUT_FILES_KEY = "input_files"


def changed_inputs(run_info: Mapping[str, Any], config_input: Mapping[str, Any] | None = None
                   ) -> tuple[list[str], list[str]]:
    """(changed, unreadable): the input files of a run (run.json, ``INPUT_FILES_KEY``) whose
    content differs now from when they were measured, and those that cannot be read any more
    (moved or deleted: not checked). A run.json of an older version without that key: its mesh
    alone (``settings.inputs.mesh`` against ``config_input["mesh"]``, where the hash covers the
    mesh file alone)."""
    files = run_info.get(INPUT_FILES_KEY)
    if not isinstance(files, Mapping):
        settings = run_info.get("settings")
        stored = (settings or {}).get("inputs", {}).get("mesh") if isinstance(settings, Mapping) \
            else None
        mesh = (config_input or {}).get("mesh")
        if not isinstance(stored, str) or not mesh or stored.startswith("mesh+side:"):
            return [], []
        files = {os.path.abspath(str(mesh)): stored}
    changed, unreadable = [], []
    for path, digest in files.items():
        try:
            now = content_hash(path)
        except OSError:
            now = "missing"
        if now == "missing":
            unreadable.append(str(path))
        elif now != digest:
            changed.append(str(path))
    return changed, unreadable
