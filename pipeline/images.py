"""Image folders: listing in natural order, fingerprints, loading with clear errors."""

from __future__ import annotations

import glob
import hashlib
import re
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")


class ImageError(RuntimeError):
    """An image (or image folder) cannot be used; the message names the file and the fix."""


def natural_key(name: str) -> list:
    """Sort key under which img2 comes before img10."""
    return [int(tok) if tok.isdigit() else tok.lower() for tok in re.split(r"(\d+)", name)]


@dataclass
class ImageSet:
    """An ordered list of image files, as one traverse."""

    source: str
    paths: list[Path]
    on_error: str = "stop"
    skipped: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.paths)

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.paths]

    def fingerprint(self) -> str:
        """SHA-256 over names, sizes and modification times: cheap, and changes when a file does."""
        h = hashlib.sha256()
        for p in self.paths:
            st = p.stat()
            h.update(f"{p.name}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
        return h.hexdigest()


def list_images(spec: str | Path, on_error: str = "stop") -> ImageSet:
    """List the images of a folder (or glob) in natural sort order."""
    spec = str(spec)
    p = Path(spec)
    if p.is_dir():
        files = [q for q in p.iterdir() if q.is_file() and q.suffix.lower() in IMAGE_EXTENSIONS]
    else:
        files = [Path(q) for q in glob.glob(spec) if Path(q).suffix.lower() in IMAGE_EXTENSIONS]
    if not files:
        raise ImageError(
            f"{spec}: no images found (looked for {', '.join(IMAGE_EXTENSIONS)}); "
            "point reference.images / query.images at a folder of images"
        )
    files.sort(key=lambda q: natural_key(q.name))
    return ImageSet(source=spec, paths=files, on_error=on_error)


def read_gray(path: str | Path) -> np.ndarray:
    """Read an image as 8-bit greyscale; colour is converted, 16-bit is scaled down."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise ImageError(f"{path}: cannot be read as an image (corrupt or not an image); "
                         "remove or replace it, or set on_error: skip beside images:")
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    return img


def read_color(path: str | Path) -> np.ndarray:
    """Read an image as 8-bit BGR."""
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ImageError(f"{path}: cannot be read as an image (corrupt or not an image); "
                         "remove or replace it, or set on_error: skip beside images:")
    return img
