"""Writing a generated scene to disk (``aerotrack synth``) and perturbing its map."""

from __future__ import annotations

import json
import logging
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from ..errors import OutputError
from ..io.mot import format_mot_rows
from ..io.output import OutputDir, atomic_write_text
from .scene import Scenario
from .world import ROADS

log = logging.getLogger(__name__)


def render_to(out: OutputDir | str | Path, *, seed: int = 0, frames: int = 900,
              size: tuple[int, int] = (640, 480), fps: float = 30.0, scenario: str = "default",
              jpeg_quality: int = 90, progress: Callable[[int], None] | None = None,
              gsd_scale: float = 1.0) -> dict:
    """Render a scene into ``out`` and return its ``scenario.json`` content.

    Writes ``frames/000001.jpg...``, ``gt.txt`` (MOTChallenge, visible targets only; x, y = the
    ground point in the map CRS, lon/lat, so `aerotrack eval --geo-crs EPSG:4326` scores positions),
    ``states.csv`` (every target every frame: state visible/occluded/outside, map pixel and lon/lat
    position, box, heading, speed; ``heading_deg`` is the direction of travel on the map image,
    from its +x axis (east) towards +y (down, south), so 90 is south and 270 north: not the
    compass bearing of ``observations.csv``), ``homographies.csv`` (true frame -> map pixels), ``map.tif``,
    ``map_init.txt`` (frame-1 homography), ``map_init_gcps.csv`` and ``map_init_lonlat.csv``
    (control points), ``occluders.csv`` (bounding boxes), ``occluders.geojson`` (outlines, lon/lat,
    with map pixels in a ``map_px`` property), ``roads.geojson`` (the road centre-lines, lon/lat) and ``scenario.json``.
    ``gsd_scale``: see :class:`Scenario`.
    """
    if not isinstance(out, OutputDir):
        out = OutputDir(out)
    sc = Scenario(seed=seed, frames=frames, size=size, fps=fps, name=scenario, gsd_scale=gsd_scale)
    world = sc.world
    # Frames are written into .partial/frames (no per-file fsync: 900 of them dominated the run
    # time) and the folder is renamed into place once every frame is there.
    fdir = out.partial / "frames"
    if fdir.exists():
        shutil.rmtree(fdir)
    fdir.mkdir(parents=True)
    gt_rows, state_lines, hom_lines = [], [], []
    state_lines.append("frame,id,state,map_x,map_y,lon,lat,bb_left,bb_top,bb_width,bb_height,"
                       "heading_deg,speed_mps,occluder_distance_m")
    hom_lines.append("frame,h00,h01,h02,h10,h11,h12,h20,h21,h22")
    H1 = None
    counts = {"visible": 0, "occluded": 0, "outside": 0}
    params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)]
    for frame, H, truth in sc.frames():
        if H1 is None:
            H1 = H
        ok, buf = cv2.imencode(".jpg", frame.image, params)
        if not ok:
            raise OutputError(f"--out {out.path}: JPEG encoding of frame {frame.index} failed")
        (fdir / f"{frame.index:06d}.jpg").write_bytes(buf.tobytes())
        hom_lines.append(f"{frame.index}," + ",".join(f"{v:.12g}" for v in H.reshape(-1)))
        lonlat = world.geomap.pixel_to_lonlat(np.array([t["map"] for t in truth]))
        for t, ll in zip(truth, lonlat):
            b = t["box"]
            counts[t["state"]] += 1
            state_lines.append(
                f"{t['frame']},{t['id']},{t['state']},{t['map'][0]:.4f},{t['map'][1]:.4f},"
                f"{ll[0]:.8f},{ll[1]:.8f},{b[0]:.3f},{b[1]:.3f},{b[2]:.3f},{b[3]:.3f},"
                f"{t['heading']:.2f},{t['speed']:.3f},{t['occ_dist_m']:.2f}")
            if t["state"] == "visible":
                gt_rows.append([t["frame"], t["id"], *b, 1, ll[0], ll[1], -1])
        if progress:
            progress(frame.index)
    atomic_write_text(out.file("gt.txt"), format_mot_rows(gt_rows))
    atomic_write_text(out.file("states.csv"), "\n".join(state_lines) + "\n")
    atomic_write_text(out.file("homographies.csv"), "\n".join(hom_lines) + "\n")
    _write_map(out.file("map.tif"), world)
    atomic_write_text(out.file("map_init.txt"),
                      "\n".join(" ".join(f"{v:.12g}" for v in row) for row in H1) + "\n")
    w, h = size
    src = np.array([[w * 0.1, h * 0.1], [w * 0.9, h * 0.1], [w * 0.9, h * 0.9], [w * 0.1, h * 0.9],
                    [w * 0.5, h * 0.5], [w * 0.3, h * 0.7]])
    hp = np.hstack([src, np.ones((len(src), 1))]) @ H1.T
    dst = hp[:, :2] / hp[:, 2:]
    ll = world.geomap.pixel_to_lonlat(dst)
    atomic_write_text(out.file("map_init_gcps.csv"), "frame_x,frame_y,map_x,map_y\n" + "".join(
        f"{a:.3f},{b:.3f},{c:.6f},{d:.6f}\n" for (a, b), (c, d) in zip(src, dst)))
    atomic_write_text(out.file("map_init_lonlat.csv"), "frame_x,frame_y,lon,lat\n" + "".join(
        f"{a:.3f},{b:.3f},{c:.9f},{d:.9f}\n" for (a, b), (c, d) in zip(src, ll)))
    atomic_write_text(out.file("occluders.csv"), "kind,x0,y0,x1,y1\n" + "".join(
        f"{o['kind']},{o['x0']:.1f},{o['y0']:.1f},{o['x1']:.1f},{o['y1']:.1f}\n"
        for o in world.occluders))
    atomic_write_text(out.file("occluders.geojson"), _occluders_geojson(world))
    # the road centre-lines the vehicles drive (lon/lat), for `track --roads` / `predict --roads`
    atomic_write_text(out.file("roads.geojson"), ROADS.read_text(encoding="utf-8"))
    info = {
        "seed": seed, "scenario": scenario, "frames": frames, "fps": fps, "size": list(size),
        "map_metres_per_pixel": [world.mx, world.my], "camera_gsd_m": sc.camera.gsd0,
        "gsd_scale": sc.gsd_scale,
        "vehicles": len(sc.vehicles), "gt_rows": len(gt_rows), "states": counts,
        "occluders": len(world.occluders),
        "attribution": "map: solaris 0.4.0 test tile (Apache-2.0), imagery likely SpaceNet "
                       "(CC BY-SA 4.0)",
    }
    atomic_write_text(out.file("scenario.json"), json.dumps(info, indent=2) + "\n")
    os.replace(fdir, out.file("frames"))
    out.finish()
    return info


