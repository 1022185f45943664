"""The element pass's gather and scatter for a whole block of lanes, written as LLVM vector code.

The element pass (kernels.py) does its arithmetic on a block of BLOCK = 8 elements at once, field k
of lane j at k * 8 + j of a work row. Moving node values in and forces out goes through memory a
scalar at a time: per element 24 loads, 18 subtractions and 18 stores for the displacement and
velocity differences, and 12 read-modify-writes for the forces. numba leaves those loops scalar
(the loads are indirect: LLVM vectorizes them only with hardware gathers, which it does not pick
here, and which are slower than scalar loads here even when written by hand).

Written here instead as vector code on each node's row: one load brings a node's displacement and
velocity ([ux uy uz 0 vx vy vz 0], the ``node_state`` rows ``pack_node_state`` fills, in the
model's precision), the differences are taken a row at a time, and an 8 x 8 transpose (three
stages of shuffles, which LLVM lowers to the target's permutes) turns the 8 lanes' rows into the
work row's fields. The scatter runs the other way: the force fields transposed into each lane's
[fx fy fz 0] per corner, added to that node's padded row of the force buffer, lane after lane in
the scalar loop's order. With float64 state the arithmetic and its order are the scalar loops'
(test_simd_lanes). A float32 model keeps its node state in float32: the differences are taken
after rounding u and v, not before (the full model's forces within 4.9e-7 of float64's largest
on tissue-sim bench's dent, against 1.6e-7 with the differences taken before rounding), and the
state moves half the bytes. Figures: docs/performance.md.

The code is plain LLVM IR (vector loads, shufflevector, fptrunc/fpext), so every target numba
supports lowers it; only its speed is measured on x86-64 with AVX-512.
"""
from llvmlite import ir
from numba import njit, prange, types
from numba.core import errors
from numba.extending import intrinsic

LANES = 8            # kernels.BLOCK; the transpose below is 8 x 8
STATE_WIDTH = 8      # node_state row: [ux uy uz 0 vx vy vz 0]
BUFFER_WIDTH = 4     # force buffer row: [fx fy fz 0]

_I64 = ir.IntType(64)
_I32 = ir.IntType(32)


# not cached on its own: compiled into each element pass that calls it (engine.compiled.cache)
@njit(parallel=True, boundscheck=False, nogil=True)
def pack_node_state(displacement, velocity, with_velocity, node_state):
    """node_state[i] = [u_i, 0, v_i, 0] in node_state's precision (v left as it is when not
    ``with_velocity``; the zeros are the allocation's, never written)."""
    for i in prange(displacement.shape[0]):
        for r in range(3):
            node_state[i, r] = displacement[i, r]
        if with_velocity:
            for r in range(3):
                node_state[i, 4 + r] = velocity[i, r]


def _check_c_arrays(name, *arrays):
    for array in arrays:
        if not (isinstance(array, types.Array) and array.ndim == 2 and array.layout == 'C'):
            raise errors.TypingError(f'{name}: expected 2-D C-contiguous arrays, got {array}')


def _index(builder, value):
    return builder.sext(value, _I64) if value.type.width < 64 else value


def _shuffle(builder, a, b, mask):
    return builder.shuffle_vector(a, b, ir.Constant(ir.VectorType(_I32, len(mask)), mask))


def _transpose8(builder, rows):
    """The columns of an 8 x 8 matrix given as 8 row vectors: pairs interleaved, then pairs of
    pairs, then the 128-bit halves combined (the classic AVX transpose)."""
    interleaved = [(_shuffle(builder, rows[p], rows[p + 1], [0, 8, 1, 9, 4, 12, 5, 13]),
                    _shuffle(builder, rows[p], rows[p + 1], [2, 10, 3, 11, 6, 14, 7, 15]))
                   for p in range(0, 8, 2)]
    quads = []   # per half of the lanes: columns [c | c + 4] for c = 0..3
    for (lo_a, hi_a), (lo_b, hi_b) in (interleaved[0:2], interleaved[2:4]):
        quads.append([_shuffle(builder, lo_a, lo_b, [0, 1, 8, 9, 4, 5, 12, 13]),
                      _shuffle(builder, lo_a, lo_b, [2, 3, 10, 11, 6, 7, 14, 15]),
                      _shuffle(builder, hi_a, hi_b, [0, 1, 8, 9, 4, 5, 12, 13]),
                      _shuffle(builder, hi_a, hi_b, [2, 3, 10, 11, 6, 7, 14, 15])])
    return [_shuffle(builder, quads[0][c % 4], quads[1][c % 4],
                     [0, 1, 2, 3, 8, 9, 10, 11] if c < 4 else [4, 5, 6, 7, 12, 13, 14, 15])
            for c in range(8)]


