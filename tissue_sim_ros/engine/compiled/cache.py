"""First start: compile the numba kernels where the user can see it, on two cores.

numba compiles each kernel at its first call and keeps the machine code in its on-disk cache
(``NUMBA_CACHE_DIR``; ``tissue_sim_ros.system.numba_threads`` points it at a per-user directory). A fresh
install has no cache, so the first scene compiles everything before its first step; later starts
load the code in about a second. This module

* reports every compile of one of the package's kernels on stderr, a line when it starts and one
  with its duration, so a first start says what it is doing; nothing is printed when the code
  comes from the cache;
* compiles an element pass that the cache lacks in a separate process and loads it from the
  cache (``call_compiled_apart``), so every process runs the cached machine code. A pass compiled
  in the process that runs it calls its thread pass as LLVM optimized it alone, not the copy
  optimized again with the kernel, which the cache holds: its lane loops not vectorized (the full
  model 4.6 instead of 2.7 ms per evaluation, 98304 tetrahedra, one thread) and forces a few
  units in the last place apart from every later start's;
* meanwhile, on a first start, compiles what a scene needs next in a second process: when a
  model's first kernels compile (``start_up``), the helper runs ``warm_up`` (the needle's
  kernels, the solver's, the linear pass of the critical time step) into the same cache, and the
  first process waits for it (``wait_for_helper``) before it runs those, which then load.

Figures (default scene, 2 cores): tissue-sim bench cold-start.

Two processes must not compile different signatures of one function at the same time (numba's
index of a function's cached signatures is one file: one entry can be lost, or point at the other
process's code). Each model's element pass has its own index (``kernels.element_kernel``), the
parts compiled per model are not cached on their own, and what both processes compile is the same
(the same signature, the same code).

TISSUE_SIM_ROS_COMPILE_PROCESSES=0 compiles everything in the process itself, to measure what that
costs: that process then runs the slower element passes described above (later ones load them).
"""
import atexit
import os
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager

from numba.core import config, event

from tissue_sim_ros.system.child_env import importing_from
from tissue_sim_ros.system.paths import SOURCE_ROOT

PREFIX = 'tissue_sim_ros:'
QUIET_ENV = 'TISSUE_SIM_ROS_COMPILE_PROCESS'     # set in the processes started here
PROCESSES_ENV = 'TISSUE_SIM_ROS_COMPILE_PROCESSES'
TIMEOUT_S = 900.0
HEARTBEAT_S = 10.0
_PACKAGE_ROOT = SOURCE_ROOT

#: element passes this process has run (their code is loaded)
LOADED = set()


def cache_dir():
    """Where numba caches compiled kernels: NUMBA_CACHE_DIR, else beside the sources."""
    return config.CACHE_DIR or '__pycache__ beside the sources'


def _say(text):
    print(f'{PREFIX} {text}', file=sys.stderr, flush=True)


def _label(dispatcher):
    """A kernel's name for the progress lines, e.g. 'kernels.reduce_buffers' or 'element pass,
    geometric_physical_viscous model'."""
    name = dispatcher.py_func.__qualname__
    if '<locals>.kernel_' in name:
        return f"element pass, {name.split('<locals>.kernel_')[1]} model"
    return f"{dispatcher.py_func.__module__.rsplit('.', 1)[-1]}.{name}"


def _in_compile_process():
    return os.environ.get(QUIET_ENV) == '1'


def _processes_allowed():
    return not _in_compile_process() and os.environ.get(PROCESSES_ENV, '1') != '0' and bool(sys.executable)


class _NotCached(Exception):
    """The probed kernel is not in the cache (raised instead of compiling it here)."""


class _State:
    announced = False
    in_start_up = 0            # depth of start_up() contexts
    refuse = None              # the dispatcher call_compiled_apart is probing
    helper = None              # the helper's _Process while it runs
    helper_tried = False


class _Reporter(event.Listener):
    """Prints the package's top-level compiles (nested ones are part of them); refuses to compile
    the kernel that call_compiled_apart probes."""

    def __init__(self):
        self.depth = 0
        self.started = None

    def on_start(self, ev):
        # numba calls on_end for every on_start, one that raises included (trigger_event pushes
        # the end before it starts), so the depth is counted before a refusal: counted after it,
        # a refusal would leave the depth at -1 and the next probed kernel would compile here unseen.
        dispatcher = ev.data['dispatcher']
        self.depth += 1
        if self.depth != 1:
            return
        self.started = None
        if dispatcher is _State.refuse:
            _announce()
            if _State.in_start_up:
                _start_helper()
            raise _NotCached
        module = getattr(getattr(dispatcher, 'py_func', None), '__module__', None) or ''
        if not module.startswith('tissue_sim_ros'):
            return
        _announce()
        if _State.in_start_up:
            _start_helper()
        if not _in_compile_process():
            _say(f'compiling {_label(dispatcher)} ...')
        self.started = (time.monotonic(), dispatcher)

    def on_end(self, ev):
        self.depth -= 1
        if self.depth == 0 and self.started is not None:
            start, dispatcher = self.started
            self.started = None
            if not _in_compile_process():
                _say(f'compiled {_label(dispatcher)} in {time.monotonic() - start:.1f} s')


