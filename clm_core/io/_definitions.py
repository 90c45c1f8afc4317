"""The ``clm_msgs`` definitions: where they are, the rosbags type store, and the text rosbag2 embeds.

Implementation of part 1 of :mod:`clm_core.io.messages` (which re-exports the
public names; import them from there). The ``.msg``/``.srv``/``.action``
files of ``clm_msgs`` are the one source of truth: ``<prefix>/share/clm_msgs`` for each
prefix of ``AMENT_PREFIX_PATH`` and ``sys.prefix`` (what rosidl generated
rclpy's classes from), then the source tree ``ros2_ws/src/clm_msgs``, then the
copy packaged with clm_core (``clm_core/io/interfaces/clm_msgs``, identical by
test).
"""

from __future__ import annotations

import functools
import os
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from clm_core.io.errors import MessageError

if TYPE_CHECKING:
    from collections.abc import Iterable

    from rosbags.interfaces.typing import Typesdict
    from rosbags.typesys.store import Typestore

__all__ = [
    "PACKAGE",
    "clm_types",
    "interface_dir",
    "message_definition",
    "packaged_interface_dir",
    "source_interface_dir",
    "typestore",
]

#: Name of the interface package.
PACKAGE = "clm_msgs"

_SEPARATOR = re.compile(r"^---[ \t]*\r?$", re.MULTILINE)
# Event message rosidl generates for every service (Jazzy service introspection), .msg syntax.
_SERVICE_EVENT = "service_msgs/ServiceEventInfo info\n{name}_Request[<=1] request\n{name}_Response[<=1] response\n"
# rosbag2 Jazzy (local_message_definition_source.cpp): field types of a .msg text, and the delimiter.
_MSG_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
_PRIMITIVES = frozenset(
    "bool byte char float32 float64 int8 uint8 int16 uint16 int32 uint32 int64 uint64 string".split()
)
_DELIMITER = "=" * 80 + "\n"


def source_interface_dir() -> Path:
    """``ros2_ws/src/clm_msgs`` of the source tree (may not exist in an installed clm_core)."""
    return Path(__file__).resolve().parents[2] / "ros2_ws" / "src" / PACKAGE


def packaged_interface_dir() -> Path:
    """The copy of the clm_msgs definitions packaged with clm_core (identical to the source tree, by test)."""
    return Path(__file__).resolve().parent / "interfaces" / PACKAGE


