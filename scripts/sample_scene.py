"""The procedural room of ``make_sample_data.py``: textures, textured quads and boxes, the scene.

``build_scene`` makes the room (four walls, floor, ceiling, three crates) as a
``trimesh.Scene`` of textured quads: variant ``"mesh"`` is the published mesh.glb, ``"photo"``
the world the photos are rendered from (one crate moved, a cabinet added). The textures
(bricks, posters, a bookshelf, tiles, plaster, crates) are drawn with OpenCV from the random
generator they are given, so the scene is deterministic for a given seed.
"""

from __future__ import annotations

import io
import string

import numpy as np

from pgt_check.geometry.transforms import axis_angle_to_rotmat

PX_PER_M = 110  # texture resolution
ROOM = np.array([8.0, 6.0, 3.0])  # x, y extent and height (z up), origin at the floor centre


# -- procedural textures (uint8 RGB, row 0 = top) ---------------------------------------------


def smooth_noise(rng: np.random.Generator, h: int, w: int, cells: int) -> np.ndarray:
    """(h, w) float32 low-frequency noise in about [-1, 1]."""
    import cv2

    grid = rng.standard_normal((max(2, h * cells // w), cells)).astype(np.float32)
    return cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)


def grain(rng: np.random.Generator, h: int, w: int, amount: float) -> np.ndarray:
    return (rng.standard_normal((h, w, 1)) * amount).astype(np.float32)


def random_word(rng: np.random.Generator, n: int) -> str:
    letters = string.ascii_uppercase + string.digits
    return "".join(rng.choice(list(letters), size=n))


def draw_text_block(rng, img, x0, y0, x1, y1, colour) -> None:

    canvas = np.clip(img, 0, 255).astype(np.uint8)  # putText draws on 8-bit images only
    _draw_text(rng, canvas, x0, y0, x1, y1, colour)
    img[...] = canvas


def _draw_text(rng, img, x0, y0, x1, y1, colour) -> None:
    import cv2

    y = y0 + 14
    while y < y1 - 4:
        scale = float(rng.uniform(0.35, 0.7))
        word = " ".join(random_word(rng, int(rng.integers(2, 7))) for _ in range(4))
        font = int(
            rng.choice(
                [
                    cv2.FONT_HERSHEY_SIMPLEX,
                    cv2.FONT_HERSHEY_DUPLEX,
                    cv2.FONT_HERSHEY_COMPLEX,
                    cv2.FONT_HERSHEY_TRIPLEX,
                ]
            )
        )
        cv2.putText(img, word, (x0 + 4, y), font, scale, colour, 1, cv2.LINE_AA)
        y += int(22 * scale + 6)
        if y > y1:
            break
    cv2.rectangle(img, (x0, y0), (x1, y1), colour, 1)


def bricks(rng, h: int, w: int) -> np.ndarray:
    import cv2

    img = np.full((h, w, 3), 175, np.float32)
    bh = 24
    bw = 56
    for r, y in enumerate(range(0, h, bh)):
        off = (bw // 2) * (r % 2)
        for x in range(-off, w, bw):
            base = np.array([150, 60, 45]) + rng.normal(0, 22, 3) + rng.normal(0, 15)
            cv2.rectangle(img, (x + 2, y + 2), (x + bw - 2, y + bh - 2), base.tolist(), -1)
    img *= 1 + 0.25 * smooth_noise(rng, h, w, 8)[:, :, None]
    img += grain(rng, h, w, 10)
    # a few stencil signs
    for _ in range(3):
        x, y = int(rng.integers(20, w - 260)), int(rng.integers(20, h - 80))
        cv2.rectangle(img, (x, y), (x + 230, y + 60), (235, 230, 210), -1)
        draw_text_block(rng, img, x, y, x + 230, y + 60, (20, 20, 60))
    return np.clip(img, 0, 255).astype(np.uint8)


def posters(rng, h: int, w: int) -> np.ndarray:
    import cv2

    img = np.full((h, w, 3), 200, np.float32) + np.array([10, 5, -10])
    img *= 1 + 0.08 * smooth_noise(rng, h, w, 6)[:, :, None]
    x = 20
    while x < w - 120:
        pw, ph = int(rng.integers(100, 200)), int(rng.integers(120, h - 60))
        y = int(rng.integers(20, h - ph - 10))
        bg = rng.integers(40, 230, 3).astype(float).tolist()
        cv2.rectangle(img, (x, y), (x + pw, y + ph), bg, -1)
        for _ in range(int(rng.integers(3, 8))):
            c = rng.integers(0, 255, 3).astype(float).tolist()
            cx, cy = int(rng.integers(x, x + pw)), int(rng.integers(y, y + ph // 2))
            if rng.random() < 0.5:
                cv2.circle(img, (cx, cy), int(rng.integers(5, 30)), c, -1, cv2.LINE_AA)
            else:
                pts = rng.integers([x, y], [x + pw, y + ph // 2], size=(3, 2)).astype(np.int32)
                cv2.fillPoly(img, [pts], c, cv2.LINE_AA)
        ink = (255.0, 255.0, 255.0) if np.mean(bg) < 120 else (10.0, 10.0, 10.0)
        draw_text_block(rng, img, x, y + ph // 2, x + pw, y + ph, ink)
        x += pw + int(rng.integers(15, 60))
    img += grain(rng, h, w, 6)
    return np.clip(img, 0, 255).astype(np.uint8)


def bookshelf(rng, h: int, w: int) -> np.ndarray:
    import cv2

    img = np.full((h, w, 3), (120, 85, 50), np.float32)
    img *= 1 + 0.15 * smooth_noise(rng, h, w, 40)[:, :, None]
    shelf = h // 4
    for s in range(4):
        y0, y1 = s * shelf + 10, (s + 1) * shelf - 6
        cv2.rectangle(img, (0, y1), (w, y1 + 6), (70, 45, 25), -1)
        x = int(rng.integers(5, 30))
        while x < w - 30:
            bw = int(rng.integers(10, 34))
            top = y0 + int(rng.integers(0, 25))
            c = rng.integers(20, 235, 3).astype(float).tolist()
            cv2.rectangle(img, (x, top), (x + bw, y1), c, -1)
            band = int(rng.integers(top + 5, y1 - 10))
            cv2.line(img, (x, band), (x + bw, band), (240, 220, 120), 2)
            x += bw + int(rng.integers(0, 4))
            if rng.random() < 0.08:
                x += int(rng.integers(30, 90))  # gap, maybe a framed picture
                if x < w - 90:
                    cv2.rectangle(img, (x - 80, y0 + 20), (x - 10, y1 - 5), (230, 230, 230), -1)
                    draw_text_block(rng, img, x - 80, y0 + 20, x - 10, y1 - 5, (30, 30, 30))
    img += grain(rng, h, w, 6)
    return np.clip(img, 0, 255).astype(np.uint8)


def tiles(rng, h: int, w: int, tile: int = 55) -> np.ndarray:
    import cv2

    img = np.full((h, w, 3), 90, np.float32)
    palette = np.array(
        [[190, 180, 160], [120, 110, 100], [160, 90, 70], [90, 110, 140], [210, 205, 195]],
        np.float32,
    )
    for y in range(0, h, tile):
        for x in range(0, w, tile):
            c = palette[rng.integers(len(palette))] + rng.normal(0, 12, 3)
            cv2.rectangle(img, (x + 2, y + 2), (x + tile - 2, y + tile - 2), c.tolist(), -1)
            if rng.random() < 0.15:
                cv2.circle(
                    img, (x + tile // 2, y + tile // 2), tile // 4, (60, 60, 60), 2, cv2.LINE_AA
                )
    img *= 1 + 0.12 * smooth_noise(rng, h, w, 10)[:, :, None]
    img += grain(rng, h, w, 8)
    return np.clip(img, 0, 255).astype(np.uint8)


def plaster(rng, h: int, w: int) -> np.ndarray:
    import cv2

    img = np.full((h, w, 3), 215, np.float32)
    img *= 1 + 0.10 * smooth_noise(rng, h, w, 12)[:, :, None]
    for _ in range(6):  # ceiling lamps / vents
        x, y = int(rng.integers(30, w - 80)), int(rng.integers(30, h - 60))
        cv2.rectangle(img, (x, y), (x + 70, y + 30), (250, 250, 240), -1)
        for k in range(5):
            cv2.line(img, (x + 5 + 14 * k, y + 3), (x + 5 + 14 * k, y + 27), (120, 120, 120), 1)
    img += grain(rng, h, w, 5)
    return np.clip(img, 0, 255).astype(np.uint8)


def crate(rng, h: int, w: int) -> np.ndarray:
    import cv2

    base = rng.integers(60, 200, 3).astype(np.float32)
    img = np.full((h, w, 3), 1.0, np.float32) * base
    img *= 1 + 0.2 * smooth_noise(rng, h, w, 30)[:, :, None]
    cv2.rectangle(img, (6, 6), (w - 7, h - 7), (30, 30, 30), 4)
    cv2.line(img, (6, 6), (w - 7, h - 7), (40, 40, 40), 3)
    draw_text_block(rng, img, w // 6, h // 3, 5 * w // 6, 2 * h // 3, (250, 250, 250))
    img += grain(rng, h, w, 8)
    return np.clip(img, 0, 255).astype(np.uint8)


# -- geometry ------------------------------------------------------------------------------------


def textured_quad(corners: np.ndarray, image: np.ndarray, quality: int = 80):
    """A quad (corners: top-left, top-right, bottom-right, bottom-left as seen from the front)
    with ``image`` mapped once over it, as a trimesh.Trimesh with a JPEG texture."""
    import trimesh
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="JPEG", quality=quality)
    buf.seek(0)
    pil = Image.open(buf)
    pil.load()
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], dtype=float)  # v = 0 at the image bottom
    material = trimesh.visual.material.PBRMaterial(
        baseColorTexture=pil, baseColorFactor=[255, 255, 255, 255]
    )
    return trimesh.Trimesh(
        vertices=np.asarray(corners, dtype=float),
        faces=[[0, 1, 2], [0, 2, 3]],
        visual=trimesh.visual.TextureVisuals(uv=uv, material=material),
        process=False,
    )


def textured_box(centre, size, image, yaw_deg: float = 0.0) -> list:
    """Five visible faces (no bottom) of a box standing on the floor, each with ``image``."""
    c = np.asarray(centre, float)
    sx, sy, sz = np.asarray(size, float) / 2
    rot = axis_angle_to_rotmat(np.array([0.0, 0.0, 1.0]), yaw_deg)

    def p(x, y, z):
        return c + rot @ np.array([x * sx, y * sy, z * sz])

    faces = [
        [p(-1, -1, 1), p(1, -1, 1), p(1, -1, -1), p(-1, -1, -1)],  # front (-y)
        [p(1, 1, 1), p(-1, 1, 1), p(-1, 1, -1), p(1, 1, -1)],  # back (+y)
        [p(1, -1, 1), p(1, 1, 1), p(1, 1, -1), p(1, -1, -1)],  # +x
        [p(-1, 1, 1), p(-1, -1, 1), p(-1, -1, -1), p(-1, 1, -1)],  # -x
        [p(-1, 1, 1), p(1, 1, 1), p(1, -1, 1), p(-1, -1, 1)],  # top
    ]
    return [textured_quad(np.array(f), image) for f in faces]


def build_scene(rng: np.random.Generator, variant: str):
    """The room. variant "mesh" is the published mesh; "photo" adds one object and moves one
    box (the small geometry differences between the scan and the world at capture time)."""
    import trimesh

    hx, hy, hz = ROOM[0] / 2, ROOM[1] / 2, ROOM[2]
    ppm = PX_PER_M
    tex = {
        "north": bricks(rng, int(hz * ppm), int(ROOM[0] * ppm)),
        "south": bookshelf(rng, int(hz * ppm), int(ROOM[0] * ppm)),
        "east": posters(rng, int(hz * ppm), int(ROOM[1] * ppm)),
        "west": posters(rng, int(hz * ppm), int(ROOM[1] * ppm)),
        "floor": tiles(rng, int(ROOM[1] * ppm * 0.75), int(ROOM[0] * ppm * 0.75)),
        "ceiling": plaster(rng, int(ROOM[1] * 40), int(ROOM[0] * 40)),
        "crate1": crate(rng, 160, 160),
        "crate2": crate(rng, 160, 160),
        "crate3": crate(rng, 160, 160),
    }
    parts = [
        # walls seen from inside; corners: top-left, top-right, bottom-right, bottom-left
        textured_quad([[-hx, hy, hz], [hx, hy, hz], [hx, hy, 0], [-hx, hy, 0]], tex["north"]),
        textured_quad([[hx, -hy, hz], [-hx, -hy, hz], [-hx, -hy, 0], [hx, -hy, 0]], tex["south"]),
        textured_quad([[hx, hy, hz], [hx, -hy, hz], [hx, -hy, 0], [hx, hy, 0]], tex["east"]),
        textured_quad([[-hx, -hy, hz], [-hx, hy, hz], [-hx, hy, 0], [-hx, -hy, 0]], tex["west"]),
        textured_quad([[-hx, hy, 0], [hx, hy, 0], [hx, -hy, 0], [-hx, -hy, 0]], tex["floor"]),
        textured_quad([[-hx, -hy, hz], [hx, -hy, hz], [hx, hy, hz], [-hx, hy, hz]], tex["ceiling"]),
    ]
    parts += textured_box([2.4, 1.9, 0.45], [0.9, 0.9, 0.9], tex["crate1"], 15.0)
    parts += textured_box([-2.6, -1.8, 0.6], [1.0, 0.8, 1.2], tex["crate2"], -10.0)
    moved = variant == "photo"
    parts += textured_box(
        [-2.9 + (0.35 if moved else 0.0), 2.2, 0.35],
        [0.7, 0.7, 0.7],
        tex["crate3"],
        30.0 + (20.0 if moved else 0.0),
    )
    if variant == "photo":
        # an object that is not in the scan: a tall cabinet in front of the east wall
        extra = crate(np.random.default_rng(7), 160, 160)
        parts += textured_box([3.6, -0.6, 0.8], [0.4, 0.9, 1.6], extra, 0.0)
    scene = trimesh.Scene()
    for i, part in enumerate(parts):
        scene.add_geometry(part, geom_name=f"part{i:02d}")
    return scene
