"""rosbags type store with the ``clm_msgs`` interfaces registered.

Bags written with rosbags using :func:`typestore` deserialize in rclpy and
vice versa: the types are parsed from the very ``.msg``/``.srv`` files that
rosidl generated the rclpy classes from (the installed
``<prefix>/share/clm_msgs``), so field lists and RIHS01 type hashes agree.
Only ``rosbags`` is imported here; no rclpy is needed.

Services are registered the way ROS 2 Jazzy names them in bags and over DDS:
``clm_msgs/srv/<Name>_Request``, ``_Response`` and ``_Event`` (the service
introspection message). Two rosbags 0.11 limits apply to ``_Event`` only:
``generate_msgdef`` fails on it (so rosbags cannot write it to a bag), and
its RIHS01 hash differs from rosidl's because rosbags' Jazzy store declares
``service_msgs/ServiceEventInfo.client_gid`` as ``char[16]`` where rosidl
hashes ``uint8[16]`` (the CDR bytes are the same).

Examples
--------
>>> from clm_ros.msg_types import typestore
>>> ts = typestore()
>>> WheelLoads = ts.types['clm_msgs/msg/WheelLoads']
"""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore

from clm_ros.errors import ClmRosError

if TYPE_CHECKING:
    from collections.abc import Iterable

    from rosbags.interfaces.typing import Typesdict
    from rosbags.typesys.store import Typestore

__all__ = [
    "PACKAGE",
    "clm_types",
    "interface_dir",
    "source_interface_dir",
    "typestore",
]

#: Name of the interface package.
PACKAGE = "clm_msgs"

# Line between request and response in .srv files.
_SEPARATOR = re.compile(r"^---[ \t]*\r?$", re.MULTILINE)

# Event message that rosidl generates for every service (Jazzy service
# introspection), in .msg syntax; names relative to the service's package.
_SERVICE_EVENT = "service_msgs/ServiceEventInfo info\n{name}_Request[<=1] request\n{name}_Response[<=1] response\n"


def source_interface_dir() -> Path:
    """Return the ``clm_msgs`` package directory of the source tree.

    Returns
    -------
    pathlib.Path
        ``ros2_ws/src/clm_msgs`` next to this package's source directory; it
        may not exist (e.g. when clm_ros is installed without its sources).
    """
    # .../ros2_ws/src/clm_ros/clm_ros/msg_types.py -> .../ros2_ws/src/clm_msgs
    return Path(__file__).resolve().parents[2] / PACKAGE


