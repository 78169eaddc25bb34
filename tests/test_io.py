import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aerotrack.errors import FormatError, InputError, OutputError
from aerotrack.io import OutputDir, open_source, read_mot, write_mot
from aerotrack.io.mot import parse_mot_text


def test_mot_round_trip(tmp_path):
    rows = np.array([[1, 3, 10.5, 20.25, 30, 40, 0.9, -1, -1, -1],
                     [2, 3, 11.5, 21.25, 30, 40, 0.8, 1.2345678, 2.5, -1]])
    write_mot(tmp_path / "t.txt", rows)
    back = read_mot(tmp_path / "t.txt")
    np.testing.assert_allclose(back, rows, atol=1e-3)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 5000), st.integers(1, 999),
                          st.floats(-1e4, 1e4), st.floats(-1e4, 1e4),
                          st.floats(0.01, 1e3), st.floats(0.01, 1e3), st.floats(0, 1)),
                min_size=1, max_size=30, unique_by=lambda r: (r[0], r[1])))
def test_mot_round_trip_property(tmp_path_factory, rows):
    p = tmp_path_factory.mktemp("m") / "x.txt"
    arr = np.array([list(r) + [-1, -1, -1] for r in rows], dtype=float)
    write_mot(p, arr)
    back = read_mot(p)
    order = np.lexsort((arr[:, 1], arr[:, 0]))
    np.testing.assert_allclose(back, arr[order], atol=1e-3)


@pytest.mark.parametrize("text,msg", [
    ("1,2,3\n", "line 1: expected 6 to 10 columns"),
    ("1,1,1,1,1,1,1\n1,1,a,1,1,1,1\n", "line 2: non-numeric"),
    ("1,1,nan,1,1,1,1\n", "line 1: NaN"),
    ("0,1,1,1,1,1,1\n", "line 1: frame must be a positive integer"),
    ("1.5,1,1,1,1,1,1\n", "line 1: frame must be a positive integer"),
])
def test_malformed_rows_name_the_line(text, msg):
    with pytest.raises(FormatError, match=msg):
        parse_mot_text(text, "f.txt")


def test_a_header_row_is_skipped_only_first():
    arr = parse_mot_text("frame,id,bb_left,bb_top,bb_width,bb_height,conf\n2,-1,1,1,4,4,0.5\n")
    assert arr.shape == (1, 10) and arr[0, 0] == 2 and arr[0, 6] == 0.5
    with pytest.raises(FormatError, match="line 2: non-numeric"):
        parse_mot_text("2,-1,1,1,4,4,0.5\nframe,id,x,y,w,h,conf\n")


def test_strict_refuses_negative_and_duplicates(tmp_path):
    p = tmp_path / "neg.txt"
    p.write_text("1,1,1,1,-5,3,1\n")
    with pytest.raises(FormatError, match="negative"):
        read_mot(p, option="--pred")
    assert len(read_mot(p, strict=False)) == 1
    d = tmp_path / "dup.txt"
    d.write_text("1,1,1,1,5,3,1\n1,1,1,1,5,3,1\n")
    with pytest.raises(FormatError, match="repeated"):
        read_mot(d, option="--pred")


def test_image_folder_source_streams_sorted(tmp_path):
    for i in (3, 1, 2):
        cv2.imwrite(str(tmp_path / f"{i:03d}.png"), np.full((8, 10, 3), i * 10, np.uint8))
    (tmp_path / "notes.txt").write_text("not an image")
    src = open_source(tmp_path, fps=10)
    frames = list(src)
    assert [f.index for f in frames] == [1, 2, 3]
    assert [int(f.image[0, 0, 0]) for f in frames] == [10, 20, 30]
    assert frames[2].time == pytest.approx(0.2)
    assert src.size == (10, 8)


