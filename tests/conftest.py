"""Shared helpers for the test suite."""
from pathlib import Path

import pytest

from sphcore.scene import load_scene, scene_from_dict

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"


@pytest.fixture
def configs_dir() -> Path:
    return CONFIGS


def scene(name: str, *overrides: str):
    """Load configs/<name>.toml with --set style overrides."""
    return load_scene(CONFIGS / f"{name}.toml", list(overrides))


def scene_dict(**sections):
    """A scene from plain dicts (tests that build their own geometry)."""
    return scene_from_dict(sections)