REPORTER = _Reporter()
event.register('numba:compile', REPORTER)


def _announce():
    if not _State.announced and not _in_compile_process():
        _State.announced = True
        _say(f'compiling numba kernels: first start only, cached in {cache_dir()} '
             '(later starts load them in seconds)')


class _Process:
    """A quiet Python process that compiles into the shared cache."""

    def __init__(self, what, code):
        self.what = what
        self.started = time.monotonic()
        env = importing_from(_PACKAGE_ROOT)
        env[QUIET_ENV] = '1'
        env['NUMBA_NUM_THREADS'] = '1'      # its tiny models need no thread pool spinning beside us
        self.log = tempfile.TemporaryFile()
        self.popen = subprocess.Popen([sys.executable, '-c', code], env=env, stdin=subprocess.DEVNULL,
                                      stdout=self.log, stderr=subprocess.STDOUT)

    def wait(self):
        """Wait (saying so every HEARTBEAT_S); True when it compiled without error."""
        try:
            while True:
                try:
                    self.popen.wait(timeout=HEARTBEAT_S)
                    break
                except subprocess.TimeoutExpired:
                    elapsed = time.monotonic() - self.started
                    if elapsed > TIMEOUT_S:
                        self.stop()
                        break
                    _say(f'still compiling {self.what} ({elapsed:.0f} s so far)')
        except BaseException:
            self.stop()
            raise
        elapsed = time.monotonic() - self.started
        ok = self.popen.returncode == 0
        if ok:
            _say(f'compiled {self.what} in {elapsed:.1f} s')
        else:
            self.log.seek(0)
            tail = self.log.read().decode(errors='replace').strip().splitlines()[-3:]
            _say(f'compiling {self.what} in a separate process failed (status {self.popen.returncode}): '
                 f"{' / '.join(tail) or 'no output'}; compiling here instead")
        self.log.close()
        return ok

    def stop(self):
        if self.popen.poll() is None:
            self.popen.kill()
            self.popen.wait()


def _start_helper():
    """On a first start, the helper process (once per process, and with a second core for it)."""
    if _State.helper_tried or not _processes_allowed():
        return
    _State.helper_tried = True
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    if cores < 2:
        return
    what = 'the needle, solver and linear kernels'
    try:
        _State.helper = _Process(what, 'from tissue_sim_ros.engine.warm_up import warm_up; warm_up()')
    except OSError as exc:
        _say(f'could not start a second compile process ({exc}); compiling here')
        return
    _say(f'compiling {what} in a second process')


def wait_for_helper():
    """Wait for the helper process, if one runs, before kernels it compiles are used (else this
    process would compile them too). Returns at once when none runs."""
    helper, _State.helper = _State.helper, None
    if helper is not None:
        helper.wait()


@contextmanager
def start_up():
    """Around a model's first kernel calls: a compile inside starts the helper process."""
    _State.in_start_up += 1
    try:
        yield
    finally:
        _State.in_start_up -= 1


def _from_cache(kernel, args, precision):
    """(True, ``kernel(*args)``) when the kernel loads from the cache; (False, None) when it would
    have to be compiled here (the reporter refuses that compile)."""
    _State.refuse = kernel
    try:
        result = kernel(*args)
    except _NotCached:
        return False, None
    finally:
        _State.refuse = None
    LOADED.add((kernel, precision))
    return True, result


def call_compiled_apart(kernel, args, precision, what, compile_code, *, helper_compiles=False):
    """``kernel(*args)`` for an element pass not yet run in this process: loaded from the cache,
    or, when the cache lacks it, compiled first in a separate process (then loaded).

    ``precision``: the pass's constants and arithmetic (another signature of the same pass);
    ``what``: its name in the progress lines; ``compile_code``: the Python statement that compiles
    it in that process (the model's module names its own entry, so this module imports none);
    ``helper_compiles``: the helper process started by :func:`start_up` compiles this one (the
    linear pass): wait for it instead of starting another."""
    if _processes_allowed():
        found, result = _from_cache(kernel, args, precision)
        if found:
            return result
        if helper_compiles and _State.helper is not None:
            wait_for_helper()
        else:
            _say(f'compiling {what} in a separate process ...')
            _Process(what, compile_code).wait()
    result = kernel(*args)           # loads it now, or compiles it here if that process failed
    LOADED.add((kernel, precision))
    return result


def _stop_helper():
    if _State.helper is not None:
        _State.helper.stop()


atexit.register(_stop_helper)
