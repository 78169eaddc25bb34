"""Residual -> blobs: hysteresis with attached parts, and the region rule of shadow removal."""

from __future__ import annotations

import cv2
import numpy as np

from aerotrack.detection.blobs import Blob, edge_extent, hysteresis_blobs, join_cabs, regrow_small
from aerotrack.detection.shadows import remove_shadows, shadow_mask, trim_shadow_side

ROAD = (70, 72, 74)  # grey asphalt, BGR


def scene(vehicle_bgr: tuple, shadow: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 40x60 road background, a frame with a 10x20 vehicle at (10, 15) and optionally its cast
    shadow (the road at half brightness) in the 4 rows below it; the changed pixels as fg."""
    rng = np.random.default_rng(0)
    bg = np.clip(np.array(ROAD, float) + rng.normal(0, 2, (40, 60, 3)), 0, 255).astype(np.uint8)
    img = bg.copy()
    if shadow:
        img[20:24, 17:37] = (bg[20:24, 17:37] * 0.5).astype(np.uint8)
    img[10:20, 15:35] = vehicle_bgr
    fg = np.zeros((40, 60), bool)
    fg[10:20, 15:35] = True
    if shadow:
        fg[20:24, 17:37] = True
    return img, bg, fg


def test_bright_vehicle_loses_its_shadow():
    img, bg, fg = scene((200, 205, 210), shadow=True)
    out = remove_shadows(fg, img, bg)
    assert out[10:20, 15:35].all()
    assert not out[20:24].any()


def test_a_sky_lit_shadow_on_warm_asphalt_is_a_shadow():
    """Sunlit asphalt is a little warm (saturated enough for a hue); its shadow, lit by the blue
    sky alone, is grey-blue: the hues differ by ~150 degrees though neither pixel has much colour
    (UAV123 truck4's truck and the shadow it casts on the road)."""
    rng = np.random.default_rng(0)
    bg = np.clip(np.array((80, 92, 100), float) + rng.normal(0, 2, (40, 60, 3)), 0, 255)
    bg = bg.astype(np.uint8)
    img = bg.copy()
    img[10:20, 15:35] = (60, 150, 210)  # an orange truck
    img[10:20, 35:45] = (46, 41, 39)  # its shadow beside it
    fg = np.zeros((40, 60), bool)
    fg[10:20, 15:45] = True
    assert shadow_mask(img, bg)[10:20, 35:45].all()
    out = remove_shadows(fg, img, bg)
    assert out[10:20, 15:35].all() and not out[10:20, 35:45].any()


def test_dark_vehicle_is_kept_whole():
    # A dark grey vehicle darkens the road by ~0.65 without changing hue or saturation:
    # every one of its pixels passes Prati et al.'s test, yet it is no shadow.
    img, bg, fg = scene((45, 47, 48), shadow=False)
    assert shadow_mask(img, bg)[fg].mean() > 0.95
    out = remove_shadows(fg, img, bg)
    assert (out == fg).all()
    # The pixel test alone (min_core 0) erases it.
    assert not remove_shadows(fg, img, bg, min_core=0.0).any()


def test_shadow_rule_is_per_region():
    # A bright vehicle with a shadow and, apart, a dark vehicle: each region decides alone.
    img, bg, fg = scene((200, 205, 210), shadow=True)
    img[28:36, 42:56] = (45, 47, 48)
    fg[28:36, 42:56] = True
    out = remove_shadows(fg, img, bg)
    assert not out[20:24].any()
    assert out[28:36, 42:56].all()


def test_remove_shadows_reports_what_it_removed_and_kept():
    img, bg, fg = scene((200, 205, 210), shadow=True)
    info: dict = {}
    remove_shadows(fg, img, bg, info=info)
    assert info == {"removed": 4 * 20, "kept_shaded": 0}
    img, bg, fg = scene((45, 47, 48), shadow=True)
    remove_shadows(fg, img, bg, info=info)
    assert info["removed"] == 0 and info["kept_shaded"] > 0.9 * fg.sum()


def test_a_coloured_vehicles_shadow_passes_with_chroma_tolerance():
    """4:2:0 video: the shadow row next to a blue car takes the car's colour; with a one-pixel
    colour tolerance it is still a shadow, without it it is part of the car."""
    img, bg, fg = scene((160, 70, 30), shadow=True)
    img[20, 17:35] = (45, 34, 28)  # the shadow (35, 36, 37) with the car's colour bled in
    assert not shadow_mask(img, bg)[20, 17:35].any()
    assert shadow_mask(img, bg, chroma_tolerance_px=1)[20, 17:35].all()
    out = remove_shadows(fg, img, bg, chroma_tolerance_px=1)
    assert not out[20:24].any() and out[10:20, 15:35].all()
    assert out[20].sum() < remove_shadows(fg, img, bg)[20].sum()


def test_dark_vehicles_lose_the_growth_their_shadow_adds():
    boxes = np.array([[100.0, 50, 20, 13], [10, 10, 18, 10]])  # dark (with shadow), light
    growth = [np.array([0.0, 0, 2, 3]), np.array([0.0, 0, 2, 3]), np.array([0.0, 1, 3, 3])]
    out = trim_shadow_side(boxes, np.array([True, False]), growth)
    assert np.allclose(out[0], [100, 50, 18, 10]) and np.allclose(out[1], boxes[1])
    # too few vehicles to measure the sun's offset: unchanged; never below half a side
    assert np.allclose(trim_shadow_side(boxes, np.array([True, False]), growth[:1]), boxes)
    tiny = trim_shadow_side(np.array([[0.0, 0, 4, 4]]), np.array([True]), growth)
    assert np.allclose(tiny, [[0, 0, 2, 2]])


def two_part_vehicle() -> tuple[np.ndarray, np.ndarray]:
    """Low mask of a vehicle broken by a 3-pixel gap, only its left part holding a seed pixel."""
    low = np.zeros((30, 40), np.uint8)
    low[10:16, 5:14] = 1
    low[10:16, 17:26] = 1
    high = np.zeros_like(low)
    high[12, 8] = 1
    return low, high


def test_unseeded_part_near_a_seeded_one_is_attached():
    low, high = two_part_vehicle()
    blobs = hysteresis_blobs(low, high, close_radius=1.0, min_area=4)
    assert len(blobs) == 1
    assert blobs[0].box == (5, 10, 21, 6)
    assert blobs[0].area == 2 * 6 * 9


def test_plain_hysteresis_and_far_parts_drop_unseeded():
    low, high = two_part_vehicle()
    blobs = hysteresis_blobs(low, high, close_radius=1.0, min_area=4, attach_gap=0.0)
    assert [b.box for b in blobs] == [(5, 10, 9, 6)]
    # An unseeded region far from any seeded one is noise.
    low[25:29, 34:39] = 1
    blobs = hysteresis_blobs(low, high, close_radius=1.0, min_area=4)
    assert [b.box for b in blobs] == [(5, 10, 21, 6)]


def _rect_blob(x: int, y: int, w: int, h: int):
    from aerotrack.detection.blobs import Blob

    return Blob((x, y, w, h), np.ones((h, w), bool))


def test_typical_sides_is_the_median_oriented_extent():
    from aerotrack.detection.blobs import typical_sides

    blobs = [_rect_blob(10 * k, 0, 20, 8) for k in range(4)] + [_rect_blob(0, 50, 6, 30)]
    assert typical_sides(blobs[:4]) is None  # too few blobs to trust a median
    long_, short = typical_sides(blobs)
    assert abs(long_ - 20) <= 1 and abs(short - 8) <= 1


def test_drop_small_removes_fragments_and_debris_but_not_vehicles():
    from aerotrack.detection.blobs import drop_small

    cars = [_rect_blob(0, 30 * k, 20, 8) for k in range(5)]  # 160 px each
    beside = _rect_blob(22, 0, 4, 4)  # a leftover fragment next to car 0
    alone = _rect_blob(200, 200, 5, 5)  # debris far from every car
    blobs = cars + [beside, alone]
    assert drop_small(blobs, area_ratio=0.0) == blobs
    assert drop_small(blobs, area_ratio=0.4) == cars
    # near: only fragments within a typical length (20 px) of a vehicle go
    assert drop_small(blobs, area_ratio=0.4, near=1.0) == cars + [alone]
    # a frame with too few blobs has no trusted median: nothing is dropped
    assert drop_small(cars[:2] + [beside], area_ratio=0.4) == cars[:2] + [beside]


def _soft_rect(contrast: float, x0: float, y0: float, x1: float, y1: float,
               blur: float = 0.8) -> np.ndarray:
    """Residual of a flat vehicle of ``contrast`` grey levels covering the continuous box
    ``[x0, x1) x [y0, y1)`` (pixel area coverage from 8x supersampling), blurred."""
    s = 8
    yy, xx = (np.mgrid[0:40 * s, 0:40 * s] + 0.5) / s
    fine = ((xx >= x0) & (xx < x1) & (yy >= y0) & (yy < y1)).astype(np.float32)
    cover = cv2.resize(fine, (40, 40), interpolation=cv2.INTER_AREA)
    return cv2.GaussianBlur(cover * contrast, (0, 0), blur)


def test_edge_extent_puts_the_box_at_the_half_contrast_edge_whatever_the_contrast():
    truth = (10.0, 12.0, 30.0, 22.0)
    thr = 10.0
    fixed, edged = [], []
    for contrast in (25.0, 60.0, 200.0):
        res = _soft_rect(contrast, *truth)
        mask = res > thr
        ys, xs = np.nonzero(mask)
        fixed.append((xs.min(), ys.min(), xs.max() + 1, ys.max() + 1))
        edged.append(edge_extent(res, mask, level=0.5, floor=0.5 * thr))
    # a fixed threshold reaches further out the brighter the vehicle ...
    assert fixed[2][2] - fixed[2][0] >= fixed[0][2] - fixed[0][0] + 2
    # ... the half-contrast edge does not, and it is the vehicle's own extent
    assert len(set(edged)) == 1
    assert edged[0] == (10, 12, 30, 22)
    assert edge_extent(np.zeros((5, 5)), np.zeros((5, 5), bool), level=0.5) is None


def _dark_vehicle(contrast: float, noise: float = 4.0):
    """A 160x120 frame of grey road with sensor noise and a dark 30x12 vehicle at (60, 50)
    whose windscreen is darker still; its model-resolution (0.5) image and clean background."""
    rng = np.random.default_rng(0)
    bg = np.full((120, 160, 3), 90, np.uint8)
    img = 90 + rng.normal(0, noise, bg.shape)
    img[50:62, 60:90] -= contrast
    img[54:58, 70:80] -= 40
    img = np.clip(img, 0, 255).astype(np.uint8)
    half = (80, 60)
    return (img, cv2.resize(img, half, interpolation=cv2.INTER_AREA),
            cv2.resize(bg, half, interpolation=cv2.INTER_AREA))


def test_seeds_out_of_the_noise_let_a_dark_vehicle_be_found_whole():
    import dataclasses

    from aerotrack.config import DetectionConfig
    from aerotrack.detection.moving import SizeGates, detect_moving

    gates = SizeGates(min_area_px=60, max_length_px=300, close_px=4, join_gap_px=5,
                      min_width_px=5)
    testable = np.full((60, 80), 255, np.uint8)
    img, small, bg = _dark_vehicle(contrast=18)
    low = dataclasses.replace(DetectionConfig(), threshold_sigma=5.0, seed_sigma=12.0)
    r = detect_moving(img, small, bg, testable, low, 0.5, gates)
    assert r.boxes.tolist() == [[60.0, 50.0, 30.0, 12.0]]
    # the body (about 6 noise sigmas) under a 7-sigma threshold: nothing vehicle-sized is left
    old = dataclasses.replace(DetectionConfig(), threshold_sigma=7.0, seed_sigma=0.0)
    assert len(detect_moving(img, small, bg, testable, old, 0.5, gates).boxes) == 0
    # noise alone seeds nothing
    img, small, bg = _dark_vehicle(contrast=0)
    img = np.clip(90 + np.random.default_rng(1).normal(0, 4.0, img.shape), 0, 255).astype(np.uint8)
    small = cv2.resize(img, (80, 60), interpolation=cv2.INTER_AREA)
    assert len(detect_moving(img, small, bg, testable, low, 0.5, gates).boxes) == 0


def rect_blob(x: int, y: int, w: int, h: int) -> Blob:
    return Blob((x, y, w, h), np.ones((h, w), bool), w * h)


def test_a_dark_vehicles_fragment_regrows_into_the_vehicle_and_a_leak_is_refused():
    # five 20x10 vehicles; a 4x4 fragment (a dark car's windscreen) inside a 20x10 faint body;
    # another fragment whose faint region runs on as a 60x30 sheet (a cast shadow, road texture)
    blobs = [rect_blob(10 + 30 * i, 10, 20, 10) for i in range(5)]
    frag, leak = rect_blob(18, 43, 4, 4), rect_blob(98, 53, 4, 4)
    faint = np.zeros((120, 170), bool)
    faint[40:50, 10:30] = True
    faint[50:80, 90:150] = True
    for b in blobs:  # the vehicles' own pixels are above the low threshold too
        x, y, w, h = b.box
        faint[y:y + h, x:x + w] = True
    out, grown = regrow_small(blobs + [frag, leak], faint, area_ratio=0.4, close_radius=1.0,
                              min_ratio=0.7)
    assert grown == [False] * 5 + [True, False]
    assert out[5].box == (10, 40, 20, 10) and out[5].area == 200
    assert out[6] is leak and out[:5] == blobs
    # the grown body never takes another blob's pixels: a vehicle parked in the faint body
    # (bumper to bumper) keeps its own, and the fragment grows only up to the ring around it
    other = rect_blob(26, 40, 4, 10)
    out, grown = regrow_small(blobs + [frag, other], faint, area_ratio=0.4, close_radius=0.0)
    x, y, w, h = out[5].box
    assert grown[5] and x + w <= 25
    # too few blobs for a typical size: nothing regrown
    assert regrow_small([frag, blobs[0]], faint, area_ratio=0.4, close_radius=1.0)[1] == [False, False]


def test_an_articulated_vehicles_cab_joins_its_trailer_and_queued_cars_stay_apart():
    # typical car 10 x 5 px; a 12 x 6 trailer with a 4 x 5 cab one pixel ahead, in line
    trailer, cab = rect_blob(20, 10, 12, 6), rect_blob(33, 10, 4, 6)
    joined = join_cabs([trailer, cab], gap=2, long_t=10, max_long=40, cab_ratio=0.9)
    assert len(joined) == 1 and joined[0].box == (20, 10, 17, 6)
    # two cars bumper to bumper: both about the typical length
    a, b = rect_blob(20, 30, 10, 5), rect_blob(31, 30, 10, 5)
    assert len(join_cabs([a, b], gap=2, long_t=10, max_long=40, cab_ratio=0.9)) == 2
    # a small blob beside a vehicle (next lane, a pedestrian) widens the union: apart
    side = rect_blob(24, 46, 4, 4)
    car = rect_blob(20, 40, 10, 5)
    assert len(join_cabs([car, side], gap=2, long_t=10, max_long=40, cab_ratio=0.9)) == 2
    # too far apart, or the union longer than a vehicle can be
    assert len(join_cabs([trailer, rect_blob(36, 10, 4, 6)], gap=2, long_t=10, max_long=40)) == 2
    assert len(join_cabs([trailer, cab], gap=2, long_t=10, max_long=15)) == 2


def test_two_vehicles_a_few_pixels_apart_are_separated_and_one_vehicle_is_not():
    from aerotrack.detection.blobs import Blob as DBlob
    from aerotrack.detection.moving import pieces_of, separate_pieces

    m = np.zeros((40, 60), np.uint8)
    m[5:15, 5:35] = 1  # two cars passing in opposite lanes, 3 px of road between their bodies
    m[18:28, 20:50] = 1
    m[17, 30] = 1  # a stray pixel between them goes to the nearer car
    pieces = separate_pieces(m, min_area=150, min_width=5)
    assert pieces is not None and len(pieces) == 2
    assert sorted(int(p.sum()) for p in pieces) == [300, 301]
    assert pieces[1][17, 30] == 1
    # a car with a hood cut off by its windshield: the hood is too small to be a vehicle
    one = np.zeros((40, 60), np.uint8)
    one[5:15, 5:30] = 1
    one[5:15, 32:38] = 1
    assert separate_pieces(one, min_area=150, min_width=5) is None
    # a thin line (a parallax edge) beside a car is not a second vehicle
    line = np.zeros((40, 60), np.uint8)
    line[5:15, 5:35] = 1
    line[20:22, 0:60] = 1
    assert separate_pieces(line, min_area=100, min_width=5) is None
    # each piece gets its part of the model-resolution blob (scale 0.5)
    small = cv2.resize(m, (30, 20), interpolation=cv2.INTER_AREA) > 0
    blob = DBlob((0, 0, 30, 20), small)
    out = pieces_of(m, pieces, blob, (0, 0, 30, 20), 0.5)
    assert len(out) == 2 and all(b.mask.any() for _, b in out)
    assert (out[0][1].mask & out[1][1].mask).sum() <= 2


def test_persistence_gets_no_evidence_from_a_detected_vehicles_shadow_only():
    from aerotrack.config import DetectionConfig
    from aerotrack.detection.moving import shadows_beside_detections_removed

    # model pixels (scale 0.5): a detected truck with its shadow beside it, and far away a small
    # undetected mover's shadow; the residual is high on all three
    bg = np.full((60, 100, 3), (80, 92, 100), np.uint8)
    small = bg.copy()
    small[10:16, 10:20] = (60, 150, 210)  # the truck
    small[10:16, 20:25] = (46, 41, 39)  # its shadow
    small[40:44, 80:84] = (46, 41, 39)  # a shadow far from any detection
    residual = np.zeros((60, 100), np.uint8)
    residual[10:16, 10:25] = 50
    residual[40:44, 80:84] = 50
    boxes = np.array([[20.0, 20.0, 20.0, 12.0]])  # the truck's regular box, full resolution
    out = shadows_beside_detections_removed(residual, small, bg, boxes, 0.5, DetectionConfig())
    assert out[10:16, 10:20].min() == 50  # the truck keeps its evidence
    assert out[10:16, 20:25].max() == 0  # its shadow gives none
    assert out[40:44, 80:84].min() == 50  # a shadow away from detections still counts
    assert out.dtype == residual.dtype


def test_piece_mask_keeps_a_vehicle_and_drops_strays_and_thin_lines():
    from aerotrack.detection.moving import SizeGates, piece_mask

    gates = SizeGates(min_area_px=60, max_length_px=80, close_px=1.0, join_gap_px=2.0,
                      min_width_px=5.0)
    piece = np.zeros((40, 60), np.uint8)
    piece[10:22, 10:34] = 1  # a 24 x 12 vehicle
    piece[30, 50] = 1  # a stray pixel
    region = np.ones(piece.shape, bool)
    mask, box, area = piece_mask(piece, region, 1.0, gates)
    assert box == (10, 10, 34, 22) and area == 24 * 12 and not mask[30, 50]
    # outside the blob's region nothing counts
    assert piece_mask(piece, np.zeros(piece.shape, bool), 1.0, gates) is None
    line = np.zeros((40, 60), np.uint8)
    line[20:22, 2:58] = 1  # 56 x 2: a parallax edge, not a vehicle
    assert piece_mask(line, region, 1.0, gates) is None
    long = np.zeros((40, 120), np.uint8)
    long[10:22, 5:100] = 1  # longer than max_length_px
    assert piece_mask(long, np.ones(long.shape, bool), 1.0, gates) is None


def test_same_structure_tells_a_sharpened_wall_line_from_a_car_over_a_lane_line():
    """A thin bright line next to a dark strip (a wall and its shadow) rendered sharper in the
    frame than in the warped background leaves residual along the line, but the frame's pixels
    there correlate with the background's; a car crossing a lane line covers it and does not."""
    from aerotrack.detection.moving import same_structure

    bg = np.full((30, 40, 3), 90, np.uint8)
    bg[12:15, 5:35] = 200  # the wall's top, blurred by the warps
    bg[15:19, 5:35] = 30  # its shadow
    bg = cv2.GaussianBlur(bg, (0, 0), 1.0)
    frame = np.full((30, 40, 3), 90, np.uint8)
    frame[12:15, 5:35] = 230
    frame[15:19, 5:35] = 20
    frame = cv2.GaussianBlur(frame, (0, 0), 0.4)
    resid = np.abs(frame.astype(int) - bg.astype(int)).max(axis=2)
    line = resid > 12
    assert line.sum() > 30
    assert same_structure(frame, bg, line) > 0.8
    # a car over a lane line: the same background, something new on top
    car = bg.copy()
    car[8:22, 12:22] = (40, 40, 160)
    mask = np.zeros((30, 40), bool)
    mask[8:22, 12:22] = True
    assert same_structure(car, bg, mask) < 0.5
    # a car on plain road: nothing to correlate with
    assert same_structure(car, np.full_like(bg, 90), mask) == 0.0


def test_blob_rules_judge_each_blob_at_its_own_scale_when_told():
    """On an oblique view far vehicles are small and near ones large: with the frame's median as
    the one vehicle size, far ones were dropped as fragments. Given the area a vehicle has at
    each place (``norm``, from a map's or a ground plane's homography) they are kept, and a
    fragment beside a near vehicle still goes."""
    from aerotrack.detection.blobs import drop_small

    def blob(y, side):
        return Blob((10, y, side, side), np.ones((side, side), bool))

    far = [blob(5, 4), blob(8, 4), blob(12, 4)]  # 16 px, where a vehicle is 16 px
    near = [blob(200 + 5 * i, 12) for i in range(5)] + [blob(230, 3)]  # 144 px, and a fragment

    def norm(b):  # a vehicle's area grows 9x from row 0 to row 240
        return (1 + 2 * (b.box[1] + b.box[3] / 2) / 240) ** 2

    def has(blobs, b):
        return any(b is k for k in blobs)

    blobs = far + near
    plain = drop_small(blobs, area_ratio=0.4)
    assert not any(has(plain, b) for b in far)
    kept = drop_small(blobs, area_ratio=0.4, norm=norm)
    assert all(has(kept, b) for b in far + near[:5]) and not has(kept, near[5])


def test_separated_pieces_must_be_vehicle_shaped_and_not_a_vehicle_with_its_shadow():
    from aerotrack.detection.moving import cast_shadow_pieces, separate_pieces

    # two queued cars (30 x 10 px) 3 px apart: each piece is as long and wide as the typical car
    m = np.zeros((20, 70), np.uint8)
    m[5:15, 2:32] = 1
    m[5:15, 35:65] = 1
    assert len(separate_pieces(m, min_area=100, min_width=5, min_sides=(18, 6))) == 2
    # a car (30 x 10) with a strip 30 x 6 beside it: long enough but too narrow to be a vehicle
    # with min_sides at 0.7 of the typical car's (21 x 7); without the shape test it is split
    s = np.zeros((30, 40), np.uint8)
    s[2:12, 5:35] = 1
    s[14:20, 5:35] = 1
    assert separate_pieces(s, min_area=100, min_width=5) is not None
    assert separate_pieces(s, min_area=100, min_width=5, min_sides=(21, 7)) is None
    # a light car beside its (darker than the road, no larger) shadow: not two vehicles
    bg = np.full((30, 40, 3), 90, np.uint8)
    frame = bg.copy()
    frame[2:12, 5:35] = 230  # the white car
    frame[14:20, 5:35] = 50  # its shadow
    car, shadow = np.zeros((30, 40), np.uint8), np.zeros((30, 40), np.uint8)
    car[2:12, 5:35] = 1
    shadow[14:20, 5:35] = 1
    assert cast_shadow_pieces([car, shadow], frame, bg)
    # a larger dark car beside a light one: two vehicles
    big_dark = np.zeros((30, 40), np.uint8)
    big_dark[13:27, 3:37] = 1
    frame2 = bg.copy()
    frame2[2:12, 5:35] = 230
    frame2[13:27, 3:37] = 40
    assert not cast_shadow_pieces([car, big_dark], frame2, bg)
    # two light cars: two vehicles
    frame3 = bg.copy()
    frame3[2:12, 5:35] = 230
    frame3[14:20, 5:35] = 200
    assert not cast_shadow_pieces([car, shadow], frame3, bg)
