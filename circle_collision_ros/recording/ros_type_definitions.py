"""Full ``ros2msg`` definition texts (with dependencies) for recording.

MCAP files of the ``ros2`` profile embed, per schema, the message's ``.msg``
text followed by the text of every type it depends on, so that a reader can
decode the data without the interface packages installed. The layout matches
rosbag2's ``LocalMessageDefinitionSource`` (and the MCAP storage plugin)::

    <root .msg text>
    ================================================================================
    MSG: std_msgs/Header
    <Header.msg text>
    ================================================================================
    MSG: builtin_interfaces/Time
    <Time.msg text>

Dependencies are visited depth first, each package's dependency names sorted,
every type emitted once, exactly as rosbag2 does, so the schema bytes of our
recordings equal those ``ros2 bag record`` would write.
"""
from __future__ import annotations

import json
import os
import re
import sys
from functools import lru_cache
from pathlib import Path

__all__ = ["DefinitionFormat", "TypeDefinitionError", "full_msg_definition", "split_type_name",
           "type_description_hash"]


class DefinitionFormat:
    """Constants of the ``ros2msg`` concatenated definition format."""

    SEPARATOR = "=" * 80
    DEPENDENCY_PREFIX = "MSG: "
    MSG_EXTENSION = ".msg"
    TYPE_HASH_EXTENSION = ".json"


class TypeDefinitionError(LookupError):
    """A type name is malformed or its ``.msg`` file cannot be found."""


# Built-in field types that have no .msg file (bounded strings like string<=8 too).
_PRIMITIVES = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
})
_TYPE_NAME = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/(?:msg/)?([A-Za-z][A-Za-z0-9_]*)$")
# The field type is the first token of a field or constant line, minus any array suffix.
_FIELD_TYPE = re.compile(r"^\s*([A-Za-z0-9_/]+)(?:<=\d+)?(?:\[[^\]]*\])?\s+\S")


def split_type_name(type_name: str) -> tuple[str, str]:
    """Split ``pkg/msg/Type`` or ``pkg/Type`` into ``(pkg, Type)``.

    Raises
    ------
    TypeDefinitionError
        If the name is not of either form.
    """
    match = _TYPE_NAME.match(type_name)
    if match is None:
        raise TypeDefinitionError(f"invalid message type name {type_name!r} "
                                  "(expected 'pkg/msg/Type')")
    return match.group(1), match.group(2)


def _share_directories(package: str) -> list[Path]:
    """Candidate share directories of ``package``, most authoritative first."""
    candidates: list[Path] = []
    try:
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )
        try:
            candidates.append(Path(get_package_share_directory(package)))
        except (PackageNotFoundError, ValueError, KeyError, OSError):
            pass
    except ImportError:
        pass
    # A venv with the ROS wheels has share/ under its prefix, but AMENT_PREFIX_PATH
    # often does not list it (it is only set by sourcing a ROS setup file).
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) + [sys.prefix]:
        if prefix:
            candidates.append(Path(prefix) / "share" / package)
    return candidates


def _find_interface_file(package: str, name: str, extension: str) -> Path | None:
    for share in _share_directories(package):
        path = share / "msg" / f"{name}{extension}"
        if path.is_file():
            return path
    return None


@lru_cache(maxsize=256)
def _msg_text(package: str, name: str) -> str:
    path = _find_interface_file(package, name, DefinitionFormat.MSG_EXTENSION)
    if path is None:
        raise TypeDefinitionError(
            f"no definition file for {package}/msg/{name} (looked for msg/{name}.msg in the "
            f"share directory of {package!r} via ament_index, AMENT_PREFIX_PATH and {sys.prefix})")
    return path.read_text(encoding="utf-8")


def _dependencies(text: str, package: str) -> list[str]:
    """Sorted names of the non-primitive types referenced by a ``.msg`` text.

    Names keep the spelling of the file (``std_msgs/Header``); a bare ``Type``
    refers to the containing package, as in rosbag2.
    """
    found: set[str] = set()
    for line in text.splitlines():
        line = line.split("#", 1)[0]
        match = _FIELD_TYPE.match(line)
        if match is None:
            continue
        field_type = match.group(1)
        if field_type in _PRIMITIVES:
            continue
        found.add(field_type if "/" in field_type else f"{package}/{field_type}")
    return sorted(found)


def full_msg_definition(type_name: str) -> str:
    """Return the ``ros2msg`` schema text of ``type_name`` with all dependencies.

    Parameters
    ----------
    type_name
        ``pkg/msg/Type`` (or ``pkg/Type``), e.g.
        ``circle_collision_msgs/msg/CircleStateArray``.

    Returns
    -------
    str
        The root ``.msg`` text, then per dependency a separator line of 80 ``=``,
        ``MSG: pkg/Type`` and that type's text.

    Raises
    ------
    TypeDefinitionError
        If the name is malformed or a ``.msg`` file is missing.
    """
    seen: set[str] = set()

    def append_recursive(package: str, name: str) -> str:
        text = _msg_text(package, name)
        result = text
        for dependency in _dependencies(text, package):
            if dependency in seen:
                continue
            seen.add(dependency)
            dep_package, dep_name = split_type_name(dependency)
            result += (f"\n{DefinitionFormat.SEPARATOR}\n"
                       f"{DefinitionFormat.DEPENDENCY_PREFIX}{dependency}\n")
            result += append_recursive(dep_package, dep_name)
        return result

    return append_recursive(*split_type_name(type_name))


@lru_cache(maxsize=256)
def type_description_hash(type_name: str) -> str:
    """Return the ``RIHS01_...`` type hash of ``type_name``, or ``""`` if unknown.

    Read from the ``msg/<Type>.json`` type description rosidl installs beside the
    ``.msg`` file; rosbag2 stores it as ``type_description_hash``/``topic_type_hash``.
    """
    try:
        package, name = split_type_name(type_name)
    except TypeDefinitionError:
        return ""
    path = _find_interface_file(package, name, DefinitionFormat.TYPE_HASH_EXTENSION)
    if path is None:
        return ""
    try:
        hashes = json.loads(path.read_text(encoding="utf-8")).get("type_hashes", [])
        full_name = f"{package}/msg/{name}"
        for entry in hashes:
            if entry.get("type_name") == full_name:
                return str(entry.get("hash_string", ""))
    except (OSError, ValueError, AttributeError, TypeError):
        pass
    return ""