def _element_node_offsets(builder, tetrahedra, base, lane, row_width):
    """The 4 node indices of element base + lane, times ``row_width`` (offsets of their rows)."""
    element = builder.add(base, ir.Constant(_I64, lane))
    offsets = []
    for corner in range(4):
        pointer = builder.gep(tetrahedra.data, [builder.add(builder.mul(element, ir.Constant(_I64, 4)),
                                                            ir.Constant(_I64, corner))])
        index = builder.load(pointer)
        index = builder.zext(index, _I64) if index.type.width < 64 else index
        offsets.append(builder.mul(index, ir.Constant(_I64, row_width)))
    return offsets


def _field_pointer(builder, work, row_start, field, vector_type):
    return builder.bitcast(builder.gep(work.data, [builder.add(row_start, ir.Constant(_I64, field * LANES))]),
                           vector_type.as_pointer())


@intrinsic
def gather_difference_lanes(typingctx, work, row, field_u, field_v, node_state, tetrahedra, base, with_velocity):
    """For the 8 elements base..base + 7 (all valid), lane j, corner k = 1..3, component r:
    work[row, (field_u + 3 (k - 1) + r) * 8 + j] = u[tet[base + j, k], r] - u[tet[base + j, 0], r],
    and the same for v at field_v when ``with_velocity`` (a compile-time constant). The differences
    are taken in node_state's precision, then rounded to the work row's.
    work (rows, cols), node_state (n, 8), tetrahedra (m, 4): C-contiguous."""
    _check_c_arrays('gather_difference_lanes', work, node_state, tetrahedra)
    if not isinstance(with_velocity, types.BooleanLiteral):
        raise errors.TypingError('gather_difference_lanes: with_velocity must be a constant')
    velocity = with_velocity.literal_value
    sig = types.void(work, row, field_u, field_v, node_state, tetrahedra, base, with_velocity)

    def codegen(context, builder, signature, args):
        work_value, row_value, field_u_value, field_v_value, state_value, tets_value, base_value, _ = args
        work_type, _, _, _, state_type, tets_type, _, _ = signature.args
        work_array = context.make_array(work_type)(context, builder, work_value)
        state = context.make_array(state_type)(context, builder, state_value)
        tets = context.make_array(tets_type)(context, builder, tets_value)
        state_real = context.get_data_type(state_type.dtype)
        work_real = context.get_data_type(work_type.dtype)
        width = STATE_WIDTH if velocity else 4
        row_type = ir.VectorType(state_real, width)
        base_index = _index(builder, base_value)
        nodes = []          # per lane, the rows of its 4 nodes
        for lane in range(LANES):
            lane_rows = []
            for offset in _element_node_offsets(builder, tets, base_index, lane, STATE_WIDTH):
                pointer = builder.bitcast(builder.gep(state.data, [offset]), row_type.as_pointer())
                lane_rows.append(builder.load(pointer, align=state_type.dtype.bitwidth // 8))
            nodes.append(lane_rows)
        row_start = builder.mul(_index(builder, row_value), builder.extract_value(work_array.shape, 1))
        field_starts = [builder.add(row_start, builder.mul(_index(builder, f), ir.Constant(_I64, LANES)))
                        for f in (field_u_value, field_v_value)]
        out_type = ir.VectorType(work_real, LANES)
        for corner in range(1, 4):
            differences = []
            for lane in range(LANES):
                d = builder.fsub(nodes[lane][corner], nodes[lane][0])
                if width < LANES:   # [du 0] -> 8 wide, the upper half unused
                    d = _shuffle(builder, d, ir.Constant(row_type, ir.Undefined), list(range(width)) * 2)
                if state_real != work_real:
                    d = builder.fptrunc(d, out_type)
                differences.append(d)
            columns = _transpose8(builder, differences)
            # u's components are columns 0..2, v's 4..6
            for field_start, first_column in [(field_starts[0], 0)] + ([(field_starts[1], 4)] if velocity else []):
                for component in range(3):
                    pointer = _field_pointer(builder, work_array, field_start, 3 * (corner - 1) + component, out_type)
                    builder.store(columns[first_column + component], pointer, align=work_type.dtype.bitwidth // 8)
        return context.get_dummy_value()
    return sig, codegen


@intrinsic
def scatter_force_lanes(typingctx, buffer, work, row, field, tetrahedra, base):
    """For the 8 elements base..base + 7 (all valid), forces f_1..f_3 at work fields field +
    3 (k - 1) + r of lane j: buffer[tet[base + j, k], r] += f_k, and buffer[tet[base + j, 0], r]
    += -(f_1 + f_2 + f_3), lane after lane, corners 0..3 (the scalar loop's order). The sums are
    in the work row's precision, the additions in the buffer's. buffer (n, 4): C-contiguous."""
    _check_c_arrays('scatter_force_lanes', buffer, work, tetrahedra)
    sig = types.void(buffer, work, row, field, tetrahedra, base)

    def codegen(context, builder, signature, args):
        buffer_value, work_value, row_value, field_value, tets_value, base_value = args
        buffer_type, work_type, _, _, tets_type, _ = signature.args
        buffer_array = context.make_array(buffer_type)(context, builder, buffer_value)
        work_array = context.make_array(work_type)(context, builder, work_value)
        tets = context.make_array(tets_type)(context, builder, tets_value)
        work_real = context.get_data_type(work_type.dtype)
        buffer_real = context.get_data_type(buffer_type.dtype)
        lanes_type = ir.VectorType(work_real, LANES)
        row_start = builder.mul(_index(builder, row_value), builder.extract_value(work_array.shape, 1))
        field_start = builder.add(row_start, builder.mul(_index(builder, field_value), ir.Constant(_I64, LANES)))
        f = [builder.load(_field_pointer(builder, work_array, field_start, q, lanes_type), align=work_type.dtype.bitwidth // 8)
             for q in range(9)]
        f0 = [builder.fneg(builder.fadd(builder.fadd(f[r], f[3 + r]), f[6 + r])) for r in range(3)]
        corners = [f0, f[0:3], f[3:6], f[6:9]]
        zero = ir.Constant(lanes_type, [0.0] * LANES)
        # two corners a transpose: lane j's row [f_a 0 f_b 0]
        pairs = [_transpose8(builder, corners[a] + [zero] + corners[a + 1] + [zero]) for a in (0, 2)]
        part_type = ir.VectorType(buffer_real, BUFFER_WIDTH)
        base_index = _index(builder, base_value)
        for lane in range(LANES):
            offsets = _element_node_offsets(builder, tets, base_index, lane, BUFFER_WIDTH)
            for corner, offset in enumerate(offsets):
                both = pairs[corner // 2][lane]
                part = _shuffle(builder, both, both, [0, 1, 2, 3] if corner % 2 == 0 else [4, 5, 6, 7])
                if buffer_real != work_real:
                    part = builder.fpext(part, part_type)
                pointer = builder.bitcast(builder.gep(buffer_array.data, [offset]), part_type.as_pointer())
                total = builder.fadd(builder.load(pointer, align=buffer_type.dtype.bitwidth // 8), part)
                builder.store(total, pointer, align=buffer_type.dtype.bitwidth // 8)
        return context.get_dummy_value()
    return sig, codegen
