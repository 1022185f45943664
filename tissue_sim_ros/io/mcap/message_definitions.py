"""ROS 2 type names and message definitions, read from the installed .msg/.srv files.

The one home for parsing a ROS type name (``pkg/msg/Type``, ``pkg/srv/Type``, ``pkg/Type``):
the MCAP writer names schemas with it and ``ros.messages.from_yaml`` finds message classes with
it.
The ``ros2msg`` schema text of a type (:func:`message_definition`) is its .msg followed, for each
dependency (depth first, field order, each once), by a line of 80 ``=``, ``MSG: pkg/Type`` and
that type's .msg, as rosbag2 writes it. No rclpy: the files are found on disk.
"""
from __future__ import annotations

import importlib.util
import os
import re
import sys
from functools import lru_cache
from pathlib import Path
from typing import NamedTuple

__all__ = ['RosTypeName', 'parse_type_name', 'schema_name', 'msg_file', 'message_definition',
           'SCHEMA_ENCODING']

#: MCAP schema encoding of the text :func:`message_definition` returns.
SCHEMA_ENCODING = 'ros2msg'
_SEPARATOR = '=' * 80
_PRIMITIVES = frozenset(
    'bool byte char float32 float64 int8 uint8 int16 uint16 int32 uint32 int64 uint64 '
    'string wstring'.split())
_TYPE_PART = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')


class RosTypeName(NamedTuple):
    """The parts of a ROS type name: ``package``, ``interface`` ('msg' or 'srv'), ``name``."""

    package: str
    interface: str
    name: str


def parse_type_name(type_name: str, *, short_form: bool = True) -> RosTypeName:
    """Split 'pkg/msg/Type' or 'pkg/srv/Type' (and, if ``short_form``, 'pkg/Type', read as msg;
    if not, also 'pkg/action/Type').

    Each part must be an identifier; anything else raises ValueError naming the value.
    """
    parts = str(type_name).split('/')
    if len(parts) == 3 and (parts[1] in ('msg', 'srv') or (parts[1] == 'action' and not short_form)):
        parsed = RosTypeName(parts[0], parts[1], parts[2])
    elif len(parts) == 2 and short_form:
        parsed = RosTypeName(parts[0], 'msg', parts[1])
    else:
        parsed = None
    if parsed is None or not (_TYPE_PART.match(parsed.package) and _TYPE_PART.match(parsed.name)):
        forms = '"pkg/msg/Type" or "pkg/srv/Type"' + (' (or "pkg/Type")' if short_form
                                                      else ' (or "pkg/action/Type")')
        raise ValueError(f'type_name: {type_name!r}; expected {forms}')
    return parsed


def _split_type(type_name: str) -> tuple[str, str]:
    """('geometry_msgs', 'Wrench') from 'geometry_msgs/msg/Wrench' or 'geometry_msgs/Wrench';
    ('std_srvs', 'Trigger_Event') from 'std_srvs/srv/Trigger_Event'."""
    parsed = parse_type_name(type_name)
    return parsed.package, parsed.name


def schema_name(type_name: str) -> str:
    """The MCAP schema name of a type: 'pkg/msg/Type', or 'pkg/srv/Type_Event' (and _Request,
    _Response) for the messages rosidl generates from a service, as rosbag2 names them."""
    pkg, name = _split_type(type_name)
    return f'{pkg}/{"srv" if _service_part(pkg, name) is not None else "msg"}/{name}'


def _share_dirs(pkg: str) -> list[Path]:
    """Candidate ``share`` directories for a package, most specific first.

    1. the install prefix of the importable Python package ``pkg`` (located with
       ``importlib.util.find_spec``, which does not import it): the .msg that matches the module
       rclpy serializes with, in a virtual environment (``<venv>/share``) as in
       ``/opt/ros/<distro>`` or a colcon ``install/<pkg>`` tree;
    2. every prefix of ``AMENT_PREFIX_PATH`` (a sourced ROS installation or workspace);
    3. ``sys.prefix/share`` (the environment this interpreter runs in).
    """
    dirs: list[Path] = []
    try:
        spec = importlib.util.find_spec(pkg)
    except (ImportError, ValueError):
        spec = None
    if spec is not None:
        locations = list(spec.submodule_search_locations or [])
        if not locations and spec.origin:
            locations = [str(Path(spec.origin).parent)]
        for loc in locations:
            # <prefix>/lib/pythonX.Y/site-packages/<pkg> (or local/lib/..., dist-packages)
            for parent in list(Path(loc).resolve().parents)[:6]:
                dirs.append(parent / 'share')
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            dirs.append(Path(prefix) / 'share')
    dirs.append(Path(sys.prefix) / 'share')
    return list(dict.fromkeys(dirs))  # each once, first place kept