@pytest.mark.parametrize("suffix", [".tif", ".png"])
def test_sixteen_bit_frames_keep_their_contrast_under_one_map(tmp_path, suffix):
    """A radiometric thermal camera writes 16-bit frames over a narrow band of its 14-bit range:
    read as 8 bits by their top byte they are blank (a 1000-count scene in 4 grey levels). They
    are stretched by one map for the folder, so a hot vehicle stands out by most of the range
    and the road keeps its grey level in every frame, whatever else enters the view."""
    road = 7200
    for i in range(5):
        img = np.full((40, 60), road, np.uint16)
        img[10:18, 5 + 8 * i:25 + 8 * i] = 8100  # a warm engine, moving right
        if i == 3:
            img[30:36, 40:50] = 9000  # something hotter enters once
        cv2.imwrite(str(tmp_path / f"{i:03d}{suffix}"), img)
    assert (cv2.imread(str(tmp_path / f"000{suffix}"), cv2.IMREAD_COLOR).std() < 2)  # the old way
    src = open_source(tmp_path)
    lo, hi = src.depth_range
    assert lo == pytest.approx(road) and hi >= 8100
    frames = [f.image for f in src]
    assert all(f.dtype == np.uint8 and f.shape == (40, 60, 3) for f in frames)
    assert {int(f[38, 2, 0]) for f in frames} == {0}  # the road: one value in every frame
    assert all(int(f[14, 20 + 8 * i, 1]) - int(f[38, 2, 1]) > 100 for i, f in enumerate(frames))
    assert int(frames[3][33, 45, 2]) == 255


def test_sixteen_bit_frames_with_alpha_a_corrupt_file_and_a_jump_keep_their_map(tmp_path):
    """An opaque alpha channel (65535) set the top of the map, and every frame read blank; a
    corrupt file among the sampled ones stopped the run; one frame brighter by a flat-field
    correction's jump moved the map of all the others."""
    rng = np.random.default_rng(0)
    for i in range(9):
        grey = rng.integers(7000, 8000, (40, 60)).astype(np.uint16)
        if i == 2:
            grey = grey - 600  # the camera's correction jump: one frame darker by 600 counts
        img = np.dstack([grey, grey, grey, np.full((40, 60), 65535, np.uint16)])
        cv2.imwrite(str(tmp_path / f"{i:03d}.png"), img)
    (tmp_path / "004.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)  # corrupt, sampled
    src = open_source(tmp_path)
    lo, hi = src.depth_range
    assert 6990 <= lo <= 7010 and 7990 <= hi <= 8010
    frames = [f for f in src]
    assert len(frames) == 8 and all(f.image.std() > 50 for f in frames if f.index != 3)


def test_float_frames_are_mapped_and_nan_is_not_an_error(tmp_path):
    img = np.linspace(20.0, 35.0, 40 * 60, dtype=np.float32).reshape(40, 60)  # degrees Celsius
    img[0, 0] = np.nan
    cv2.imwrite(str(tmp_path / "a.tif"), img)
    f = next(iter(open_source(tmp_path)))
    assert f.image.dtype == np.uint8 and f.image[-1, -1, 0] > 250 and f.image[0, 1, 0] < 3


def test_eight_bit_grey_frames_read_as_before(tmp_path):
    cv2.imwrite(str(tmp_path / "a.png"), np.full((8, 10), 77, np.uint8))
    src = open_source(tmp_path)
    assert src.depth_range is None
    assert next(iter(src)).image.shape == (8, 10, 3) and int(next(iter(src)).image[0, 0, 2]) == 77


def test_image_folder_mixed_sizes_named(tmp_path):
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((8, 10, 3), np.uint8))
    cv2.imwrite(str(tmp_path / "b.png"), np.zeros((9, 10, 3), np.uint8))
    with pytest.raises(InputError, match="b.png"):
        list(open_source(tmp_path))


def test_video_source(tmp_path):
    p = tmp_path / "v.avi"
    vw = cv2.VideoWriter(str(p), cv2.VideoWriter_fourcc(*"MJPG"), 12, (32, 24))
    for i in range(5):
        vw.write(np.full((24, 32, 3), i * 40, np.uint8))
    vw.release()
    src = open_source(p)
    assert src.fps == pytest.approx(12)
    frames = list(src.frames(start=2, stride=2))
    assert [f.index for f in frames] == [2, 4]


