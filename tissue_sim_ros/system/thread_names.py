"""Our threads' names where the operating system shows them: top -H, ps -L, perf, /proc.

Python 3.12 names a ``threading.Thread`` for Python only; every thread of the node reads
``tissue_sim_node`` in ``/proc/PID/task/TID/comm``, so a per-thread CPU figure (node-bench's
``thread_cpu_pct``, or ``top -H``) cannot tell the engine from the recorder. Each of our
long-lived threads calls :func:`name_os_thread` first. Linux keeps 15 bytes of a name: the
``tissue_sim-`` prefix of ours becomes ``ts-`` (``ts-engine``). Elsewhere this does nothing.
"""
from __future__ import annotations

import ctypes
import sys
import threading

__all__ = ['name_os_thread', 'os_thread_name']

_PR_SET_NAME = 15          # prctl(2)
_MAX_BYTES = 15            # TASK_COMM_LEN - 1


def os_thread_name(name: str) -> str:
    """The name the OS is given for a thread named ``name`` (shortened to what Linux keeps)."""
    if name.startswith('tissue_sim-'):
        name = 'ts-' + name[len('tissue_sim-'):]
    return name.encode('utf-8')[:_MAX_BYTES].decode('utf-8', 'ignore')


def name_os_thread(name: str | None = None) -> None:
    """Give the calling thread its Python name (or ``name``) at the OS level; Linux only."""
    if not sys.platform.startswith('linux'):
        return
    text = os_thread_name(threading.current_thread().name if name is None else name)
    # the process's own symbols, libc's among them (ctypes.util.find_library would run ldconfig)
    ctypes.CDLL(None).prctl(_PR_SET_NAME, ctypes.c_char_p(text.encode('utf-8')), 0, 0, 0)
