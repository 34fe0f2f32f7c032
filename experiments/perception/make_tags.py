"""Writes the shipped AprilTags (tag36h11) as printable PNG files into assets/tags/.

    python experiments/perception/make_tags.py [--out assets/tags] [--dpi 300]

One file per tag of `daddpg_jax.deploy.camera.tags.SHIPPED_TAGS`, named
``tag36h11_id<ID>_<SIZE>mm.png``: SIZE is the side of the black square, which must measure
exactly that on paper (print at 100 %, no "fit to page"); the file carries its DPI so that a
printer scales it right, and a white margin of one cell (and a little more) around the square.
Also writes README.md there (what each tag marks and where it goes).
"""

from __future__ import annotations

import argparse
import os
import struct
import sys
import zlib

import cv2
import numpy as np

from daddpg_jax.deploy.camera.calibration import NOMINAL_BOARD
from daddpg_jax.deploy.camera.objects import BAR, POT
from daddpg_jax.deploy.camera.tags import CELLS, FAMILY, SHIPPED_TAGS, tag_image


def _png_with_resolution(img: np.ndarray, ppm: int) -> bytes:
    """PNG bytes of a gray image with a pHYs chunk of ``ppm`` pixels per metre."""
    ok, buf = cv2.imencode(".png", img)
    assert ok
    data = buf.tobytes()
    body = b"pHYs" + struct.pack(">IIB", ppm, ppm, 1)
    chunk = struct.pack(">I", 9) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    end_ihdr = 8 + 8 + 13 + 4  # signature, IHDR length + type, IHDR data, CRC
    return data[:end_ihdr] + chunk + data[end_ihdr:]


def write_tags(out: str, dpi: int = 300) -> list[str]:
    os.makedirs(out, exist_ok=True)
    names = []
    for tag_id, (size, _) in sorted(SHIPPED_TAGS.items()):
        cell_px = max(1, int(round(size / CELLS / 0.0254 * dpi)))
        img = tag_image(tag_id, cell_px)
        img = np.pad(img, cell_px // 2, constant_values=255)
        name = f"{FAMILY}_id{tag_id}_{round(size * 1000)}mm.png"
        with open(os.path.join(out, name), "wb") as f:
            f.write(_png_with_resolution(img, int(round(cell_px * CELLS / size))))
        names.append(name)
    return names


def readme(names) -> str:
    board = "\n".join(f"| {i} | ({c[0]:.2f}, {c[1]:.2f}) | {yaw:.0f} |"
                      for i, (c, yaw, _) in sorted(NOMINAL_BOARD.tags.items()))
    files = "\n".join(f"| `{n}` | {SHIPPED_TAGS[int(n.split('_id')[1].split('_')[0])][1]} |"
                      for n in names)
    return f"""# Printable AprilTags ({FAMILY})

Made by `python experiments/perception/make_tags.py`. The size in each file name is the side
of the tag's black square in millimetres: print at 100 % (the PNG carries its DPI) and check
it with a ruler; the camera path computes every pose from it (`SHIPPED_TAGS` in
`daddpg_jax/deploy/camera/tags.py`). Keep the white margin around the square.

| file | what it marks |
| --- | --- |
{files}

The calibration board (`NOMINAL_BOARD` in `daddpg_jax/deploy/camera/calibration.py`): each tag
lies flat on the table with its centre at (x, y) in the world frame (m), its printed top edge
towards +y (the left arm's side), its printed right edge towards +x (away from the arms):

| id | centre (x, y) | yaw |
| --- | --- | --- |
{board}

The bar's tag ({BAR.tag_id}) is centred on the top of the bar's middle, its printed top edge
towards the bar's left end (+y); the pot's tag ({POT.tag_id}) lies on the lid with its centre
{POT.tag_pos[0] * 100:.1f} cm in front of the knob's axis (towards +x when the pot stands
square), its printed top edge towards the left handle.
"""


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="assets/tags")
    p.add_argument("--dpi", type=int, default=300)
    args = p.parse_args(argv)
    names = write_tags(args.out, args.dpi)
    with open(os.path.join(args.out, "README.md"), "w") as f:
        f.write(readme(names))
    print("\n".join(os.path.join(args.out, n) for n in names))
    return 0


if __name__ == "__main__":
    sys.exit(main())
