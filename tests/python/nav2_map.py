#!/usr/bin/env python3
"""Load a map_server map the way nav2's map_io does, with readers smokenav
did not write (PyYAML, Pillow), and print its cells as JSON.

Usage: nav2_map.py MAP.yaml

Prints one JSON object: width, height, resolution, origin, mode, negate (as
read) and cells (row-major from the lower-left corner, -1 unknown, 0..100),
the layout of nav_msgs/OccupancyGrid.data. Follows nav2_map_server's
loadMapFromYaml/loadMapFromFile:

- `negate` must be 0/1 or a bool; `mode` trinary (default), scale or raw;
- shade = mean of R, G, B in [0, 1]; in trinary mode an image with an
  alpha channel averages alpha in; occ = shade if negate else 1 - shade;
- trinary: occ > occupied_thresh -> 100, occ < free_thresh -> 0, else -1;
- scale: a pixel that is not opaque -> -1, else the same thresholds, with
  values in between mapped linearly to 1..99;
- raw: round(shade * 255), kept when in 0..100, else -1;
- image row 0 is the top of the map.
"""

import json
import os
import sys

import yaml
from PIL import Image


def load(path):
    with open(path) as f:
        doc = yaml.safe_load(f)
    negate = doc.get("negate", 0)
    if isinstance(negate, bool):
        negate = int(negate)
    if negate not in (0, 1):
        raise SystemExit(f"{path}: negate must be 0 or 1, got {negate!r}")
    mode = doc.get("mode", "trinary")
    if mode not in ("trinary", "scale", "raw"):
        raise SystemExit(f"{path}: unknown mode {mode!r}")
    occ_t = float(doc["occupied_thresh"])
    free_t = float(doc["free_thresh"])
    image_path = os.path.join(os.path.dirname(path), doc["image"])
    img = Image.open(image_path)
    has_alpha = img.mode in ("LA", "RGBA", "PA") or "transparency" in img.info
    rgba = img.convert("RGBA")
    w, h = rgba.size
    px = rgba.load()
    cells = [0] * (w * h)
    for y in range(h):
        for x in range(w):
            r, g, b, a = px[x, y]
            if mode == "trinary" and has_alpha:
                shade = (r + g + b + a) / 4.0 / 255.0
            else:
                shade = (r + g + b) / 3.0 / 255.0
            occ = shade if negate else 1.0 - shade
            if mode == "raw":
                v = round(shade * 255.0)
                cell = v if 0 <= v <= 100 else -1
            elif mode == "scale" and a != 255:
                cell = -1
            elif occ > occ_t:
                cell = 100
            elif occ < free_t:
                cell = 0
            elif mode == "trinary":
                cell = -1
            else:
                cell = round(1 + 98 * (occ - free_t) / (occ_t - free_t))
            cells[w * (h - 1 - y) + x] = cell
    return {
        "width": w,
        "height": h,
        "resolution": float(doc["resolution"]),
        "origin": [float(v) for v in doc["origin"]],
        "mode": mode,
        "negate": negate,
        "negate_text": open(path).read().split("negate:")[1].split("\n")[0].strip(),
        "cells": cells,
    }


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    print(json.dumps(load(sys.argv[1])))
