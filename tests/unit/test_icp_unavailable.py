"""ICP without a loadable open3d: the error names what to install (a fresh machine lacks libusb)."""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys
from collections.abc import Sequence
from types import ModuleType

import numpy as np
import pytest

from skelfuse.calibration.errors import CalibrationError, IcpUnavailable
from skelfuse.calibration.icp import refine_icp

# What CPython says when open3d's extension cannot load the library it links.
LIBUSB_MISSING = "libusb-1.0.so.0: cannot open shared object file: No such file or directory"


class _FailingOpen3d(importlib.abc.MetaPathFinder):
    def __init__(self, message: str) -> None:
        self.message = message

    def find_spec(
        self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname == "open3d":
            raise ImportError(self.message)
        return None


def _refine_without_open3d(monkeypatch: pytest.MonkeyPatch, message: str) -> IcpUnavailable:
    monkeypatch.delitem(sys.modules, "open3d", raising=False)
    monkeypatch.setattr(sys, "meta_path", [_FailingOpen3d(message), *sys.meta_path])
    cloud = np.random.default_rng(0).uniform(-1.0, 1.0, (100, 3))
    with pytest.raises(IcpUnavailable) as caught:
        refine_icp(cloud, cloud, np.eye(4))
    return caught.value


def test_a_missing_libusb_is_named_with_the_package_that_provides_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    error = _refine_without_open3d(monkeypatch, LIBUSB_MISSING)
    assert "libusb-1.0.so.0" in str(error)
    assert "apt-get install libusb-1.0-0)" in str(error)
    assert isinstance(error, CalibrationError)  # the calibration run reports it, not "internal"


def test_a_missing_open3d_points_to_the_server_extras(monkeypatch: pytest.MonkeyPatch) -> None:
    error = _refine_without_open3d(monkeypatch, "No module named 'open3d'")
    assert "pip install 'skelfuse[server]'" in str(error)
