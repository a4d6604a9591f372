"""
rosbag2 bags with MCAP storage, without ``ros2 bag``: written with ``rosbags``.

A bag here is what ``ros2 bag record -s mcap`` writes: a folder with
``metadata.yaml`` (version 9) and one ``.mcap`` file, messages in CDR under the
type's full ROS name (``geometry_msgs/msg/PoseStamped``). The message
definitions and type hashes go into the bag, so rosbag2 and MCAP readers
(Foxglove, ``ros2 bag``, ``rosbags``, ``mcap``) decode them (except
``mcap_ros2``'s decoder for service event types: it refuses the underscore in
``AddConstraint_Event``, as it does in any rosbag2 service recording). This
package's own types (``rigid_body_sim_interfaces``), the ROS simulator interface's
(``simulation_interfaces``: ``spawn_entity``'s calls, ...), and the service event types
of their services
(``<srv>_Event``, which ``ros2 bag record --all-services`` records on
``<service>/_service_event``) are registered from their definition files.
"""

from __future__ import annotations

from functools import lru_cache
import json
from pathlib import Path
from typing import Any, Optional

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import get_types_from_msg, get_typestore, Stores
from rosbags.typesys.base import Nodetype

INTERFACES = 'rigid_body_sim_interfaces'


def msgtype_name(msg: Any) -> str:
    """Return the full ROS type name of an rclpy message instance or class."""
    cls = msg if isinstance(msg, type) else type(msg)
    package = cls.__module__.split('.')[0]
    kind = 'srv' if '.srv.' in cls.__module__ else 'msg'
    return f'{package}/{kind}/{cls.__name__}'


#: The ROS simulator interface's package (its service events are recorded too).
STANDARD = 'simulation_interfaces'
#: Field types that are not messages.
PRIMITIVES = {'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16',
              'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'}


def _interface_dir(package: str = INTERFACES) -> Optional[Path]:
    """Return the folder holding a package's msg/ and srv/ definitions (None: not found)."""
    try:
        from ament_index_python.packages import get_package_share_directory
        share = Path(get_package_share_directory(package))
        if (share / 'msg').is_dir():
            return share
    except Exception:  # noqa: B902 - not installed: the source tree
        pass
    root = Path(__file__).resolve().parents[2]
    folder = root / 'interfaces' if package == INTERFACES else root / 'vendor' / package
    return folder if (folder / 'msg').is_dir() else None


def _qualified(text: str, package: str) -> str:
    """Return a definition with its package's own message types named in full."""
    lines = []
    for line in text.splitlines():
        words = line.split('#', 1)[0].split()
        if words:
            base = words[0].split('[', 1)[0].split('<=', 1)[0]
            if base not in PRIMITIVES and '/' not in base:
                line = line.replace(words[0], f'{package}/msg/{words[0]}', 1)
        lines.append(line)
    return '\n'.join(lines) + '\n'


@lru_cache(maxsize=None)
def typestore():
    """
    Return the Jazzy type store with this package's messages and service events added.

    Service ``S`` gives ``S_Request``, ``S_Response`` and ``S_Event`` (its
    ``service_msgs/ServiceEventInfo`` plus at most one request and one response):
    those of this package's services, of ``simulation_interfaces`` (its messages too)
    and of ``std_srvs/Trigger``.
    """
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for package in (INTERFACES, STANDARD):
        folder = _interface_dir(package)
        if folder is None:   # (the standard's package, where it is neither built nor here)
            continue
        for path in sorted((folder / 'msg').glob('*.msg')):
            types.update(get_types_from_msg(path.read_text(), f'{package}/msg/{path.stem}'))
        for path in sorted((folder / 'srv').glob('*.srv')):
            request, response = path.read_text().split('\n---', 1)
            types.update(_service_types(package, path.stem, _qualified(request, package),
                                        _qualified(response, package)))
    # std_srvs/Trigger (~/reset), which the Jazzy store lacks as a service.
    types.update(_service_types('std_srvs', 'Trigger', '', 'bool success\nstring message\n'))
    store.register(types)
    return store


def to_cdr(msg: Any, msgtype: str) -> bytes:
    """
    Return the CDR bytes of an rclpy message, exactly as long as its fields need.

    rclpy's ``serialize_message`` leaves uninitialized padding and, for some
    types (strings before float64 arrays), a few bytes of slack at the end, which
    strict readers (``rosbags``) refuse; the bytes written here are the canonical
    serialization of the same values.
    """
    store = typestore()
    return bytes(store.serialize_cdr(_to_store(store, msg, msgtype), msgtype))


def _to_store(store: Any, msg: Any, msgtype: str) -> Any:
    """Convert an rclpy message to the type store's class of ``msgtype``, recursively."""
    cls = store.types[msgtype]
    _, fields = store.fielddefs[msgtype]
    values = {}
    for name, (kind, detail) in fields:
        # (an empty ROS 2 message has a placeholder byte rclpy does not show)
        value = getattr(msg, name, 0)
        if kind == Nodetype.NAME:
            values[name] = _to_store(store, value, detail)
        elif kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            (inner_kind, inner), _ = detail
            if inner_kind == Nodetype.NAME:
                values[name] = [_to_store(store, v, inner) for v in value]
            elif inner[0] == 'string':
                values[name] = list(value)
            else:
                values[name] = np.asarray(value, dtype=_DTYPES[inner[0]])
        elif isinstance(value, (bytes, bytearray)):   # rclpy's byte fields
            values[name] = value[0]
        else:
            values[name] = value
    return cls(**values)


