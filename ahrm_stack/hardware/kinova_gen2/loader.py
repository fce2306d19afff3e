"""How Kinova's Gen2 SDK finds its communication layer, checked before ``InitAPI`` runs.

The command layer (``deploy.kinova_gen2.library``) is loaded by path. Its ``InitAPI`` then
``dlopen``\\ s the communication layer by **bare name** (``USBCommLayerUbuntu.so`` for kinova-ros's
x86_64 build; ``Kinova.API.CommLayerUbuntu.so`` for its i386 build and Kinova's installer). None of
Kinova's libraries has a SONAME, so a copy already loaded by path does not satisfy that lookup:
only the dynamic loader's search path does: ``LD_LIBRARY_PATH`` as it was when the process
started, or a default directory such as ``/usr/lib`` (where kinova-ros's install copies it; the
ldconfig cache cannot help: ldconfig skips files not named ``lib*.so``). Without it the real ``InitAPI`` returns 2002
(ERROR_LOAD_COMM_DLL), and the SDK then crashes in ``SendAdvanceTrajectory`` (observed).

:func:`check_comm_layers` does the loader's lookup itself, by the name the command layer will
use (read from the binary: :func:`comm_layer_names`), and turns a failure into one line that says
what to do. The process environment is never changed and the process never re-executed: a
robotics engineer sets ``LD_LIBRARY_PATH`` (or copies the file to ``/usr/lib``) once, as for
kinova-ros.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import re
from pathlib import Path

#: Kinova's x86_64 USB SDK shipped with this repository (see its README.md).
VENDOR_DIR = Path(__file__).resolve().parents[1] / "vendor" / "kinova_gen2" / "x86_64-linux-gnu"
VENDOR_LIBRARY = VENDOR_DIR / "USBCommandLayerUbuntu.so"

# A NUL-terminated string constant naming a communication layer: the argument of InitAPI's dlopen
# (exactly one per kinova-ros build; DWARF macro text such as `"EthCommLayerUbuntu.so"` is quoted,
# not NUL-delimited, and does not match).
_COMM_NAME = re.compile(rb"\x00([A-Za-z0-9_.]*CommLayer[A-Za-z0-9_.]*\.so)\x00")
_RTLD_DI_LINKMAP = 2


class LoaderPathError(ValueError):
    """The communication layer cannot be loaded by its bare name; one line saying what to do."""


def comm_layer_names(library: Path) -> tuple[str, ...]:
    """The file names of the communication layers ``library`` loads by bare name (sorted); ``()``
    for a command layer that names none (the tests' fake SDK)."""
    data = Path(library).read_bytes()
    return tuple(sorted({m.decode() for m in _COMM_NAME.findall(data)}))


def _loaded_from(handle: ctypes.CDLL) -> str | None:
    """The file the dynamic loader opened for ``handle`` (``dlinfo``), or None if unknown."""
    for candidate in (None, ctypes.util.find_library("dl")):
        try:
            dlinfo = ctypes.CDLL(candidate).dlinfo
        except (OSError, AttributeError):
            continue

        class _LinkMap(ctypes.Structure):
            _fields_ = [("l_addr", ctypes.c_void_p), ("l_name", ctypes.c_char_p)]

        link = ctypes.POINTER(_LinkMap)()
        dlinfo.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_void_p]
        if dlinfo(ctypes.c_void_p(handle._handle), _RTLD_DI_LINKMAP, ctypes.byref(link)) == 0:
            name = link.contents.l_name
            return name.decode(errors="replace") if name else None
    return None


def loader_path_advice(folder: str, name: str) -> str:
    """What puts ``name`` (in ``folder``) on the dynamic loader's path: one line."""
    return (f"start the process with LD_LIBRARY_PATH={folder} (e.g. `export LD_LIBRARY_PATH={folder}` "
            "in the shell first: the loader reads it only at process start), or install the file "
            f"once where the loader always looks, as kinova-ros's install does: `sudo cp {folder}/{name} "
            "/usr/lib/` (an ldconfig entry does not work: ldconfig skips files not named lib*.so)")


def check_comm_layers(library: Path, key: str, docs: str) -> dict[str, str | None]:
    """Load each communication layer ``library`` names (:func:`comm_layer_names`) by its bare name,
    as ``InitAPI`` will: name -> the file the loader found (None if it cannot say). A
    :class:`LoaderPathError` naming ``key`` (the setting of ``library``) and ``docs`` when the
    loader does not find one (what to set), or finds one that cannot load (e.g. libusb missing)."""
    library = Path(library)
    found: dict[str, str | None] = {}
    for name in comm_layer_names(library):
        try:
            handle = ctypes.CDLL(name)
        except OSError as error:
            text = str(error)
            if text.startswith(f"{name}: cannot open shared object file"):
                beside = library.resolve().parent
                folder = str(beside) if (beside / name).is_file() else f"<the folder holding {name}>"
                raise LoaderPathError(
                    f"{key}: {library.name} loads its communication layer {name} by bare name and "
                    f"the dynamic loader does not find it: {loader_path_advice(folder, name)}; see "
                    f"{docs}") from None
            hint = (": install libusb (`sudo apt-get install libusb-1.0-0`, or `make setup`)"
                    if "libusb" in text else "")
            raise LoaderPathError(f"{key}: {library.name}'s communication layer {name} does not "
                                  f"load ({text}){hint}; see {docs}") from None
        found[name] = _loaded_from(handle)
    return found