def _candidate_prefixes() -> list[Path]:
    prefixes = [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes.append(Path(sys.prefix))
    return prefixes


def interface_dir(prefixes: Iterable[str | os.PathLike[str]] | None = None) -> Path:
    """Find the directory holding ``msg/*.msg`` and ``srv/*.srv`` of ``clm_msgs``.

    The installed package is preferred, because that is what rclpy's classes
    were generated from: ``<prefix>/share/clm_msgs`` for each prefix in
    ``AMENT_PREFIX_PATH`` (a sourced ROS install or colcon workspace), then
    ``sys.prefix`` (a venv set up by ``scripts/setup_ros.sh``). The source
    tree ``ros2_ws/src/clm_msgs`` is the fallback.

    Parameters
    ----------
    prefixes : iterable of path-like, optional
        Install prefixes to search instead of the default ones; the source
        tree is still the fallback.

    Returns
    -------
    pathlib.Path
        Directory with the subdirectories ``msg`` (and ``srv``).

    Raises
    ------
    ClmRosError
        If no prefix nor the source tree has ``msg/*.msg`` files of clm_msgs.
    """
    search = [Path(p) for p in prefixes] if prefixes is not None else _candidate_prefixes()
    candidates = [p / "share" / PACKAGE for p in search]
    candidates.append(source_interface_dir())
    for cand in candidates:
        if any((cand / "msg").glob("*.msg")):
            return cand
    tried = ", ".join(str(c) for c in candidates)
    msg = (
        f"no {PACKAGE} interface definitions (msg/*.msg) found; looked in: {tried}. "
        "Run scripts/setup_ros.sh VENV, or source the ROS workspace that has clm_msgs."
    )
    raise ClmRosError(msg)


def _read(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        msg = f"cannot read interface definition {path}: {exc}"
        raise ClmRosError(msg) from exc


def _parse(text: str, typename: str, path: Path) -> Typesdict:
    try:
        return get_types_from_msg(text, typename)
    except TypesysError as exc:
        msg = f"cannot parse {path} as {typename}: {exc}"
        raise ClmRosError(msg) from exc


def _rename_refs(types: Typesdict, mapping: dict[str, str]) -> Typesdict:
    """Rename types and the references to them in field descriptors."""

    def walk(obj: Any) -> Any:
        if isinstance(obj, str):
            return mapping.get(obj, obj)
        if isinstance(obj, tuple):
            return tuple(walk(item) for item in obj)
        return obj

    return {
        mapping.get(name, name): (consts, [(fname, walk(desc)) for fname, desc in fields])
        for name, (consts, fields) in types.items()
    }


def _service_types(path: Path, known: Typesdict) -> Typesdict:
    """Parse a .srv file into its _Request, _Response and _Event types.

    rosbags' .msg parser only makes ``pkg/msg/Name`` types: parse each part
    as a message, then move the names (and references) to ``pkg/srv/``.
    """
    parts = _SEPARATOR.split(_read(path))
    if len(parts) != 2:
        msg = f'{path}: expected one "---" line between request and response'
        raise ClmRosError(msg)
    texts = {
        "Request": parts[0],
        "Response": parts[1],
        "Event": _SERVICE_EVENT.format(name=path.stem),
    }
    parsed: Typesdict = {}
    mapping: dict[str, str] = {}
    for suffix, text in texts.items():
        as_msg = f"{PACKAGE}/msg/{path.stem}_{suffix}"
        if as_msg in known:
            msg = f"{path}: message {as_msg} clashes with the service part of the same name"
            raise ClmRosError(msg)
        parsed.update(_parse(text, as_msg, path))
        mapping[as_msg] = f"{PACKAGE}/srv/{path.stem}_{suffix}"
    return _rename_refs(parsed, mapping)


def clm_types(directory: str | os.PathLike[str] | None = None) -> Typesdict:
    """Parse every ``clm_msgs`` message and service definition.

    Parameters
    ----------
    directory : path-like, optional
        Package directory with ``msg/`` and ``srv/``; default
        :func:`interface_dir`.

    Returns
    -------
    dict
        rosbags type dictionary, keys like ``'clm_msgs/msg/WheelLoads'`` and
        ``'clm_msgs/srv/Calibrate_Request'``, ready for ``Typestore.register``.

    Raises
    ------
    ClmRosError
        If a definition cannot be found, read or parsed.
    """
    root = Path(directory) if directory is not None else interface_dir()
    types: Typesdict = {}
    msg_files = sorted((root / "msg").glob("*.msg"))
    if not msg_files:
        msg = f"no msg/*.msg files in {root}"
        raise ClmRosError(msg)
    for path in msg_files:
        types.update(_parse(_read(path), f"{PACKAGE}/msg/{path.stem}", path))
    for path in sorted((root / "srv").glob("*.srv")):
        types.update(_service_types(path, types))
    return types


def typestore(directory: str | os.PathLike[str] | None = None) -> Typestore:
    """Return a new ROS 2 Jazzy rosbags type store with the clm_msgs types.

    Parameters
    ----------
    directory : path-like, optional
        Package directory with ``msg/`` and ``srv/``; default
        :func:`interface_dir` (installed package first, then source tree).

    Returns
    -------
    rosbags.typesys.store.Typestore
        ``Stores.ROS2_JAZZY`` plus every clm_msgs type. A new object on each
        call: registering more types in it does not affect other callers.

    Raises
    ------
    ClmRosError
        If the definitions cannot be found or parsed, or clash with a type
        already in the store.
    """
    store = get_typestore(Stores.ROS2_JAZZY)
    types = clm_types(directory)
    try:
        store.register(types)
    except TypesysError as exc:
        msg = f"cannot register the {PACKAGE} types: {exc}"
        raise ClmRosError(msg) from exc
    return store
