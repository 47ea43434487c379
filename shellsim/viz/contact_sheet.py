"""A contact sheet: labelled stills side by side in one PNG, to compare the runs of a sweep."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from neural.files import write_atomically

#: Height in pixels of the label strip under each still.
LABEL_HEIGHT = 16


def contact_sheet(stills: Sequence[Path], labels: Sequence[str], path, columns: int | None = None) -> Path:
    """Write ``stills`` (PNG paths, any sizes: each is fitted into the largest one's cell) with ``labels``
    under them in a grid of ``columns`` (default: about square) to the PNG ``path`` (atomically)."""
    from PIL import Image, ImageDraw, ImageFont

    if not stills or len(stills) != len(labels):
        raise ValueError(
            f"stills: expected one label per still, got {len(stills)} stills, {len(labels)} labels"
        )
    images = [Image.open(p).convert("RGB") for p in stills]
    cell_w, cell_h = max(i.width for i in images), max(i.height for i in images)
    columns = columns or math.ceil(math.sqrt(len(images)))
    rows = math.ceil(len(images) / columns)
    sheet = Image.new("RGB", (columns * cell_w, rows * (cell_h + LABEL_HEIGHT)), "white")
    draw, font = ImageDraw.Draw(sheet), ImageFont.load_default()
    for n, (image, label) in enumerate(zip(images, labels, strict=True)):
        x, y = (n % columns) * cell_w, (n // columns) * (cell_h + LABEL_HEIGHT)
        image.thumbnail((cell_w, cell_h))
        sheet.paste(image, (x + (cell_w - image.width) // 2, y + (cell_h - image.height) // 2))
        draw.text((x + 3, y + cell_h + 2), label, fill="black", font=font)
    return write_atomically(path, sheet.save)
