"""``aerotrack mosaic``: register a video and paint its frames onto the map (Yu & Medioni fig. 2)."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from .common import PathArg, config_option, fps_option, make_progress, root_flags, set_option

log = logging.getLogger("aerotrack")

#: Share of the frames' ground outside the map above which ``mosaic --map`` warns.
OFF_MAP_WARN = 0.05


@click.command("mosaic")
@click.argument("input_path", metavar="INPUT", type=PathArg())
@click.option("--out", "out_path", required=True, type=PathArg(dir_okay=False),
              help="Output picture (.png, .jpg, or .tif: a GeoTIFF with --map; a .png or .jpg "
                   "gets a world file and a .aux.xml with the CRS beside it).")
@click.option("--map", "map_path", type=PathArg(dir_okay=False), default=None,
              help="Georeferenced map raster; the frames are painted onto it.")
@click.option("--map-init", "map_init_path", type=PathArg(dir_okay=False), default=None,
              help="Frame 1 -> map: a 3x3 homography or >= 4 control points (needs --map).")
@fps_option
@click.option("--stride", type=int, default=10, show_default=True,
              help="Paint every N-th frame (every frame is registered).")
@click.option("--max-side", type=int, default=4000, show_default=True,
              help="Longest side of the picture in pixels.")
@click.option("--registration", "reg_csv", type=PathArg(dir_okay=False), default=None,
              help="Also write the per-frame homographies as registration.csv here.")
@click.option("--outlines/--no-outlines", default=True, show_default=True,
              help="Draw frame outlines: the first frame green, the last red, and about every "
                   "twelfth of the painted frames yellow (burned into the picture).")
@config_option
@set_option
@click.pass_context
def mosaic_command(ctx, input_path, out_path, map_path, map_init_path, fps, stride, max_side, reg_csv,
                   outlines, config_path, overrides):
    """Register every frame of INPUT (video or image folder) and paint them into one picture.

    With --map and --map-init the frames are painted onto the map in map pixels (registration
    refined against the map); without a map, onto frame 1's plane, at most twice frame 1's
    diagonal around it (an oblique view reaches the horizon). Outlines: first frame green, last
    red, others yellow (--no-outlines: none). With a map the picture is georeferenced: a .tif is a GeoTIFF in the map's CRS, a
    .png or .jpg gets a world file (.pgw, .jgw) and a .aux.xml naming the CRS, which QGIS and
    GDAL read.

    \b
    Examples:
      aerotrack mosaic flight.mp4 --out mosaic.jpg
      aerotrack mosaic frames/ --out geo.tif --map ortho.tif --map-init h.txt --stride 5
    """
    import cv2

    from ..config import load_config
    from ..errors import InputError, OutputError
    from ..geo import GeoMap, read_map_init
    from ..io import open_source
    from ..io.output import atomic_write_bytes, check_apart, check_writable
    from ..registration import FrameRegistrar, write_registration_csv
    from ..registration.mosaic import paint_mosaic, picture_geotransform, share_off_map, world_file_text

    out = Path(out_path)
    if out.suffix.lower() not in (".png", ".jpg", ".jpeg", ".tif", ".tiff"):
        raise InputError(f"--out {out}: must end in .png, .jpg or .tif")
    if stride < 1:
        raise InputError(f"--stride {stride}: must be at least 1")
    if max_side < 64:
        raise InputError(f"--max-side {max_side}: must be at least 64")
    if (map_path is None) != (map_init_path is None):
        raise InputError("--map and --map-init must be given together")
    config = load_config(config_path, overrides)
    source = open_source(input_path, fps)
    inputs = [("INPUT", input_path), ("--map", map_path), ("--map-init", map_init_path)]
    check_apart(out, "--out", inputs)
    check_writable(out, "--out")  # before registering the whole video, not after
    if reg_csv is not None:
        check_apart(reg_csv, "--registration", [*inputs, ("--out", out)])
        check_writable(reg_csv, "--registration")
    geomap = H_init = None
    if map_path is not None:
        geomap = GeoMap(map_path)
        H_init = read_map_init(map_init_path, geomap)
    registrar = FrameRegistrar(config.registration, source.fps, geomap, H_init)
    regs = []
    progress, close = make_progress(source.count, "mosaic", *root_flags(ctx))
    try:
        for frame in source:
            regs.append(registrar.step(frame))
            progress(len(regs))
    finally:
        close()
    if not regs:
        raise InputError(f"{input_path}: no frames")
    log.info("mosaic: registration %s", registrar.summary()["status_counts"])
    Hs = {r.index: r.H for r in regs}
    base = geomap.read_image() if geomap is not None else None
    if base is not None:
        off = share_off_map(Hs.values(), *source.size, (base.shape[1], base.shape[0]))
        if off > OFF_MAP_WARN:
            log.warning("mosaic: %.0f%% of the frames' ground lies outside the map and is not in "
                        "the picture, which covers the map (without --map the frames are "
                        "painted whole, on frame 1's plane)", 100 * off)
    n_painted = (len(regs) + stride - 1) // stride
    if base is None:
        import numpy as np

        from ..registration.mosaic import mosaic_bounds

        w, h = source.size
        whole = mosaic_bounds(Hs.values(), w, h)
        if mosaic_bounds(Hs.values(), w, h, 2.0 * float(np.hypot(w, h))) != whole:
            # (the picture was cut there with no word: truck4's later flight over the city was
            # a sliver near frame 1's horizon)
            log.warning("mosaic: the frames reach beyond twice frame 1's diagonal on its plane "
                        "(an oblique view towards the horizon, or a long flight): the picture "
                        "shows that much around frame 1; --map paints them onto a map instead")
    img, S = paint_mosaic(source.frames(stride=stride), Hs, source.size, base=base,
                          max_side=max_side,
                          outline_every=max(1, n_painted // 12) if outlines else 0,
                          with_transform=True)
    beside: list[tuple[Path, bytes]] = []  # world file and CRS of a georeferenced .png/.jpg
    if geomap is not None and out.suffix.lower() in (".tif", ".tiff"):
        data = _geotiff_bytes(img, picture_geotransform(geomap, S), geomap.crs)
    else:
        ok, buf = cv2.imencode(out.suffix.lower(), img)
        if not ok:
            raise OutputError(f"--out {out}: cannot encode the picture")
        data = buf.tobytes()
        if geomap is not None:
            gt = picture_geotransform(geomap, S)
            world = out.with_suffix(".pgw" if out.suffix.lower() == ".png" else ".jgw")
            beside = [(world, world_file_text(gt).encode()),
                      (Path(str(out) + ".aux.xml"), _aux_xml(geomap.crs).encode())]
    for option, path, write in (("--out", out, lambda: atomic_write_bytes(out, data)),
                                *(("--out", p, (lambda p=p, b=b: atomic_write_bytes(p, b)))
                                  for p, b in beside),
                                ("--registration", reg_csv,
                                 lambda: write_registration_csv(reg_csv, regs))):
        if path is not None:
            try:
                write()
            except OutputError as exc:
                raise OutputError(f"{option} {exc}") from None
    if not root_flags(ctx)[0]:  # -q: nothing but warnings and errors
        every = "every frame" if stride == 1 else f"every {_ordinal(stride)} frame"
        click.echo(f"{out}: {len(regs)} frame{'s' * (len(regs) != 1)} registered, {every} "
                   f"painted ({img.shape[1]}x{img.shape[0]} px)")


def _geotiff_bytes(img, transform, crs) -> bytes:
    """A BGR picture as GeoTIFF bytes (RGB bands, deflate) in ``crs`` with ``transform``."""
    import numpy as np
    from rasterio.io import MemoryFile

    h, w = img.shape[:2]
    with MemoryFile() as mem:
        with mem.open(driver="GTiff", width=w, height=h, count=3, dtype="uint8", crs=crs,
                      transform=transform, compress="deflate", photometric="RGB") as ds:
            ds.write(np.ascontiguousarray(img[:, :, ::-1].transpose(2, 0, 1)))
        return mem.read()


def _aux_xml(crs) -> str:
    """GDAL's side-car ``.aux.xml`` naming the picture's CRS (a world file holds no CRS)."""
    from xml.sax.saxutils import escape

    return f"<PAMDataset>\n  <SRS>{escape(crs.to_wkt())}</SRS>\n</PAMDataset>\n"


def _ordinal(n: int) -> str:
    """2nd, 3rd, 11th, 21st, ..."""
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"
