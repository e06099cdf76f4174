"""Photo spheres stored cropped: the GPano metadata read from the file, the photo placed in
its whole panorama, only its own lines drawn, and cropped photos of several sizes localized
end to end."""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest

from placeloc.core.images import ImageError, PanoramaCrop, panorama_crop
from placeloc.geometry.panorama import Coverage, draw_line_image, panorama_lines, whole_panorama
from placeloc.umap.query_features import panorama_arrays
from tests.test_umap_panorama import PLAN, _grey_panorama, _render


def gpano_xmp(crop: PanoramaCrop, *, elements: bool = False, projection: str = "equirectangular") -> bytes:
    """The XMP packet a phone writes beside a photo sphere (attributes, or elements)."""
    values = {"ProjectionType": projection, "FullPanoWidthPixels": crop.full_width,
              "FullPanoHeightPixels": crop.full_height, "CroppedAreaLeftPixels": crop.left,
              "CroppedAreaTopPixels": crop.top, "CroppedAreaImageWidthPixels": crop.width,
              "CroppedAreaImageHeightPixels": crop.height}
    if elements:
        body = "".join(f"<GPano:{k}>{v}</GPano:{k}>" for k, v in values.items())
        desc = f'<rdf:Description rdf:about="">{body}</rdf:Description>'
    else:
        attrs = " ".join(f'GPano:{k}="{v}"' for k, v in values.items())
        desc = f'<rdf:Description rdf:about="" {attrs}/>'
    return ('<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#" '
            f'xmlns:GPano="http://ns.google.com/photos/1.0/panorama/">{desc}</rdf:RDF></x:xmpmeta>').encode()