_DTYPES = {'bool': np.bool_, 'byte': np.uint8, 'char': np.uint8, 'octet': np.uint8,
           'float32': np.float32, 'float64': np.float64, 'int8': np.int8,
           'uint8': np.uint8, 'int16': np.int16, 'uint16': np.uint16, 'int32': np.int32,
           'uint32': np.uint32, 'int64': np.int64, 'uint64': np.uint64}


def _definition(msgtype: str) -> tuple[str, str]:
    """
    Return the message definition text and RIHS01 type hash stored in a bag for a type.

    A service type's definition is written from its msg twin; its hash is the one
    rosidl generated for the service (``share/<pkg>/srv/<S>.json``), which the
    twin's would not match.
    """
    store = typestore()
    if '/srv/' not in msgtype:
        return store.generate_msgdef(msgtype, ros_version=2)[0], store.hash_rihs01(msgtype)
    twin = msgtype.replace('/srv/', '/msg/')
    return store.generate_msgdef(twin, ros_version=2)[0], _service_hash(msgtype)


def _service_hash(msgtype: str) -> str:
    """Return rosidl's RIHS01 hash of a service's type (``pkg/srv/S_Event`` ...)."""
    from ament_index_python.packages import get_package_share_directory
    package, _, name = msgtype.split('/')
    service = name.rsplit('_', 1)[0]
    path = Path(get_package_share_directory(package)) / 'srv' / f'{service}.json'
    for entry in json.loads(path.read_text())['type_hashes']:
        if entry['type_name'] == msgtype:
            return entry['hash_string']
    raise KeyError(f'{path}: no type hash for {msgtype}')


def _service_types(package: str, name: str, request: str, response: str) -> dict:
    """
    Return the types ``S_Request``, ``S_Response`` and ``S_Event`` of service ``pkg/srv/S``.

    Each under its own name, to read it, and under a msg twin (``pkg/msg/S_Event``)
    from which rosbags can write a definition (it writes those of msg types only).
    """
    event = (f'service_msgs/ServiceEventInfo info\n{name}_Request[<=1] request\n'
             f'{name}_Response[<=1] response\n')
    types = {}
    for suffix, text in (('Request', request), ('Response', response), ('Event', event)):
        # (rosbags names the types of a srv folder pkg/srv/msg/Name: put them back.)
        parsed = get_types_from_msg(text, f'{package}/srv/{name}_{suffix}')
        types.update(_renamed(parsed, f'{package}/srv/msg/', f'{package}/srv/'))
        types.update(_renamed(parsed, f'{package}/srv/msg/', f'{package}/msg/'))
    return types


def _renamed(value: Any, old: str, new: str) -> Any:
    """Replace the prefix ``old`` by ``new`` in every type name of a parsed definition."""
    if isinstance(value, str):
        return new + value[len(old):] if value.startswith(old) else value
    if isinstance(value, dict):
        return {_renamed(k, old, new): _renamed(v, old, new) for k, v in value.items()}
    if isinstance(value, tuple):
        return tuple(_renamed(v, old, new) for v in value)
    if isinstance(value, list):
        return [_renamed(v, old, new) for v in value]
    return value


class BagWriter:
    """
    Write a rosbag2 bag (MCAP storage) of rclpy messages.

    Parameters
    ----------
    path : Path
        The bag folder to create; it must not exist.
    custom_data : dict, optional
        Strings stored in ``metadata.yaml`` under ``custom_data``.

    """

    def __init__(self, path: Path, custom_data: Optional[dict] = None) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise FileExistsError(f'{self.path}: exists already; choose a new bag folder')
        self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        for key, value in (custom_data or {}).items():
            self._writer.set_custom_data(key, value)
        self._connections: dict = {}
        self.counts: dict = {}

    def add_topic(self, topic: str, msgtype: str) -> None:
        """Declare a topic and its type (``pkg/msg/Name``); done on first write too."""
        if topic not in self._connections:
            msgdef, rihs01 = _definition(msgtype)
            self._connections[topic] = self._writer.add_connection(topic, msgtype,
                                                                   msgdef=msgdef,
                                                                   rihs01=rihs01)
            self.counts[topic] = 0

    def write(self, topic: str, stamp_ns: int, data: bytes, msgtype: str) -> None:
        """Write serialized CDR ``data`` at ``stamp_ns`` (bag time, ns)."""
        self.add_topic(topic, msgtype)
        self._writer.write(self._connections[topic], stamp_ns, data)
        self.counts[topic] += 1

    def write_msg(self, topic: str, stamp_ns: int, msg: Any) -> None:
        """Serialize an rclpy message (canonical CDR, see :func:`to_cdr`) at ``stamp_ns``."""
        msgtype = msgtype_name(msg)
        self.write(topic, stamp_ns, to_cdr(msg, msgtype), msgtype)

    def close(self) -> None:
        """Finish the MCAP file and write ``metadata.yaml``."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def __enter__(self) -> 'BagWriter':
        """Return self."""
        return self

    def __exit__(self, *exc: Any) -> None:
        """Close the bag, also on an error (what was written stays readable)."""
        self.close()