def _write_video(path, fourcc, n=45, size=(160, 96)):
    """A video whose every frame differs: a drifting texture and a moving square."""
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.integers(0, 255, (120, 200, 3), dtype=np.uint8), (0, 0), 3)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 15, size)
    if not writer.isOpened():
        pytest.skip(f"no {fourcc} encoder in this OpenCV build")
    w, h = size
    for k in range(n):
        img = base[k % 20:k % 20 + h, k % 37:k % 37 + w].copy()
        cv2.rectangle(img, (2 * k, 40), (2 * k + 12, 52), (255, 255, 255), -1)
        writer.write(img)
    writer.release()


def _decoded(path, stop):
    """Frames 1..stop decoded one after the other with OpenCV alone (no seeking)."""
    cap = cv2.VideoCapture(str(path))
    out = []
    while len(out) < stop:
        ok, img = cap.read()
        if not ok:
            break
        out.append(img)
    cap.release()
    return out


@pytest.mark.parametrize("fourcc,suffix", [("mp4v", ".mp4"), ("MJPG", ".avi")])
@pytest.mark.parametrize("start,stop,stride", [(1, 12, 1), (17, 33, 2), (38, 60, 1), (44, 45, 3)])
def test_video_frames_seek_to_the_frames_sequential_decoding_gives(tmp_path, fourcc, suffix,
                                                                   start, stop, stride):
    """Reading from frame ``start`` seeks there; it must give the very frames (index, time,
    pixels) that decoding from the first frame gives, and stop at the video's end."""
    path = tmp_path / f"clip{suffix}"
    _write_video(path, fourcc)
    src = open_source(path, None)
    decoded = _decoded(path, stop)
    want = list(range(start, min(stop, len(decoded)) + 1, stride))
    got = list(src.frames(start=start, stop=stop, stride=stride))
    assert [f.index for f in got] == want and want
    assert [f.time for f in got] == [(i - 1) / src.fps for i in want]
    assert all(np.array_equal(f.image, decoded[f.index - 1]) for f in got)


def test_video_frames_decode_from_the_first_when_the_backend_cannot_seek(tmp_path, monkeypatch):
    """A backend that refuses to seek still gives the right frames (decoded from frame 1)."""
    path = tmp_path / "clip.avi"
    _write_video(path, "MJPG", n=12)
    src = open_source(path, None)
    monkeypatch.setattr(type(src), "_seek", lambda self, cap, start: -1)
    decoded = _decoded(path, 12)
    got = list(src.frames(start=5, stop=9, stride=2))
    assert [f.index for f in got] == [5, 7, 9]
    assert all(np.array_equal(f.image, decoded[f.index - 1]) for f in got)


def test_image_folder_frames_open_only_the_range(tmp_path, monkeypatch):
    """A range of an image folder reads the files of that range alone (a broken file outside it
    is never opened), in name order, with the frame numbers of the whole folder."""
    for i in range(1, 10):
        cv2.imwrite(str(tmp_path / f"{i:03d}.png"), np.full((8, 10, 3), i * 10, np.uint8))
    src = open_source(tmp_path, fps=10)
    (tmp_path / "002.png").write_bytes(b"broken")  # after open_source read the first file
    frames = list(src.frames(start=4, stop=8, stride=2))
    assert [f.index for f in frames] == [4, 6, 8]
    assert [int(f.image[0, 0, 0]) for f in frames] == [40, 60, 80]
    assert frames[0].time == pytest.approx(0.3)
    assert [f.index for f in src.frames(start=8, stop=20)] == [8, 9]
    # a broken file inside the range is skipped (a warning names it), not the end of the run
    assert [f.index for f in src.frames(start=1, stop=3)] == [1, 3]


