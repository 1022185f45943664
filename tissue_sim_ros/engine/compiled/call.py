"""Compiled functions called by address from compiled code, their types checked for nothing a call.

A slice of substeps (:mod:`.substeps`) calls the force kernel, the node update and the
needle's step as the machine code a Python call of each runs (compiled into the slice, the
element pass would be optimized again with it: :mod:`.cache`). Handed over as numba first-class
function values, they would be paid for in Python at each call of the slice: typing each value
and unboxing it (``numba.experimental.function_type``: ``_get_wrapper_address`` and
``_get_jit_address`` per value) costs about twice what the slice's ~100 arrays cost.

Here the address of a function's C wrapper (the one a first-class function value holds) is a
plain integer, :func:`compiled_address`, and :func:`call_compiled` calls it with a tuple's
values, as numba's own first-class call does (``lowering.__call_first_class_function_pointer``: the
C wrapper's value types in and out). An address says nothing of its function's types, so
:func:`compiled_address` also returns a check of them (a hash of the argument and return types'
names) and :func:`signature_check` is the same hash of the types a call site passes, a constant
compiled into the caller: the caller compares the two before any call, and a function compiled
for other types (an array whose layout or dtype changed) is refused instead of called.
"""
import hashlib

from llvmlite import ir
from numba import typeof, types
from numba.extending import intrinsic

__all__ = ['compiled_address', 'signature_check', 'call_compiled']


def _check_of(argument_types, return_type) -> int:
    """A 62-bit hash of the types' names (the same in every process: numba's cache keeps the
    constants compiled from it)."""
    text = repr((tuple(str(t) for t in argument_types), str(return_type)))
    return int.from_bytes(hashlib.blake2b(text.encode(), digest_size=8).digest(), 'little') >> 2


def compiled_address(dispatcher, args, return_type) -> tuple[int, int]:
    """(address of the C wrapper of ``dispatcher``'s code for arguments like ``args``, the check of
    its types), compiled or loaded from numba's cache if need be. Raises TypeError when that code
    does not return ``return_type``. The address stays valid while the dispatcher lives."""
    argument_types = tuple(typeof(a) for a in args)
    dispatcher.compile(argument_types)
    signature = dispatcher.overloads[argument_types].signature
    if signature.return_type != return_type:
        raise TypeError(f'{dispatcher.py_func.__qualname__} returns {signature.return_type}, expected {return_type}')
    compiled = dispatcher.get_compile_result(signature)
    address = compiled.library.get_pointer_to_function(compiled.fndesc.llvm_cfunc_wrapper_name)
    if not address:        # numba made no C wrapper for these types
        raise TypeError(f'{dispatcher.py_func.__qualname__} has no C wrapper for {signature}')
    return address, _check_of(signature.args, signature.return_type)


def _plain(t):
    """``t`` without literal values (a constant typed in a caller: ``0`` is ``int64`` here)."""
    if isinstance(t, types.BaseTuple):
        return types.Tuple(tuple(_plain(m) for m in t.types))
    return types.unliteral(t)


def _flat_types(leading, arguments):
    return tuple(_plain(t) for t in tuple(leading.types) + tuple(arguments.types))


def _return_type(returns):
    return types.none if isinstance(returns, types.NoneType) else _plain(returns)


@intrinsic
def signature_check(typingctx, leading, arguments, returns):
    """The check :func:`compiled_address` gives a function taking ``leading + arguments`` (two
    tuples) and returning the type of ``returns`` (a value of that type, or None), as a constant."""
    if not (isinstance(leading, types.BaseTuple) and isinstance(arguments, types.BaseTuple)):
        return None
    value = _check_of(_flat_types(leading, arguments), _return_type(returns))

    def codegen(context, builder, signature, args):
        return ir.Constant(ir.IntType(64), value)
    return types.int64(leading, arguments, returns), codegen


@intrinsic
def call_compiled(typingctx, address, leading, arguments, returns):
    """Call the C wrapper at ``address`` with the values of ``leading`` and of ``arguments`` (two
    tuples), returning the type of ``returns`` (a value of that type, or None). The caller has
    compared the function's check with :func:`signature_check` of the same types."""
    if not (isinstance(address, types.Integer) and isinstance(leading, types.BaseTuple)
            and isinstance(arguments, types.BaseTuple)):
        return None
    return_type = _return_type(returns)

    def codegen(context, builder, signature, args):
        values = [builder.extract_value(args[1], i) for i in range(len(leading))]
        values += [builder.extract_value(args[2], i) for i in range(len(arguments))]
        function_type = ir.FunctionType(context.get_value_type(return_type),
                                        [context.get_value_type(t) for t in _flat_types(leading, arguments)])
        function = builder.inttoptr(args[0], function_type.as_pointer())
        return builder.call(function, values)
    return return_type(address, leading, arguments, returns), codegen
