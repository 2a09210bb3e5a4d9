"""open3d, imported on first use, with an error that says what to install when it cannot be.

open3d is heavy (≈100 MB) and only ICP needs it; on Linux its native library links system
libraries that minimal machines and containers lack, and Python then reports only the first
missing ``.so``. :data:`OPEN3D_SYSTEM_LIBRARIES` maps each to its Debian package;
scripts/venv.sh and the Dockerfile install the same list.
"""

from __future__ import annotations

from typing import Any, Final

from skelfuse.calibration.errors import IcpUnavailable

OPEN3D_SYSTEM_LIBRARIES: Final = {
    "libusb-1.0.so.0": "libusb-1.0-0",
    "libGL.so.1": "libgl1",
    "libEGL.so.1": "libegl1",
    "libX11.so.6": "libx11-6",
    "libudev.so.1": "libudev1",
}
"""Shared library open3d links on Linux -> the Debian package that provides it."""


def load_open3d() -> Any:
    """The open3d module.

    Raises:
        IcpUnavailable: open3d is not installed, or a system library it links is missing; the
            message names the library and what to install.
    """
    try:
        import open3d
    except ImportError as exc:
        packages = [deb for lib, deb in OPEN3D_SYSTEM_LIBRARIES.items() if lib in str(exc)]
        if packages:
            fix = f"install the system library (Debian/Ubuntu: apt-get install {packages[0]})"
        else:
            fix = "install the server extras: pip install 'skelfuse[server]'"
        raise IcpUnavailable(f"ICP needs open3d, which does not import ({exc}): {fix}") from exc
    return open3d