def test_image_folder_order_hidden_files_duplicates_and_alpha(tmp_path):
    """Found by a probe: img1..img100 were read img1, img10, img100, img11, ...; macOS's
    ._DJI_0001.JPG made a folder unusable; 0001.jpg beside 0001.png read every frame twice;
    transparent pixels of RGBA images were tracked as image."""
    nat = tmp_path / "nat"
    nat.mkdir()
    for i in (1, 2, 10, 11, 100):
        cv2.imwrite(str(nat / f"img{i}.png"), np.full((8, 10, 3), i, np.uint8))
    (nat / "._img1.png").write_bytes(b"\x00\x05\x16\x07 AppleDouble")
    src = open_source(nat)
    assert [int(f.image[0, 0, 0]) for f in src.frames()] == [1, 2, 10, 11, 100]
    dup = tmp_path / "dup"
    dup.mkdir()
    for ext in ("jpg", "png"):
        cv2.imwrite(str(dup / f"0001.{ext}"), np.zeros((8, 10, 3), np.uint8))
    with pytest.raises(InputError, match="both 0001.jpg and 0001.png"):
        open_source(dup)
    rgba = tmp_path / "rgba"
    rgba.mkdir()
    img = np.full((8, 10, 4), 200, np.uint8)
    img[:, :3, 3] = 0  # a transparent strip
    cv2.imwrite(str(rgba / "0001.png"), img)
    frame = next(iter(open_source(rgba).frames()))
    assert frame.image.shape == (8, 10, 3)
    assert frame.image[:, :3].max() == 0 and frame.image[:, 3:].min() == 200


@pytest.mark.parametrize("content", [b"", b"this is not a video at all" * 10])
def test_bad_video_is_input_error(tmp_path, content):
    p = tmp_path / "bad.mp4"
    p.write_bytes(content)
    with pytest.raises(InputError, match="bad.mp4"):
        open_source(p)


def test_output_dir_rules(tmp_path):
    d = tmp_path / "out"
    od = OutputDir(d)
    od.write_text("tracks.csv", "x")
    with pytest.raises(OutputError, match="already holds results"):
        OutputDir(d)
    again = OutputDir(d, overwrite=True)
    assert (d / "tracks.csv").exists()  # kept until the new results are all written
    again.finish()
    assert not (d / "tracks.csv").exists()


