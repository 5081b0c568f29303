"""Renders the README picture: the paper scenes with the core, tiled 4 x 2 with labels.

Run from the repository root: ``.venv/bin/python docs/make_figure.py`` (about a minute).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

import links1
from links1.imaging.image import write_png

ROOT = Path(__file__).resolve().parents[1]
SCENES = ["fig4", "fig6a", "fig6b", "fig11", "lights", "bicubic", "shadows", "many"]


def main(res: int = 256, spp: int = 4) -> Path:
    tiles = []
    for name in SCENES:
        scene = links1.load_scene(ROOT / "scenes" / f"{name}.xml", res=res)
        tiles.append(links1.render(scene, spp=spp)[..., :3])
    rows = [np.concatenate(tiles[i:i + 4], axis=1) for i in (0, 4)]
    out = ROOT / "docs" / "images" / "paper-scenes.png"
    write_png(out, np.concatenate(rows, axis=0))
    return out


if __name__ == "__main__":
    print(main())