def _prefixes() -> list[Path]:
    found = [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    return [*found, Path(sys.prefix)]


def interface_dir(prefixes: Iterable[str | os.PathLike[str]] | None = None) -> Path:
    """Directory holding ``msg/*.msg`` and ``srv/*.srv`` of ``clm_msgs``.

    Parameters
    ----------
    prefixes : iterable of path-like, optional
        Install prefixes to search for ``share/clm_msgs`` instead of
        ``AMENT_PREFIX_PATH`` and ``sys.prefix``; the source tree and the
        packaged copy are still the fallbacks.

    Returns
    -------
    pathlib.Path
        The first of: ``<prefix>/share/clm_msgs``, ``ros2_ws/src/clm_msgs``,
        the packaged copy, that has ``msg/*.msg`` files.

    Raises
    ------
    MessageError
        None of them has the definitions.
    """
    search = [Path(p) for p in prefixes] if prefixes is not None else _prefixes()
    candidates = [p / "share" / PACKAGE for p in search] + [source_interface_dir(), packaged_interface_dir()]
    for cand in candidates:
        if any((cand / "msg").glob("*.msg")):
            return cand
    raise MessageError(
        f"no {PACKAGE} interface definitions (msg/*.msg) found; looked in: {', '.join(map(str, candidates))}"
    )


def _read(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        raise MessageError(f"cannot read interface definition {path}: {exc}") from exc


def _parse(text: str, typename: str, path: Path) -> Typesdict:
    from rosbags.typesys import TypesysError, get_types_from_msg

    try:
        return get_types_from_msg(text, typename)
    except TypesysError as exc:
        raise MessageError(f"cannot parse {path} as {typename}: {exc}") from exc


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


def _split(path: Path, parts: int) -> list[str]:
    texts = _SEPARATOR.split(_read(path))
    if len(texts) != parts:
        raise MessageError(f'{path}: expected {parts - 1} "---" line(s), found {len(texts) - 1}')
    return texts


def _interface_types(path: Path, kind: str, texts: dict[str, str], known: Typesdict) -> Typesdict:
    """Parts ``<Name>_<suffix>`` of a service or action, parsed as messages and moved to ``<kind>/``."""
    parsed: Typesdict = {}
    mapping: dict[str, str] = {}
    for suffix, text in texts.items():
        as_msg = f"{PACKAGE}/msg/{path.stem}_{suffix}"
        if as_msg in known:
            raise MessageError(f"{path}: message {as_msg} clashes with the {kind} part of the same name")
        parsed.update(_parse(text, as_msg, path))
        mapping[as_msg] = f"{PACKAGE}/{kind}/{path.stem}_{suffix}"
    return _rename_refs(parsed, mapping)


def _service_types(path: Path, known: Typesdict) -> Typesdict:
    """A .srv file as its _Request, _Response and _Event types."""
    request, response = _split(path, 2)
    texts = {"Request": request, "Response": response, "Event": _SERVICE_EVENT.format(name=path.stem)}
    return _interface_types(path, "srv", texts, known)


def _action_types(path: Path, known: Typesdict) -> Typesdict:
    """An .action file as the types rosidl generates for it (``clm_msgs/action/<Name>_...``).

    ``_Goal``, ``_Result``, ``_Feedback``, the ``_FeedbackMessage`` of the
    feedback topic, and the ``_SendGoal`` / ``_GetResult`` services
    (``_Request``, ``_Response``, ``_Event``), with the fields rosidl_generator
    adds (``unique_identifier_msgs/UUID goal_id``, ...).
    """
    goal, result, feedback = _split(path, 3)
    name = path.stem
    texts = {
        "Goal": goal,
        "Result": result,
        "Feedback": feedback,
        "FeedbackMessage": f"unique_identifier_msgs/UUID goal_id\n{name}_Feedback feedback\n",
        "SendGoal_Request": f"unique_identifier_msgs/UUID goal_id\n{name}_Goal goal\n",
        "SendGoal_Response": "bool accepted\nbuiltin_interfaces/Time stamp\n",
        "SendGoal_Event": _SERVICE_EVENT.format(name=f"{name}_SendGoal"),
        "GetResult_Request": "unique_identifier_msgs/UUID goal_id\n",
        "GetResult_Response": f"int8 status\n{name}_Result result\n",
        "GetResult_Event": _SERVICE_EVENT.format(name=f"{name}_GetResult"),
    }
    return _interface_types(path, "action", texts, known)


@functools.lru_cache(maxsize=8)
def _clm_types_cached(root: Path) -> Typesdict:
    types: Typesdict = {}
    msg_files = sorted((root / "msg").glob("*.msg"))
    if not msg_files:
        raise MessageError(f"no msg/*.msg files in {root}")
    for path in msg_files:
        types.update(_parse(_read(path), f"{PACKAGE}/msg/{path.stem}", path))
    for path in sorted((root / "srv").glob("*.srv")):
        types.update(_service_types(path, types))
    for path in sorted((root / "action").glob("*.action")):
        types.update(_action_types(path, types))
    return types


def clm_types(directory: str | os.PathLike[str] | None = None) -> Typesdict:
    """Parse every ``clm_msgs`` message, service and action definition.

    Parameters
    ----------
    directory : path-like, optional
        Package directory with ``msg/``, ``srv/`` and ``action/``; default
        :func:`interface_dir`.

    Returns
    -------
    dict
        rosbags type dictionary (``'clm_msgs/msg/WheelLoads'``,
        ``'clm_msgs/srv/Calibrate_Request'``,
        ``'clm_msgs/action/Calibrate_FeedbackMessage'``, ...), for
        ``Typestore.register``.

    Raises
    ------
    MessageError
        A definition cannot be found, read or parsed.
    """
    root = Path(directory) if directory is not None else interface_dir()
    return dict(_clm_types_cached(root.resolve()))


def typestore(directory: str | os.PathLike[str] | None = None) -> Typestore:
    """A new ROS 2 Jazzy rosbags type store with the ``clm_msgs`` types.

    Parameters
    ----------
    directory : path-like, optional
        Package directory with ``msg/`` and ``srv/``; default :func:`interface_dir`.

    Returns
    -------
    rosbags.typesys.store.Typestore
        ``Stores.ROS2_JAZZY`` plus every clm_msgs type; a new object on each
        call (registering more types in it does not affect other callers).

    Raises
    ------
    MessageError
        The definitions cannot be found or parsed, or clash with the store.
    """
    from rosbags.typesys import Stores, TypesysError, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    try:
        store.register(clm_types(directory))
    except TypesysError as exc:
        raise MessageError(f"cannot register the {PACKAGE} types: {exc}") from exc
    return store


@functools.lru_cache(maxsize=256)
def _own_text(name: str, clm_dir: Path) -> str:
    """The .msg text of one type ``pkg/Name`` or ``pkg/msg/Name`` (no dependencies)."""
    pkg, *_, short = name.split("/")
    if pkg == PACKAGE:
        return _read(clm_dir / "msg" / f"{short}.msg")
    for prefix in _prefixes():
        path = prefix / "share" / pkg / "msg" / f"{short}.msg"
        if path.is_file():
            return _read(path)
    # no installed .msg: rosbags' own definition of the type (the same fields, without comments)
    from rosbags.typesys import Stores, TypesysError, get_typestore

    full = f"{pkg}/msg/{short}"
    try:
        text, _ = get_typestore(Stores.ROS2_JAZZY).generate_msgdef(full, ros_version=2)
    except (TypesysError, KeyError) as exc:
        raise MessageError(f"no definition of message type {full!r} (not clm_msgs nor ROS 2 Jazzy)") from exc
    return text.split(_DELIMITER)[0]


def message_definition(msgtype: str, directory: str | os.PathLike[str] | None = None) -> str:
    """The definition text rosbag2 Jazzy embeds in a bag for ``msgtype`` (encoding ``ros2msg``).

    The type's ``.msg`` file verbatim (comments included), then each
    dependency once, depth first in sorted order, after a line of 80 ``=``
    and ``MSG: pkg/Name`` (rosbag2's ``LocalMessageDefinitionSource``).
    Definitions outside clm_msgs come from ``<prefix>/share/<pkg>/msg`` when
    installed, else from rosbags' Jazzy store (same fields, no comments).

    Parameters
    ----------
    msgtype : str
        ``pkg/msg/Name``, e.g. ``'clm_msgs/msg/WheelLoads'``.
    directory : path-like, optional
        clm_msgs package directory (default :func:`interface_dir`).

    Returns
    -------
    str
        The full definition text.

    Raises
    ------
    MessageError
        A definition cannot be found.
    """
    clm_dir = (Path(directory) if directory is not None else interface_dir()).resolve()
    seen: set[str] = set()

    def append(name: str, depth: int) -> str:
        if depth <= 0:
            raise MessageError(f"{msgtype}: definitions nest too deep (recursive type?)")
        text = _own_text(name, clm_dir)
        pkg = name.split("/")[0]
        deps = set()
        for m in _MSG_FIELD_TYPE.finditer(text):
            t = m.group(1)
            if t not in _PRIMITIVES:
                deps.add(t if "/" in t else f"{pkg}/{t}")
        out = text
        for dep in sorted(deps):
            if dep not in seen:
                seen.add(dep)
                out += "\n" + _DELIMITER + "MSG: " + dep + "\n" + append(dep, depth - 1)
        return out

    return append(msgtype, 50)