def write_photo_sphere(path, gray: np.ndarray, xmp: bytes | None) -> None:
    """A JPEG with the XMP packet in an APP1 segment right after its start marker, as cameras
    store it."""
    data = cv2.imencode(".jpg", gray, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    if xmp is not None:
        payload = b"http://ns.adobe.com/xap/1.0/\x00" + xmp
        data = data[:2] + b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload + data[2:]
    path.write_bytes(data)


def test_the_crop_is_read_from_attributes_or_elements(tmp_path):
    crop = PanoramaCrop(8000, 4000, 100, 700, 7900, 2300)
    gray = np.full((23, 79), 128, np.uint8)
    for elements in (False, True):
        write_photo_sphere(tmp_path / "a.jpg", gray, gpano_xmp(crop, elements=elements))
        assert panorama_crop(tmp_path / "a.jpg") == crop
    write_photo_sphere(tmp_path / "plain.jpg", gray, None)
    assert panorama_crop(tmp_path / "plain.jpg") is None
    write_photo_sphere(tmp_path / "cyl.jpg", gray, gpano_xmp(crop, projection="cylindrical"))
    with pytest.raises(ImageError, match="cyl.jpg.*ProjectionType 'cylindrical'"):
        panorama_crop(tmp_path / "cyl.jpg")
    for bad in ("inf", "nan", "wide"):
        write_photo_sphere(tmp_path / "bad.jpg", gray, gpano_xmp(crop).replace(b'"8000"', f'"{bad}"'.encode()))
        with pytest.raises(ImageError, match="bad.jpg.*not a number"):
            panorama_crop(tmp_path / "bad.jpg")
    write_photo_sphere(tmp_path / "off.jpg", gray, gpano_xmp(PanoramaCrop(8000, 4000, 0, 3000, 8000, 2000)))
    with pytest.raises(ImageError, match="off.jpg.*does not fit"):
        panorama_crop(tmp_path / "off.jpg")


def test_whole_panorama_by_hand():
    # a 4 x 6 photo from columns 10..15 (wrapping past 11) and rows 1..4 of a 12 x 6 panorama,
    # stored at half size (2 x 3): placed at the photo's scale, the rest its mean grey
    photo = np.array([[10, 20, 30], [40, 50, 60]], np.uint8)
    canvas, cov = whole_panorama(photo, PanoramaCrop(12, 6, 10, 2, 6, 4))
    assert canvas.shape == (3, 6)
    assert cov == Coverage(10 / 12, 2 / 6, 6 / 12, 4 / 6)
    mean = 35
    assert canvas.tolist() == [[mean] * 6, [20, 30, mean, mean, mean, 10], [50, 60, mean, mean, mean, 40]]
    with pytest.raises(ImageError, match="resized unevenly"):
        whole_panorama(np.zeros((5, 3), np.uint8), PanoramaCrop(12, 6, 0, 0, 6, 4))


def test_metadata_asking_for_a_huge_canvas_is_refused(monkeypatch):
    # a 100 x 50 photo said to be a 20 x 10 crop of a 20,000 x 10,000 panorama (a damaged or
    # hostile file) would need a canvas of 100,000 x 50,000 pixels (5 GB): refused with the
    # file named, as a decode larger than the memory is
    monkeypatch.setenv("PLACELOC_MEMORY_LIMIT_MB", "512")
    with pytest.raises(ImageError, match="odd.jpg: its Photo Sphere metadata .* more than a quarter of the memory"):
        whole_panorama(np.zeros((50, 100), np.uint8), PanoramaCrop(20000, 10000, 0, 0, 20, 10), "odd.jpg")
    canvas, _ = whole_panorama(np.zeros((50, 100), np.uint8), PanoramaCrop(200, 100, 0, 25, 100, 50), "fine.jpg")
    assert canvas.shape == (100, 200)


def _line_image(arrays: dict, h: int, w: int) -> np.ndarray:
    return np.unpackbits(arrays["lines"][0].view(np.uint8), bitorder="little")[:h * w].reshape(h, w)


def test_a_cropped_photo_sphere_draws_its_own_lines_only(tmp_path):
    # the L-shaped room's panorama without its top 40 and bottom 30 degrees (a photo sphere a
    # phone did not close): stored cropped with its metadata, its lines inside the covered
    # rows are the whole panorama's; none is drawn outside, not even the crop's own edge
    pose = [2.1, 5.3, 1.4, 62.5]
    img = _grey_panorama(pose, np.random.default_rng(1))          # 512 x 256
    top, bottom = 57, 256 - 43                                     # 40 deg down from the zenith, 30 up from the nadir
    img[top:top + 12], img[bottom - 12:bottom] = 245, 35           # a bright ceiling and a dark floor at its edges
    crop = PanoramaCrop(512, 256, 0, top, 512, bottom - top)
    write_photo_sphere(tmp_path / "sphere.jpg", img[top:bottom], gpano_xmp(crop))
    write_photo_sphere(tmp_path / "bare.jpg", img[top:bottom], None)
    w, h = 288, 144
    kw = {"width": w, "height": h, "face_px": 256, "min_length": 8.0, "level_max_deg": 0.0}
    gray = cv2.imread(str(tmp_path / "sphere.jpg"), cv2.IMREAD_GRAYSCALE)
    part = _line_image(panorama_arrays(gray, path=str(tmp_path / "sphere.jpg"), **kw), h, w)
    whole = _line_image(panorama_arrays(img, **kw), h, w)
    rows = np.arange(h)
    inner = (rows >= (top / 256 * h) + 2) & (rows < (bottom / 256 * h) - 2)
    outer = (rows < top / 256 * h - 1) | (rows >= bottom / 256 * h + 1)
    assert part[outer].sum() == 0
    edges = (np.abs(rows - top / 256 * h) <= 1) | (np.abs(rows - bottom / 256 * h) <= 1)
    assert part[edges].sum() == 0
    # the fill's edge is strong: drawn as if the photo covered the sphere, it would be there
    canvas, _ = whole_panorama(gray, crop)
    naive = draw_line_image(panorama_lines(canvas, face_px=256, min_length=8.0), face_px=256, width=w, height=h)
    assert naive[edges].sum() > 0.5 * w
    near = cv2.dilate(whole, np.ones((3, 3), np.uint8))
    assert (part[inner] & near[inner]).sum() >= 0.95 * part[inner].sum()       # its lines are the whole one's
    assert part[inner].sum() >= 0.9 * whole[inner].sum()                      # and most of them are there
    # without its metadata the crop is refused, and the message says what would do
    with pytest.raises(ImageError, match="bare.jpg.*Photo Sphere metadata"):
        panorama_arrays(gray, path=str(tmp_path / "bare.jpg"), **kw)
    # the map's lines of the covered rows are there, and the same is true of the map
    ref = _render(pose, w, h)
    assert (cv2.dilate(part, np.ones((3, 3), np.uint8)) & ref)[inner].sum() >= 0.8 * ref[inner].sum()


def test_cropped_photo_spheres_of_several_sizes_localized_end_to_end(tmp_path):
    # three photo spheres of the L-shaped room, each cropped differently (so of three sizes
    # in one folder), with their metadata: each is placed within 0.1 m and 2.5 deg
    import yaml

    from placeloc.core.config import load_config
    from placeloc.core.runner import run_all

    (tmp_path / "plan.yaml").write_text(yaml.safe_dump(PLAN))
    (tmp_path / "q").mkdir()
    truth = [(1.2, 1.1, 1.4, 30.0), (4.9, 2.6, 1.4, 200.0), (2.3, 5.8, 1.4, 287.5)]
    rows = [(40, 210), (20, 236), (57, 200)]                        # of 256: what each covers
    rng = np.random.default_rng(2)
    with open(tmp_path / "poses.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "x", "y", "z", "heading_deg"])
        for k, (pose, (top, bottom)) in enumerate(zip(truth, rows)):
            img = _grey_panorama(pose, rng)
            write_photo_sphere(tmp_path / "q" / f"p{k}.jpg", img[top:bottom],
                               gpano_xmp(PanoramaCrop(512, 256, 0, top, 512, bottom - top)))
            w.writerow([f"p{k}.jpg", *pose])
    cfg = load_config(data={"method": "umap", "query": {"images": str(tmp_path / "q")},
                            "ground_truth": {"kind": "poses", "path": str(tmp_path / "poses.csv")},
                            "umap": {"model": str(tmp_path / "plan.yaml"), "query_kind": "panorama",
                                     "grid": {"x": [0.2, 5.8, 0.2], "y": [0.2, 6.8, 0.2], "z": 1.4, "headings": [0.0]}},
                            "plots": False}, base_dir=tmp_path)
    run_all(cfg, tmp_path / "run", quiet=True)
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["max_error_m"] <= 0.1
    for r, t in zip(csv.DictReader(open(tmp_path / "run" / "estimates.csv")), truth):
        assert abs((float(r["heading_deg"]) - t[3] + 180) % 360 - 180) <= 2.5


@pytest.mark.parametrize("spread", [None, 1])
def test_the_seen_rows_table_equals_the_scores_with_the_unseen_rows_weighed_zero(spread):
    # a query that saw rows 3..12 of 16: its table with `seen` counts the map's lines in
    # those rows only in the recall half, as the pixel path does with the other rows'
    # weights set to zero (the precision half is the same either way: the query has no
    # pixels there); the tolerant table likewise equals the table at the same tau and no blur
    from placeloc.umap.panorama import (
        chamfer_at_shifts,
        chamfer_spectra,
        chamfer_table,
        precision_rows,
        row_weights,
        seen_rows,
        tolerant_chamfer_table,
    )

    rng = np.random.default_rng(5)
    h, w, bins = 16, 24, 4
    shape = (3, bins, h, w) if spread is not None else (3, h, w)
    db = (rng.random(shape) < 0.05).astype(np.uint8)
    q = (rng.random(shape[1:]) < 0.05).astype(np.uint8)
    seen = np.zeros((1, h), np.float32)
    seen[0, 3:13] = 1.0
    q[..., :3, :] = 0
    q[..., 13:, :] = 0
    weights = row_weights(h, polar_deg=60.0, polar_weight=1.0, solid_angle=True)
    prows = precision_rows(h, 75.0)
    sp = chamfer_spectra(db, tau_px=3.0, weights=weights, spread=spread)
    table = chamfer_table(sp, q[None], tau_px=3.0, weights=weights, chance="none", precision_rows=prows,
                          spread=spread, seen=seen)[0]
    shifts = np.tile(np.arange(w), (3, 1))
    at = chamfer_at_shifts(db, q, shifts, tau_px=3.0, weights=weights * seen[0], chance="none", precision_rows=prows,
                           spread=spread)
    assert np.abs(table - at).max() < 1e-4
    plain = chamfer_table(sp, q[None], tau_px=3.0, weights=weights, chance="none", precision_rows=prows, spread=spread)[0]
    assert np.abs(plain - table).max() > 0.01                 # the map's lines outside the rows no longer count
    tolerant = tolerant_chamfer_table(sp, q[None], recall_tau_px=3.0, blur_px=0, weights=weights,
                                      precision_rows=prows, spread=spread, seen=seen)[0]
    assert np.abs(tolerant - table).max() < 1e-4
    # the rows a coverage gives: row centres inside it by more than the drawing's 1 degree margin
    rows = seen_rows(np.array([[0.0, 0.25, 1.0, 0.5]]), 8)     # rows 2..5 of 8 (elevations 45 .. -45 deg)
    assert rows.tolist() == [[0, 0, 1, 1, 1, 1, 0, 0]]
    # levelled by 20 deg, the band it saw in the levelled frame is 20 deg narrower either side
    assert seen_rows(np.array([[0.0, 0.25, 1.0, 0.5]]), 8, np.array([20.0])).tolist() == [[0, 0, 0, 1, 1, 0, 0, 0]]


def test_generated_photo_spheres_are_the_whole_panoramas_rows_with_their_metadata(tmp_path):
    # cover_low_deg / cover_high_deg: the same home and poses, each panorama stored as the
    # rows between those elevations (JPEG, so within its rounding) with its metadata
    from placeloc.synth.home import generate

    kw = {"seed": 3, "panoramas": 3, "width": 256, "stats_width": 64}
    generate(tmp_path / "whole", **kw)
    generate(tmp_path / "sphere", cover_low_deg=-55.0, cover_high_deg=60.0, **kw)
    whole = list(csv.DictReader(open(tmp_path / "whole" / "poses.csv")))
    sphere = list(csv.DictReader(open(tmp_path / "sphere" / "poses.csv")))
    top, bottom = round(30 / 180 * 128), round(145 / 180 * 128)
    for a, b in zip(whole, sphere):
        assert b["frame"] == a["frame"].replace(".png", ".jpg") and (a["x"], a["y"], a["heading_deg"]) == (
            b["x"], b["y"], b["heading_deg"])
        assert panorama_crop(tmp_path / "sphere" / "panoramas" / b["frame"]) == PanoramaCrop(256, 128, 0, top, 256,
                                                                                            bottom - top)
        full = cv2.imread(str(tmp_path / "whole" / "panoramas" / a["frame"]), cv2.IMREAD_GRAYSCALE)
        part = cv2.imread(str(tmp_path / "sphere" / "panoramas" / b["frame"]), cv2.IMREAD_GRAYSCALE)
        assert part.shape == (bottom - top, 256)
        assert np.abs(part.astype(int) - full[top:bottom]).mean() < 2.0
    with pytest.raises(ValueError, match="cover_low_deg"):
        generate(tmp_path / "bad", cover_low_deg=10.0, cover_high_deg=-10.0, **kw)


def test_the_picture_shades_the_rows_the_photo_did_not_cover(tmp_path):
    from placeloc.umap.plots import plot_panorama_overlay

    h, w = 72, 144
    unseen = np.zeros(h, bool)
    unseen[:20] = True                                         # the ceiling cap the photo lacks
    empty = np.zeros((h, w), np.uint8)
    plot_panorama_overlay(tmp_path / "p.png", empty, empty, None, "a cropped sphere", unseen=unseen)
    plot_panorama_overlay(tmp_path / "whole.png", empty, empty, None, "a whole sphere")
    img = cv2.imread(str(tmp_path / "p.png"))[:, :, ::-1]
    whole = cv2.imread(str(tmp_path / "whole.png"))[:, :, ::-1]
    # the plot area spans rows 56..504 of the picture for elevations 90..-90: elevation 75 deg
    # (image row 6 of 72) lies at picture row 56 + 448 * 15 / 180, elevation 0 at the middle
    top, middle = int(56 + 448 * 15 / 180), 280
    assert tuple(img[top, 500]) == (219, 227, 242) and tuple(img[middle, 500]) == (255, 255, 255)
    assert tuple(whole[top, 500]) == (255, 255, 255)
