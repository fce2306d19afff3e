"""``pupil_apriltags.Detector`` with its C resources freed in the library's own order.

pupil-apriltags 1.0.4's ``Detector.__del__`` destroys the tag families *before* the detector, and
``apriltag_detector_destroy`` then reads each family's ``impl`` (``quick_decode_uninit``) from
freed memory: a use-after-free that corrupts the heap now and then, and aborts the whole process
later, far from the cause (``free(): invalid pointer``; pupil-labs/apriltags PR #65, the same fix
as duckietown/lib-dt-apriltags PR #26, unmerged). With ``MALLOC_PERTURB_`` set, freed memory is
overwritten and the upstream order crashes at once (``tests/test_perception.py``).

:class:`Detector` frees the detector first, then the families, as AprilTag's own examples do.
Use it wherever the project makes a detector.
"""

from __future__ import annotations

from typing import Any

from pupil_apriltags import Detector as _UpstreamDetector


class Detector(_UpstreamDetector):
    """``pupil_apriltags.Detector`` (same arguments) whose :meth:`close` and ``__del__`` destroy
    the detector before the tag families it points to; closing twice is harmless."""

    tag_detector_ptr: Any  # ctypes pointer to apriltag_detector_t, None once closed
    tag_families: dict[str, Any]  # family name -> ctypes pointer to apriltag_family_t

    def close(self) -> None:
        ptr = getattr(self, "tag_detector_ptr", None)
        if ptr is None:
            return
        self.tag_detector_ptr = None  # the upstream __del__ sees None and does nothing
        lib = self.libc
        lib.apriltag_detector_destroy.restype = None
        lib.apriltag_detector_destroy(ptr)  # clears the families while they still exist
        for name, family in getattr(self, "tag_families", {}).items():
            destroy = getattr(lib, f"{name}_destroy")
            destroy.restype = None
            destroy(family)
        self.tag_families = {}

    def __del__(self) -> None:
        self.close()
