"""The contact sheet of docs/plant.md: each planted failure at severity ``high`` in a RealEstate10K
clip, clean and planted, with the region outlined and what the project's optical flow recovers.

    .venv/bin/python scripts/plant_sheet.py [OUT.png]   # default: docs/images/plant-sheet.png

Rows: ``morph``, ``redraw``, ``breathing``, ``slide`` (seed 0, the first 10 frames; the frame of the
largest damage). Columns: the clean clip, the planted clip (the region's rim in green), and for the
kinds that move content the length of the DIS flow from the clean to the planted frame (0 to 10 px,
black to white), for ``redraw`` the grey difference of the two (0 to 64 levels). Written as an
indexed PNG (256 colours) to stay small.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT.parent / "shared" / "data" / "real" / "realestate10k" / "0bf152ef84195293.mp4"
KINDS = ("morph", "redraw", "breathing", "slide")
SCALE = 2 / 3
LABEL_H = 22


def _frames(path: Path) -> list[np.ndarray]:
    from geocon_core.media import open_video

    _fps, frames = open_video(str(path))
    return list(frames)


def _tile(bgr: np.ndarray, label: str, rim: list[list[float]] | None = None) -> np.ndarray:
    small = cv2.resize(bgr, None, fx=SCALE, fy=SCALE, interpolation=cv2.INTER_AREA)
    if rim is not None:
        points = np.round((np.array(rim) + 0.5) * SCALE - 0.5).astype(np.int32)
        cv2.polylines(small, [points], True, (0, 255, 0), 2, cv2.LINE_AA)
    bar = np.full((LABEL_H, small.shape[1], 3), 255, np.uint8)
    cv2.putText(bar, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([bar, small])


def sheet(out: Path) -> None:
    from geocon_core.flow import make_flow_backend
    from geocon_core.plant import plant_clip

    rows = []
    flow = make_flow_backend("dis")
    with tempfile.TemporaryDirectory() as tmp:
        for kind in KINDS:
            result = plant_clip(CLIP, kind, "high", 0, tmp, frames=10)
            gains = np.abs(result.truth["displacement"]["gain"])
            t = int(np.argmax(gains))
            clean, planted = _frames(result.clean)[t], _frames(result.planted)[t]
            region = result.planting.region
            rim = None if region is None else region.polygon(t)
            g0, g1 = (cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in (clean, planted))
            if kind == "redraw":
                diff = np.abs(g0.astype(np.int16) - g1)
                third = np.clip(diff * 4, 0, 255).astype(np.uint8)
                what = "|planted - clean|, 0-64 grey levels"
            else:
                length = np.linalg.norm(flow.compute(g0, g1).flow, axis=2)
                third = np.clip(length * 25.5, 0, 255).astype(np.uint8)
                what = "recovered flow length, 0-10 px"
            amp = f"blend {result.truth['amplitude']:g}" if kind == "redraw" else f"{result.truth['amplitude']:g} px"
            rows.append(
                np.hstack(
                    [
                        _tile(clean, f"clean, frame {t}"),
                        _tile(planted, f"{kind} high ({amp}), frame {t}", rim),
                        _tile(cv2.cvtColor(third, cv2.COLOR_GRAY2BGR), what),
                    ]
                )
            )
    image = Image.fromarray(cv2.cvtColor(np.vstack(rows), cv2.COLOR_BGR2RGB))
    out.parent.mkdir(parents=True, exist_ok=True)
    image.quantize(256, dither=Image.Dither.NONE).save(out, optimize=True)
    print(f"{out}: {out.stat().st_size / 1024:.0f} KiB")


if __name__ == "__main__":
    sheet(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "images" / "plant-sheet.png")
