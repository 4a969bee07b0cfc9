"""Fixture datasets written once per test session into a temp dir (exact on-disk layouts)."""

import shutil

import pytest

from tests.data.floaff_fixture import make_floaff_dataset
from tests.data.moma_kitchen.data import make_dataset


@pytest.fixture(scope="session")
def moma_src(tmp_path_factory):
    root = tmp_path_factory.mktemp("moma_src")
    return root, make_dataset(root)


@pytest.fixture
def moma_root(moma_src, tmp_path):
    """A private copy (tests may corrupt files or fill caches)."""
    src, expected = moma_src
    dst = tmp_path / "moma"
    shutil.copytree(src, dst)
    return dst, expected


@pytest.fixture(scope="session")
def floaff_src(tmp_path_factory):
    root = tmp_path_factory.mktemp("floaff_src")
    return root, make_floaff_dataset(root)


@pytest.fixture
def floaff_root(floaff_src, tmp_path):
    src, expected = floaff_src
    dst = tmp_path / "floaff"
    shutil.copytree(src, dst)
    return dst, expected
