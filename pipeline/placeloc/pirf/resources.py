"""PIRF-nav2's memory and disk needs per stage (the contract with :mod:`placeloc.core.limits`)."""

from __future__ import annotations

from typing import Any, Sequence

from placeloc.core.limits import Need, count_images, decode_need

BASE_MEMORY: dict[str, int] = {
    "extract": 64 << 20,
    "build-dictionary": 32 << 20,
    "index": 64 << 20,
    "localize": 64 << 20,
    "evaluate": 32 << 20,
}


def needs(config: dict[str, Any], images: dict[str, Any], stages: Sequence[str]) -> list[Need]:
    p = config.get("pirf") or {}
    n = count_images(images)
    dims = 64 if str(p.get("features", "sift")).startswith("surf") else (61 if p.get("features") == "akaze" else 128)
    per_feature = 4 * dims + 24  # float32 descriptor, position, scale, angle
    # extract.h5 holds at most n_features descriptors a frame: an upper bound (frames with
    # fewer features write less; measured 73 kB a frame on 480x240 synthetic frames).
    n_features = int(p.get("n_features", 1000))
    needs = [Need(f"PIRF features of {n} frames (at most {n_features} a frame)", "pirf.n_features", stage="extract",
                  disk=n * n_features * per_feature)]
    cap = n * int(p.get("n_pmax", 200)) * per_feature  # at most n_pmax PIRFs per window, a window per frame
    # build-dictionary: the windows' PIRFs and the growing dictionary (measured 37 and 106 MB
    # for 80 and 260 frames, against caps of 8.6 and 28 MB).
    needs.append(Need("the PIRF dictionary (at most pirf.n_pmax PIRFs a window)", "pirf.n_pmax", stage="build-dictionary",
                      memory=3 * cap, disk=cap))
    needs.append(Need("the dictionary's ANN index", "pirf.ann", stage="index", memory=2 * cap, disk=cap))
    # SIFT/SURF on one frame: about 240 bytes of scale space per pixel (measured: one
    # 8000x8000 frame took 14.9 GB).
    verify = [] if int(p.get("verify_frames", 5)) == 0 else decode_need(
        config, images, 240, "the loop closures' geometric check (features again, about 240 bytes a pixel)", stages,
        stage="build-dictionary")
    return [x for x in needs if x.stage in stages] + \
        decode_need(config, images, 240, "feature extraction (about 240 bytes a pixel)", stages) + verify
