from __future__ import annotations

import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SAMPLES = ROOT / "data-samples" / "route"


@pytest.fixture
def route(tmp_path: Path) -> Path:
    """A private copy of the bundled route pair (tests may touch or corrupt files)."""
    dst = tmp_path / "route"
    shutil.copytree(SAMPLES, dst)
    return dst


def shared_data() -> Path | None:
    from placeloc.experiments import shared_data_dir

    return shared_data_dir()


@pytest.fixture
def tears_of_steel() -> Path:
    """The shared tears-of-steel tracks folder (markers.csv, points.csv, intrinsics.csv);
    the test is skipped when the shared data folder does not have it."""
    root = shared_data()
    if root is None or not (root / "tears-of-steel" / "markers.csv").is_file():
        pytest.skip("../shared/data/tears-of-steel is absent")
    return root / "tears-of-steel"
