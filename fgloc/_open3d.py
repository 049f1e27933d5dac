"""Import open3d, providing libusb-1.0 from the ``libusb-package`` wheel when the system lacks it.

open3d's shared library links against libusb-1.0, which a fresh machine of this image does not
have. Loading the wheel's copy with RTLD_GLOBAL before the import satisfies the dynamic linker.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from types import ModuleType


def _preload_libusb() -> None:
    if ctypes.util.find_library("usb-1.0"):
        return
    try:
        import libusb_package
    except ImportError:  # pragma: no cover - dependency of fgloc
        return
    path = libusb_package.get_library_path()
    if path is not None:
        ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)


def open3d() -> ModuleType:
    """The open3d module, imported on first use."""
    _preload_libusb()
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    return o3d
