"""The README's picture of a generated frame with its ground truth.

``python benchmarks/synth_picture.py [OUT.png] [--seed N] [--frame N] [--scenario NAME]`` renders the
scene, stops at the requested frame and draws: visible targets' ground-truth boxes (green, with
their ids), occluded targets' boxes (orange, thin: in gt.txt they are absent), and the outlines of
the occluders (tree canopies, overpass) projected into the frame (cyan).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from aerotrack.synth.scene import Scenario


def annotate(image: np.ndarray, H: np.ndarray, truth: list[dict], world) -> np.ndarray:
    """Draw ground truth on a copy of a (H, W, 3) BGR frame; H maps frame -> map pixels."""
    out = image.copy()
    Hinv = np.linalg.inv(H)
    for o in world.occluders:
        for poly in o.get("polygons", []):
            p = np.hstack([poly, np.ones((len(poly), 1))]) @ Hinv.T
            q = p[:, :2] / p[:, 2:] - 0.5  # continuous -> OpenCV pixel-index coordinates
            cv2.polylines(out, [np.round(q * 4).astype(np.int32)], True, (230, 220, 40), 1,
                          cv2.LINE_AA, 2)
    for t in truth:
        if t["state"] == "outside":
            continue
        x, y, w, h = t["box"]
        p0 = (round((x - 0.5) * 4), round((y - 0.5) * 4))
        p1 = (round((x + w - 0.5) * 4), round((y + h - 0.5) * 4))
        if t["state"] == "visible":
            cv2.rectangle(out, p0, p1, (60, 230, 60), 1, cv2.LINE_AA, 2)
            cv2.putText(out, str(t["id"]), (int(x), int(y) - 2), cv2.FONT_HERSHEY_SIMPLEX, 0.35,
                        (60, 230, 60), 1, cv2.LINE_AA)
        else:
            cv2.rectangle(out, p0, p1, (40, 140, 255), 1, cv2.LINE_AA, 2)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", default="docs/images/synth_frame.png")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frame", type=int, default=150)
    ap.add_argument("--scenario", default="default")
    args = ap.parse_args(argv)
    sc = Scenario(seed=args.seed, frames=args.frame, name=args.scenario)
    for frame, H, truth in sc.frames():
        pass
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(args.out, annotate(frame.image, H, truth, sc.world))


if __name__ == "__main__":
    main()
