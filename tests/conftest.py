"""Shared fixtures: paths to the real motion-capture sets beside the checkout."""

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CMU_DIR = SHARED / "cmu-handshake"
BANDAI_DIR = SHARED / "bandai-emotion"


@pytest.fixture(scope="session")
def cmu_files():
    files = sorted(CMU_DIR.glob("*.bvh"))
    if not files:
        pytest.skip(f"shared CMU data not found at {CMU_DIR}")
    return files


@pytest.fixture(scope="session")
def bandai_root():
    if not (BANDAI_DIR / "data").is_dir():
        pytest.skip(f"shared Bandai data not found at {BANDAI_DIR}")
    return BANDAI_DIR


@pytest.fixture(scope="session")
def bandai_files(bandai_root):
    return sorted((bandai_root / "data").glob("*.bvh"))
