"""Presets that run from any clone (paths into the shared data folder), and the command
line's help naming every method."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from placeloc import cli
from placeloc.core.config import ConfigError, load_config
from placeloc.core.methods import METHOD_NAMES

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
PACKAGE = Path(__file__).resolve().parent.parent / "pipeline" / "placeloc"


def test_help_lists_every_discovered_method() -> None:
    text = " ".join(CliRunner().invoke(cli.app, ["--help"]).output.split())
    listed = re.search(r"Methods \(a config's `method:`\): ([a-z_, ]+);", text)
    assert listed is not None, text
    # every method folder (a subpackage with stages.py), in the help and nothing else
    on_disk = sorted(d.name for d in PACKAGE.iterdir() if (d / "stages.py").is_file() and (d / "__init__.py").is_file())
    assert listed.group(1).split(", ") == on_disk == sorted(METHOD_NAMES)
    assert len(on_disk) == 5


def _fake_shared(root: Path) -> Path:
    """A shared data folder holding two one-frame nordland-dev traverses."""
    for part in ("summer", "winter"):
        (root / "nordland-dev" / part).mkdir(parents=True)
        cv2.imwrite(str(root / "nordland-dev" / part / "images-00001.png"), np.full((32, 64), 100, np.uint8))
    return root


def test_preset_reads_the_shared_data_folder_from_any_clone(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """configs/nordland.yaml copied far from any ../shared/data resolves its images through
    PLACELOC_SHARED_DATA, whatever the folder the command runs in."""
    shared = _fake_shared(tmp_path / "somewhere" / "data")
    clone = tmp_path / "clone" / "configs"
    clone.mkdir(parents=True)
    shutil.copy(CONFIGS / "nordland.yaml", clone)
    monkeypatch.setenv("PLACELOC_SHARED_DATA", str(shared))
    monkeypatch.chdir(tmp_path)
    cfg = load_config(clone / "nordland.yaml")
    assert cfg["reference"]["images"] == str(shared / "nordland-dev" / "summer")
    assert cfg["query"]["images"] == str(shared / "nordland-dev" / "winter")


def test_preset_without_shared_data_names_the_variable(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PLACELOC_SHARED_DATA", str(tmp_path / "missing"))
    with pytest.raises(ConfigError, match=r"reference\.images: shared:nordland-dev/summer names the shared data folder, "
                                          r"but PLACELOC_SHARED_DATA='.*missing' does not exist; point it at the shared "
                                          r"data folder"):
        load_config(CONFIGS / "nordland.yaml")
    (tmp_path / "other").mkdir()
    monkeypatch.setenv("PLACELOC_SHARED_DATA", str(tmp_path / "other"))
    with pytest.raises(ConfigError, match=r"reference\.images: .*other/nordland-dev/summer does not exist"):
        load_config(CONFIGS / "nordland.yaml")


def test_no_preset_reads_a_path_outside_the_clone() -> None:
    """A relative path that climbs out of the checkout works only beside a particular
    folder layout: shared data goes through shared:, everything else stays inside."""
    for preset in sorted(CONFIGS.glob("*.yaml")):
        for line in preset.read_text().splitlines():
            value = line.split("#", 1)[0]
            assert "../../" not in value, f"{preset.name}: {line.strip()}"
