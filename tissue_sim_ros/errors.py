"""The package's errors: one family, so that a caller can tell bad input from a bug.

Every error names what it refuses: the field (a scene key such as ``regions[0].poisson_ratio``,
a parameter, a column, a file) and the value, then what was expected. The command line turns
any :class:`TissueSimError` into one line on stderr and exit status 2; the node logs it and
keeps running.

::

    TissueSimError
      InputError (also a ValueError)          bad input, refused where it enters
        SceneError                            a scene file or scene key
        MeshError                             a mesh (degenerate elements, bad indices, a file)
        MaterialError                         a material built directly with impossible values
        PoseError                             a needle pose (NaN, not unit, a jump, a wrong frame)
        DataError                             a load-cell recording (file, column, row)
        DataSpecError                         a data description (its keys)
        UnitError                             a unit no table knows
        LogError                              an MCAP log
          NotAnMcapError, TruncatedLogError, RecoverError, ReplayError
        ConfigError                           a node parameter
        CommandLineError                      what only the command line sees
      SimulationDiverged (also a RuntimeError) a run that cannot go on
      WallTimeExceeded (also a RuntimeError)  a run stopped at the wall-time limit it was given
      NodeProcessError (also a RuntimeError)  a node process that would not start or answer
      BenchError (also a RuntimeError)        a benchmark that cannot run, or a run of it failed
"""

__all__ = [
    'BenchError', 'CommandLineError', 'ConfigError', 'DataError', 'DataSpecError', 'InputError', 'LogError',
    'MaterialError', 'MeshError', 'NodeProcessError', 'NotAnMcapError', 'PoseError', 'RecoverError',
    'ReplayError', 'SceneError', 'SimulationDiverged', 'TissueSimError', 'TruncatedLogError',
    'UnitError', 'WallTimeExceeded',
]


class TissueSimError(Exception):
    """Base of every error this package raises on purpose."""


class InputError(TissueSimError, ValueError):
    """Bad input, refused where it enters; the message names the field and the value."""


class SceneError(InputError):
    """A scene file or value the engine refuses; names the key and the value."""


class MeshError(InputError):
    """A mesh that cannot be simulated; names the offending elements or nodes."""


class MaterialError(InputError):
    """Material parameters outside their physical range (a Material built directly)."""


class PoseError(InputError):
    """A needle pose the engine refuses (non-finite, not a unit quaternion, a jump, a frame)."""

    def __init__(self, field_name, value, expected):
        self.field = field_name
        self.value = value
        self.expected = expected
        super().__init__(f'{field_name} = {value!r}: {expected}')

    def __reduce__(self):       # a prediction worker's refusal reaches the node whole
        return type(self), (self.field, self.value, self.expected)


class DataError(InputError):
    """A recording that cannot be imported; the message names the file and, where it applies,
    the column (or topic) and the 1-based row (the file's line, or the message's index on its
    topic)."""

    def __init__(self, file, problem: str, *, column=None, row: int | None = None):
        self.file = str(file)
        self.problem = problem
        self.column = column
        self.row = row
        where = ''.join([f', column {column!r}' if column is not None else '',
                         f', row {row}' if row is not None else ''])
        super().__init__(f'{self.file}{where}: {problem}')

    def __reduce__(self):
        return _rebuild_data_error, (type(self), self.file, self.problem, self.column, self.row)


class DataSpecError(InputError):
    """A data description (a study's files described once) that cannot be used; names the key."""


class UnitError(InputError):
    """A unit that no table knows for a quantity; names the quantity, the unit and the known ones."""


class LogError(InputError):
    """An MCAP log that cannot be read, repaired or replayed as asked."""


class NotAnMcapError(LogError):
    """A file that does not start as an MCAP file."""


class TruncatedLogError(LogError):
    """A log cut short (a hard kill): ``tissue-sim recover`` repairs it."""


class RecoverError(LogError):
    """A log ``recover`` cannot repair; says why."""


class ReplayError(LogError):
    """A log that cannot be replayed (no engine trace, no scene, a gap)."""


class ConfigError(InputError):
    """A node parameter refused at start; names the parameter and its value."""


class CommandLineError(InputError):
    """Bad input only the command line can see (an unknown name in a list option)."""


class SimulationDiverged(TissueSimError, RuntimeError):
    """The watchdog stopped a run (non-finite state, energy gained without input, inverted
    elements): what diverged, at which step, with which time step against the critical one."""

    def __init__(self, reason, step, time, time_step, critical_time_step):
        self.reason = reason
        self.step = step
        self.time = time
        self.time_step = time_step
        self.critical_time_step = critical_time_step
        super().__init__(
            f'simulation diverged at step {step} (t = {time:.6g} s): {reason}; time step '
            f'{time_step:.4g} s against the estimated critical step {critical_time_step:.4g} s '
            f'({time_step / critical_time_step:.2f}x)')

    def __reduce__(self):       # a worker process's divergence reaches its caller whole
        return type(self), (self.reason, self.step, self.time, self.time_step, self.critical_time_step)


class WallTimeExceeded(TissueSimError, RuntimeError):
    """A run stopped at the wall-time limit it was given: how far it got."""

    def __init__(self, limit_s, simulated_s):
        self.limit_s = limit_s
        self.simulated_s = simulated_s
        super().__init__(f'stopped at its wall-time limit of {limit_s:g} s, {simulated_s:.3g} s simulated')

    def __reduce__(self):
        return type(self), (self.limit_s, self.simulated_s)


class NodeProcessError(TissueSimError, RuntimeError):
    """A node process that did not start, did not answer, or ended with an error."""


class BenchError(TissueSimError, RuntimeError):
    """A benchmark that cannot run (a revision that is not there) or one of whose runs failed;
    names the run and where its output is."""


def _rebuild_data_error(cls, file, problem, column, row):
    return cls(file, problem, column=column, row=row)