# -- world sizes under a rotating registration --------------------------------------------------
def _rotation(deg: float, scale: float, tx: float = 40.0, ty: float = -25.0) -> np.ndarray:
    a = np.deg2rad(deg)
    return np.array([[scale * np.cos(a), -scale * np.sin(a), tx],
                     [scale * np.sin(a), scale * np.cos(a), ty], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("deg", [0.0, 30.0, 45.0, 90.0])
def test_external_detections_world_size_is_the_box_times_the_scale_at_any_rotation(deg):
    """--detections: a box's world size is its sides times the registration's local scale, as
    the built-in detector's; the corner offset through a rotation lost a side (at 45 degrees
    a 16 x 8 box had a width near 0 and the finish stage dropped the vehicle as too small)."""
    from aerotrack.config import Config
    from aerotrack.pipeline import Pipeline
    from aerotrack.types import Frame, Registration

    rows = np.array([[5, -1, 100.0, 60.0, 16.0, 8.0, 0.9, -1, -1, -1]])
    pipe = Pipeline(Config(), 30.0, detections={5: rows}, associate=False)
    reg = Registration(5, _rotation(deg, 1.5))
    d = pipe._external_detections(Frame(5, None, 4 / 30.0), reg)
    assert np.allclose(d.size_world, [[24.0, 12.0]])


@pytest.mark.parametrize("deg", [0.0, 45.0, 120.0])
def test_segment_sizes_carried_into_world_0_keep_their_sides(deg):
    from aerotrack.parallel import _size_to

    A = _rotation(deg, 0.5)
    world = np.array([[10.0, 20.0], [300.0, -40.0]])
    sizes = np.array([[16.0, 8.0], [10.0, 10.0]])
    assert np.allclose(_size_to(A, world, sizes), sizes * 0.5)


def test_a_box_rebuilt_from_a_world_size_is_the_detected_box_at_any_rotation():
    from aerotrack.outputs import _box_from_world
    from aerotrack.types import Registration, TrackPoint, apply_homography

    H = _rotation(45.0, 2.0)
    centre = np.array([120.0, 80.0])
    p = TrackPoint(3, None, apply_homography(H, centre[None])[0], 0.0,
                   size_world=np.array([32.0, 16.0]))
    box = _box_from_world(p, Registration(3, H), None)
    assert np.allclose(box, [120 - 8, 80 - 4, 16, 8])


def test_read_ahead_yields_the_sources_frames_in_order(tmp_path):
    from aerotrack.io.frames import read_ahead

    for i in range(7):
        cv2.imwrite(str(tmp_path / f"{i:03d}.png"), np.full((6, 8, 3), 30 * i, np.uint8))
    src = open_source(tmp_path, 10)
    direct = [(f.index, f.time, f.image.copy()) for f in src.frames(start=2, stop=6, stride=2)]
    ahead = [(f.index, f.time, f.image) for f in read_ahead(src.frames(start=2, stop=6, stride=2))]
    assert [a[:2] for a in ahead] == [d[:2] for d in direct] == [(2, 0.1), (4, 0.3), (6, 0.5)]
    assert all(np.array_equal(a[2], d[2]) for a, d in zip(ahead, direct))


def test_read_ahead_raises_the_sources_error_in_place_and_stops_with_the_consumer():
    import threading
    import time

    from aerotrack.io.frames import read_ahead

    def failing():
        yield 1
        yield 2
        raise InputError("frame 3: corrupt")

    got = []
    with pytest.raises(InputError, match="frame 3"):
        for x in read_ahead(failing()):
            got.append(x)  # noqa: PERF402 - what arrived before the error
    assert got == [1, 2]

    closed = threading.Event()

    def endless():
        try:
            n = 0
            while True:
                n += 1
                yield n
        finally:
            closed.set()

    for x in read_ahead(endless(), depth=2):
        if x == 3:
            break
    t0 = time.monotonic()
    while not closed.is_set() and time.monotonic() - t0 < 5:
        time.sleep(0.01)
    assert closed.is_set()  # the source was closed: a video's capture is released
    assert not any(t.name == "aerotrack-read-ahead" for t in threading.enumerate())


def test_image_names_equal_as_numbers_are_refused(tmp_path):
    for name in ("img3.png", "img03.png"):
        cv2.imwrite(str(tmp_path / name), np.zeros((8, 10, 3), np.uint8))
    with pytest.raises(InputError, match="both img03.png and img3.png|both img3.png and img03.png"):
        open_source(tmp_path)


def test_a_variable_frame_rate_video_is_recognised(tmp_path):
    """Frames of a variable-frame-rate video are numbered in decoding order and timed at the
    mean rate: speeds were off (x1.43 and x0.73 on a 15-then-30 fps clip) without a word."""
    import subprocess

    from aerotrack.viz.video import ffmpeg_exe

    frames = b"".join(np.full((48, 64, 3), (i * 7) % 255, np.uint8).tobytes() for i in range(80))
    out = tmp_path / "vfr.mp4"
    head = [ffmpeg_exe(), "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "bgr24",
            "-s", "64x48", "-r", "30", "-i", "-"]
    tail = ["-c:v", "libx264", "-pix_fmt", "yuv420p"]
    vfr = ["-vf", "select='gte(n\\,40)+not(mod(n\\,2))'", "-fps_mode", "passthrough"]
    subprocess.run([*head, *vfr, *tail, str(out)], input=frames, check=True)
    spread = open_source(out).timing_irregularity()
    assert spread is not None and spread[1] > 1.8 * spread[0], spread
    cfr = tmp_path / "cfr.mp4"
    subprocess.run([*head, *tail, str(cfr)], input=frames, check=True)
    assert open_source(cfr).timing_irregularity() is None


def test_a_header_naming_the_columns_in_another_order_is_refused(tmp_path):
    """Trajectory files often start id,frame,...: the header was skipped and the rows read in MOT
    order (ids as frames), and the error then was about a missing row."""
    p = tmp_path / "t.csv"
    p.write_text("id,frame,x,y,w,h,conf,wx,wy,z\n1,40,0,0,4,2,1,-1,-1,-1\n")
    with pytest.raises(FormatError, match=r"'frame' in column 2 and 'id' in column 1"):
        read_mot(p)
    p.write_text("frame,id,bb_left,bb_top,bb_width,bb_height,conf,x,y,z\n40,1,0,0,4,2,1,-1,-1,-1\n")
    assert read_mot(p)[0, :2].tolist() == [40, 1]
    p.write_text("frame id x y w h\n40 1 0 0 4 2\n")
    assert read_mot(p)[0, :2].tolist() == [40, 1]


def test_a_gap_in_numbered_frame_files_is_named(tmp_path, caplog):
    """A folder without 000050.png was tracked with every later frame numbered one lower than
    its name and no word (HOTA 0.780 -> 0.730 against the names' ground truth); a folder of
    every 5th frame (one spacing) is a numbering, not a gap."""
    import logging

    img = np.zeros((16, 16, 3), np.uint8)
    gap, fifth = tmp_path / "gap", tmp_path / "fifth"
    gap.mkdir()
    fifth.mkdir()
    for i in [*range(45, 50), *range(51, 56)]:
        cv2.imwrite(str(gap / f"{i:06d}.png"), img)
    for i in range(0, 50, 5):
        cv2.imwrite(str(fifth / f"{i:06d}.png"), img)
    with caplog.at_level(logging.WARNING, logger="aerotrack"):
        open_source(fifth)
        assert "skip" not in caplog.text
        assert open_source(gap).count == 10
    assert "file numbers skip 1 time (between 49-51; about 1 file missing)" in caplog.text
    # one file without a number beside them turned the check off (a probe)
    cv2.imwrite(str(gap / "zfinal.png"), img)
    from aerotrack.io import frames

    frames._GAPS_WARNED.clear()
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="aerotrack"):
        open_source(gap)
    assert "file numbers skip 1 time" in caplog.text


def test_a_motchallenge_sequence_folder_is_read_from_its_image_folder(tmp_path, capsys):
    """``SEQ/seqinfo.ini`` + ``SEQ/img1/``: frames come from imDir at frameRate (the folder itself
    holds no image and was refused); ``--fps`` still wins; batch takes the sequence as an input
    at its own rate; a broken seqinfo.ini is a one-line error naming it."""
    import cv2
    import numpy as np
    from conftest import run_cli

    from aerotrack.io.frames import open_source
    from aerotrack.parallel import item_fps, plan_batch

    seq = tmp_path / "seqs" / "MOT-01"
    (seq / "img1").mkdir(parents=True)
    for i in range(3):
        cv2.imwrite(str(seq / "img1" / f"{i + 1:06d}.jpg"), np.full((24, 32, 3), 40 * i, np.uint8))
    (seq / "seqinfo.ini").write_text("[Sequence]\nname=MOT-01\nimDir=img1\nframeRate=25\n"
                                     "seqLength=3\nimWidth=32\nimHeight=24\nimExt=.jpg\n")
    src = open_source(seq)
    assert src.fps == 25.0 and src.count == 3
    assert [f.image[0, 0, 0] for f in src.frames()] == [0, 40, 80]
    assert open_source(seq, 10.0).fps == 10.0
    assert [i.name for i in plan_batch(tmp_path / "seqs", tmp_path / "out")] == ["MOT-01"]
    assert item_fps(seq, 10.0) is None  # its own rate, as a video's
    # shared images linked in, a BOM, a lower-case section: read all the same
    linked = tmp_path / "seqs" / "MOT-02"
    linked.mkdir()
    (linked / "img1").symlink_to(seq / "img1")
    (linked / "seqinfo.ini").write_bytes(b"\xef\xbb\xbf[sequence]\nimDir=img1/\nframeRate=12\n")
    src = open_source(linked)
    assert (src.fps, src.count) == (12.0, 3)
    (linked / "seqinfo.ini").write_text("[Sequence]\nimDir=../MOT-01/img1\n")
    with pytest.raises(InputError, match="not a folder inside"):
        open_source(linked)
    # a missing image: frames keep the files' numbers (as the sequence's gt.txt and det.txt do)
    gap = tmp_path / "seqs2" / "GAP"
    (gap / "img1").mkdir(parents=True)
    for i in (1, 2, 4):
        cv2.imwrite(str(gap / "img1" / f"{i:06d}.jpg"), np.full((24, 32, 3), 40 * i, np.uint8))
    (gap / "seqinfo.ini").write_text("[Sequence]\nimDir=img1\nframeRate=25\n")
    src = open_source(gap)
    got = [(f.index, int(f.image[0, 0, 0])) for f in src.frames()]
    assert src.count == 4 and [i for i, _ in got] == [1, 2, 4] and src.skipped_frames == {3}
    assert abs(got[2][1] - 160) <= 2  # frame 4 is 000004.jpg (JPEG rounding aside)
    (seq / "seqinfo.ini").write_text("[Sequence]\nimDir=img1\nframeRate=fast\n")
    code, _, err = run_cli(capsys, "track", seq, "--out", tmp_path / "run")
    assert code == 2 and "seqinfo.ini: frameRate 'fast' is not a positive number" in err
    assert "Traceback" not in err and not (tmp_path / "run").exists()


def test_overwrite_keeps_the_earlier_results_until_the_new_ones_are_all_written(tmp_path):
    """``--overwrite`` deleted the earlier run's results before the new run started, so a run that
    failed or was stopped left nothing; and a run that failed while writing its results (a full
    disk) left some of them. Now results are staged and moved in together by ``finish``; a
    resumed overwrite still replaces every earlier entry (a stale observations.csv went)."""
    out = tmp_path / "run"
    first = OutputDir(out)
    first.write_text("tracks.csv", "old\n")
    first.write_text("observations.csv", "old\n")
    first.finish(keep_as="stages")
    assert sorted(e.name for e in out.iterdir()) == ["observations.csv", "stages", "tracks.csv"]
    again = OutputDir(out, overwrite=True)
    again.write_text("tracks.csv", "new\n")  # ... and then the run fails: no finish
    assert (out / "tracks.csv").read_text() == "old\n"
    assert (out / "observations.csv").read_text() == "old\n"
    resumed = OutputDir(out, resume=True)  # the interrupted --overwrite run, continued
    assert not resumed.staged.exists()  # the failed write's staged files are not kept
    resumed.write_text("tracks.csv", "new\n")
    resumed.finish(keep_as="stages")
    assert (out / "tracks.csv").read_text() == "new\n"
    assert sorted(e.name for e in out.iterdir()) == ["stages", "tracks.csv"]
    assert not (out / "stages" / "replaced.txt").exists()


def test_atomic_writes_keep_links_and_refuse_devices(tmp_path):
    """An output that is a link was replaced by a plain file (the link gone, its target
    unchanged); one that is a device or a pipe was replaced too (as root, /dev/full became a
    file). Now a link's target is written and a device or pipe is refused."""
    import os

    from aerotrack.io.output import atomic_write_text

    target = tmp_path / "real.csv"
    target.write_text("old\n")
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    atomic_write_text(link, "new\n")
    assert link.is_symlink() and target.read_text() == "new\n"
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(OutputError, match="not a regular file"):
        atomic_write_text(fifo, "x\n")
    assert not fifo.is_file()


def test_output_dir_records_its_writer_while_it_works(tmp_path):
    """.partial/owner names the process writing the folder (so a second run is refused while it
    runs); it is not kept in stages/ once the results are in place."""
    import os

    out = OutputDir(tmp_path / "o", stage=True)
    assert str(os.getpid()) in (out.partial / "owner").read_text().split()
    out.finish(keep_as="stages")
    assert (tmp_path / "o" / "stages").is_dir()
    assert not (tmp_path / "o" / "stages" / "owner").exists()