def _occluders_geojson(world) -> str:
    """Occluder outlines as an RFC 7946 GeoJSON FeatureCollection: lon/lat geometry (GIS tools
    place it on the map), and the same rings in map pixels (col, row) in each feature's ``map_px``
    property, for scoring against ``states.csv``'s ``map_x, map_y``.

    One feature per occluder (``kind`` tree or overpass), a Polygon or MultiPolygon of its mask's
    outline(s). (The geometry was in map pixels, read by GDAL as degrees: latitudes up to 1170.)
    """
    feats = []
    for i, o in enumerate(world.occluders, start=1):
        rings = [np.vstack([q, q[:1]]) for q in o.get("polygons", [])]
        if not rings:
            continue
        px = [[[round(float(x), 3), round(float(y), 3)] for x, y in r] for r in rings]
        ll = [[[round(float(x), 9), round(float(y), 9)] for x, y in world.geomap.pixel_to_lonlat(r)]
              for r in rings]
        geom = ({"type": "Polygon", "coordinates": ll} if len(ll) == 1
                else {"type": "MultiPolygon", "coordinates": [[r] for r in ll]})
        feats.append({"type": "Feature", "id": i,
                      "properties": {"kind": o["kind"], "map_px": px},
                      "geometry": geom})
    return json.dumps({"type": "FeatureCollection", "features": feats}) + "\n"


def _write_map(path: Path, world) -> None:
    """The colourised map as a 3-band uint8 GeoTIFF on the tile's grid (CRS and transform)."""
    import rasterio

    rgb = world.image[..., ::-1].transpose(2, 0, 1)
    tmp = path.with_name(f".{path.name}.tmp")
    with rasterio.open(tmp, "w", driver="GTiff", width=world.width, height=world.height, count=3,
                       dtype="uint8", crs=world.geomap.crs, transform=world.geomap.transform,
                       compress="deflate", photometric="RGB") as ds:
        ds.write(rgb)
    tmp.replace(path)


def perturb_map(image: np.ndarray, rng: np.random.Generator | int | None = None, *,
                strength: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A map as a satellite image of another date would show it.

    Gamma and contrast change, blur, a seasonal colour shift (greener or browner vegetation), and a
    resampling by a small offset and scale. Returns (perturbed image, 3x3 homography from the
    original's pixels to the perturbed image's pixels), so tests know the true correspondence.
    """
    rng = np.random.default_rng(rng)
    img = image.astype(np.float32) / 255.0
    gamma = 1.0 + strength * rng.uniform(-0.25, 0.25)
    contrast = 1.0 + strength * rng.uniform(-0.2, 0.2)
    img = np.clip((img ** gamma - 0.5) * contrast + 0.5 + strength * rng.uniform(-0.05, 0.05), 0, 1)
    season = 1.0 + strength * rng.uniform(-0.12, 0.12, 3).astype(np.float32)
    img = np.clip(img * season[None, None, :], 0, 1)
    sigma = 0.5 + strength * rng.uniform(0.3, 1.0)
    img = cv2.GaussianBlur(img, (0, 0), sigma)
    scale = 1.0 + strength * rng.uniform(-0.03, 0.03)
    off = strength * rng.uniform(-2.0, 2.0, 2)
    A = np.array([[scale, 0, off[0]], [0, scale, off[1]], [0, 0, 1.0]])
    h, w = img.shape[:2]
    out = cv2.warpPerspective(img, A, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return np.clip(out * 255 + 0.5, 0, 255).astype(np.uint8), A