def msg_file(type_name: str) -> Path:
    """Path of the installed ``share/<pkg>/msg/<Type>.msg`` of a message type."""
    pkg, name = _split_type(type_name)
    tried = []
    for share in _share_dirs(pkg):
        candidate = share / pkg / 'msg' / f'{name}.msg'
        if candidate.is_file():
            return candidate
        tried.append(str(candidate.parent))
    raise FileNotFoundError(
        f'{pkg}/msg/{name}.msg not found; looked in {tried[:8]} (install the message package '
        'or source its workspace so that AMENT_PREFIX_PATH names it)')


def _dependencies(pkg: str, text: str) -> list[tuple[str, str]]:
    """Non-primitive field types of a .msg, in field order, each once."""
    out: list[tuple[str, str]] = []
    for line in text.splitlines():
        code = line.split('#', 1)[0].strip()
        if not code:
            continue
        type_token = code.split()[0]
        base = type_token.split('[', 1)[0].split('<=', 1)[0]
        if base in _PRIMITIVES:
            continue
        parts = base.split('/')
        if len(parts) == 1:
            dep = (pkg, parts[0])  # a bare name is a type of the same package
        else:
            dep = _split_type(base)
        if dep not in out:
            out.append(dep)
    return out


@lru_cache(maxsize=None)
def _service_part(pkg: str, name: str) -> str | None:
    """The .msg text of ``<Service>_Request``, ``_Response`` or ``_Event``, as rosidl generates
    them from ``share/<pkg>/srv/<Service>.srv`` (request above the ``---`` line, response below;
    a part without fields gets rosidl's placeholder field); None for other names."""
    suffix = next((s for s in ('_Request', '_Response', '_Event') if name.endswith(s)), None)
    if suffix is None:
        return None
    service = name[:-len(suffix)]
    path = next((d / pkg / 'srv' / f'{service}.srv' for d in _share_dirs(pkg)
                 if (d / pkg / 'srv' / f'{service}.srv').is_file()), None)
    if path is None:
        return None
    if suffix == '_Event':
        return (f'service_msgs/ServiceEventInfo info\n{pkg}/{service}_Request[<=1] request\n'
                f'{pkg}/{service}_Response[<=1] response\n')
    request, _, response = _split_service(path.read_text(encoding='utf-8'))
    text = (request if suffix == '_Request' else response).strip('\n')
    has_fields = any(line.split('#', 1)[0].strip() for line in text.splitlines())
    return (text if has_fields else 'uint8 structure_needs_at_least_one_member') + '\n'


def _split_service(text: str) -> tuple[str, str, str]:
    """(request, '---', response) of a .srv file."""
    parts = re.split(r'^---[ \t]*$', text, maxsplit=1, flags=re.MULTILINE)
    return parts[0], '---', parts[1] if len(parts) > 1 else ''


@lru_cache(maxsize=None)
def _msg_text(pkg: str, name: str) -> str:
    service = _service_part(pkg, name)
    if service is not None:
        return service
    return msg_file(f'{pkg}/{name}').read_text(encoding='utf-8').rstrip() + '\n'


@lru_cache(maxsize=None)
def message_definition(type_name: str) -> str:
    """The ``ros2msg`` schema text of a type: its .msg, then each dependency once.

    Dependencies are visited depth first in field order (as rosbag2's message definition cache
    does); each is introduced by a line of 80 '=' and ``MSG: pkg/Type``.
    """
    root = _split_type(type_name)
    parts = [_msg_text(*root)]
    seen = {root}

    def visit(pkg: str, text: str) -> None:
        for dep in _dependencies(pkg, text):
            if dep in seen:
                continue
            seen.add(dep)
            dep_text = _msg_text(*dep)
            parts.append(f'{_SEPARATOR}\nMSG: {dep[0]}/{dep[1]}\n{dep_text}')
            visit(dep[0], dep_text)

    visit(root[0], parts[0])
    return ''.join(parts)
