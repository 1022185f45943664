"""ROS 2 messages from YAML/dicts (the ``msg_examples/`` files), without rosidl_runtime_py.

``rosidl_runtime_py.set_message_fields`` is not among the PyPI wheels of Jazzy, so this is the
small part of it the examples need: nested messages, sequences of messages, primitive arrays,
``byte`` fields given as integers. Unknown fields and wrong values are refused with the dotted
field path.

Example file layout (see ``msg_examples/README.md``)::

    topic: needle/pose              # or  service: ~/reset, or  action: ~/predict_path
    type: geometry_msgs/msg/PoseStamped
    direction: in                   # in | out
    message: {header: ..., pose: ...}        # services: request, response; actions: goal, feedback, result
"""
from __future__ import annotations

import importlib
from pathlib import Path

import yaml

from tissue_sim_ros.io.mcap.message_definitions import parse_type_name

__all__ = ['message_type', 'message_from_dict', 'load_example']


def message_type(type_name: str, part: str | None = None):
    """The Python class of 'pkg/msg/Type', of a service's Request/Response ('pkg/srv/Type') or of an
    action's Goal/Result/Feedback ('pkg/action/Type')."""
    try:
        parsed = parse_type_name(type_name, short_form=False)
    except ValueError:
        raise ValueError(f'type: {type_name!r}; expected pkg/msg/Type or pkg/srv/Type') from None
    module = importlib.import_module(f'{parsed.package}.{parsed.interface}')
    cls = getattr(module, parsed.name)
    parts = {'srv': ('Request', 'Response'), 'action': ('Goal', 'Result', 'Feedback')}.get(parsed.interface)
    if parts is not None:
        if part not in parts:
            raise ValueError(f'{type_name}: needs a part, one of {list(parts)}')
        cls = getattr(cls, part)
    return cls


def _namespaced_class(slot):
    return getattr(importlib.import_module('.'.join(slot.namespaces)), slot.name)


_INTEGER_TYPES = {'int8', 'uint8', 'int16', 'uint16', 'int32', 'uint32', 'int64', 'uint64', 'char'}


def _check_plain(slot, value, where: str) -> None:
    """Type checks the generated setters leave out (their asserts are off unless asked for)."""
    from rosidl_parser.definition import AbstractNestedType, AbstractString, BasicType
    if isinstance(slot, AbstractNestedType):
        if not isinstance(value, (list, tuple)):
            raise ValueError(f'{where}: {value!r}; expected a list')
        for i, item in enumerate(value):
            _check_plain(slot.value_type, item, f'{where}[{i}]')
        return
    if isinstance(slot, AbstractString):
        ok = isinstance(value, str)
        expected = 'a string'
    elif isinstance(slot, BasicType) and slot.typename == 'boolean':
        ok, expected = isinstance(value, bool), 'true or false'
    elif isinstance(slot, BasicType) and slot.typename in _INTEGER_TYPES:
        ok = isinstance(value, int) and not isinstance(value, bool)
        expected = f'an integer ({slot.typename})'
    elif isinstance(slot, BasicType) and slot.typename in ('float', 'double'):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        expected = f'a number ({slot.typename})'
    else:
        return
    if not ok:
        raise ValueError(f'{where}: {value!r}; expected {expected}')


def message_from_dict(cls, data, path: str = ''):
    """An instance of message class ``cls`` with the fields in ``data`` (others default)."""
    from rosidl_parser.definition import AbstractNestedType, BasicType, NamespacedType
    msg = cls()
    if data is None:
        return msg
    if not isinstance(data, dict):
        raise ValueError(f'{path or cls.__name__}: {data!r}; expected a mapping of fields')
    fields = list(cls.get_fields_and_field_types())
    slots = dict(zip(fields, cls.SLOT_TYPES))
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ValueError(f'{path or cls.__name__}: unknown fields {unknown}; '
                         f'{cls.__name__} has {fields}')
    for name, value in data.items():
        where = f'{path}.{name}' if path else name
        slot = slots[name]
        try:
            if isinstance(slot, NamespacedType):
                value = message_from_dict(_namespaced_class(slot), value, where)
            elif isinstance(slot, AbstractNestedType) and isinstance(slot.value_type, NamespacedType):
                item_cls = _namespaced_class(slot.value_type)
                value = [message_from_dict(item_cls, v, f'{where}[{i}]')
                         for i, v in enumerate(value or [])]
            elif isinstance(slot, BasicType) and slot.typename == 'octet' and isinstance(value, int):
                value = bytes((value,))
            else:
                _check_plain(slot, value, where)
            setattr(msg, name, value)
        except (AssertionError, TypeError, ValueError) as exc:
            if str(exc).startswith(where):
                raise
            raise ValueError(f'{where}: {value!r} refused by {cls.__name__}: {exc}') from None
    return msg


def load_example(path) -> dict:
    """Read one example file; returns its keys plus ``messages``: {role: message instance}.

    Roles: 'message' for a topic, 'request' and 'response' for a service, 'goal', 'feedback' and
    'result' for an action.
    """
    doc = yaml.safe_load(Path(path).read_text())
    if not isinstance(doc, dict) or 'type' not in doc:
        raise ValueError(f'{path}: expected a mapping with type and message (or request/response)')
    out = dict(doc)
    if '/action/' in doc['type']:
        out['messages'] = {role: message_from_dict(message_type(doc['type'], role.capitalize()),
                                                   doc.get(role))
                           for role in ('goal', 'feedback', 'result')}
    elif '/srv/' in doc['type']:
        out['messages'] = {
            'request': message_from_dict(message_type(doc['type'], 'Request'), doc.get('request')),
            'response': message_from_dict(message_type(doc['type'], 'Response'),
                                          doc.get('response'))}
    else:
        out['messages'] = {'message': message_from_dict(message_type(doc['type']),
                                                        doc.get('message'))}
    return out
