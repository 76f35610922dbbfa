"""Camera specifications given on the command line."""

from __future__ import annotations

from pgt_check.errors import InputError
from pgt_check.types import CAMERA_MODELS, Camera


def parse_camera_spec(spec: str) -> Camera:
    """Parse ``"MODEL,width,height,p1,p2,..."`` (COLMAP parameter order and pixel convention).

    The principal point in the string follows COLMAP (centre of the top-left pixel at
    (0.5, 0.5)), as in a COLMAP ``cameras.txt`` line; the returned Camera is in OpenCV
    convention (0.5 subtracted from cx, cy). Commas and/or whitespace separate the fields.
    Raises InputError with the expected layout on any problem.
    """
    fields = [f for f in spec.replace(",", " ").split() if f]
    if not fields:
        raise InputError("camera spec is empty; expected MODEL,width,height,params...")
    model = fields[0].upper()
    if model not in CAMERA_MODELS:
        raise InputError(
            f"camera spec {spec!r}: expected a model in {', '.join(CAMERA_MODELS)}; got {fields[0]!r}"
        )
    names = CAMERA_MODELS[model]
    layout = f"{model},width,height,{','.join(names)}"
    if len(fields) != 3 + len(names):
        raise InputError(
            f"camera spec {spec!r}: expected {3 + len(names)} fields ({layout}); got {len(fields)}"
        )
    try:
        width, height = int(fields[1]), int(fields[2])
        params = [float(p) for p in fields[3:]]
    except ValueError:
        raise InputError(
            f"camera spec {spec!r}: expected integer width, height and numeric parameters ({layout})"
        ) from None
    values = [p - 0.5 if n in ("cx", "cy") else p for n, p in zip(names, params, strict=True)]
    try:
        return Camera(model, width, height, tuple(values))
    except ValueError as err:
        raise InputError(f"camera spec {spec!r}: {err}") from None
