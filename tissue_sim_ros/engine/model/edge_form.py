"""The paper's assembled form of the linear forces: vertex and edge tensors (numba).

f_i = -(K_ii u_i + sum_j K_ij u_j), with vertex tensors K_ii and edge tensors K_ij summed over the
elements around a vertex or edge, lambda and mu parts stored separately (Cotin et al., seed
section 3; docs/method.md, "Linear tensor-mass"). Linear only, as in the paper. The hot path is
kernels.element_kernel; the tests hold the two equal. The tensors also give the global stiffness
matrix (TensorMassModel.stiffness_matrix), and cutting removes an element's share
(accumulate_tensors, sign -1).
"""
import numpy as np
from numba import njit, prange

from tissue_sim_ros.engine.model.kernels import FASTMATH


@njit(cache=True, boundscheck=False)
def accumulate_tensors(tetrahedra, shape_gradients, volume_lambda, volume_mu, element_edges,
                       elements, sign, vertex_lambda, vertex_mu, edge_lambda, edge_mu):
    """Add (sign=+1) or remove (sign=-1) the given elements' K_jk = lambda A_jk + mu B_jk.

    A_jk = V a_j a_k^T, B_jk = V [a_k a_j^T + (a_j . a_k) I] (docs/method.md, "Linear
    tensor-mass"). Vertex tensors get K_jj; the edge tensor of edge (p, q), p < q, gets K_jk
    with j, k the local indices of p, q.
    element_edges (m, 6): global edge of each local pair (0,1),(0,2),(0,3),(1,2),(1,3),(2,3).
    """
    a = np.empty((4, 3))
    for e in elements:
        for r in range(3):
            a[1, r] = shape_gradients[e, 0, r]
            a[2, r] = shape_gradients[e, 1, r]
            a[3, r] = shape_gradients[e, 2, r]
            a[0, r] = -(a[1, r] + a[2, r] + a[3, r])
        vl = sign * volume_lambda[e]
        vm = sign * volume_mu[e]
        local = 0
        for j in range(4):
            for k in range(j, 4):
                dot = a[j, 0] * a[k, 0] + a[j, 1] * a[k, 1] + a[j, 2] * a[k, 2]
                if j == k:
                    p = tetrahedra[e, j]
                    for r in range(3):
                        for s in range(3):
                            vertex_lambda[p, r, s] += vl * a[j, r] * a[j, s]
                            vertex_mu[p, r, s] += vm * (a[j, s] * a[j, r] + (dot if r == s else 0.0))
                else:
                    edge = element_edges[e, local]
                    local += 1
                    # stored as K_pq with p < q: K_jk if the local order matches, else K_kj = K_jk^T
                    jj, kk = (j, k) if tetrahedra[e, j] < tetrahedra[e, k] else (k, j)
                    for r in range(3):
                        for s in range(3):
                            edge_lambda[edge, r, s] += vl * a[jj, r] * a[kk, s]
                            edge_mu[edge, r, s] += vm * (a[kk, r] * a[jj, s] + (dot if r == s else 0.0))


@njit(cache=True, inline='always')
def _edge_tensor_times(edge_lambda, edge_mu, edge, transpose, vx, vy, vz):
    """(K_e v) or (K_e^T v) for the edge tensor K_e = lambda part + mu part, as three scalars."""
    out0 = 0.0
    out1 = 0.0
    out2 = 0.0
    for s in range(3):
        value = vx if s == 0 else (vy if s == 1 else vz)
        if transpose:
            out0 += (edge_lambda[edge, s, 0] + edge_mu[edge, s, 0]) * value
            out1 += (edge_lambda[edge, s, 1] + edge_mu[edge, s, 1]) * value
            out2 += (edge_lambda[edge, s, 2] + edge_mu[edge, s, 2]) * value
        else:
            out0 += (edge_lambda[edge, 0, s] + edge_mu[edge, 0, s]) * value
            out1 += (edge_lambda[edge, 1, s] + edge_mu[edge, 1, s]) * value
            out2 += (edge_lambda[edge, 2, s] + edge_mu[edge, 2, s]) * value
    return out0, out1, out2


@njit(cache=True, parallel=True, fastmath=FASTMATH, boundscheck=False)
def edge_forces(vertex_lambda, vertex_mu, edge_lambda, edge_mu, edges,
                adjacency_ptr, adjacency_edge, displacement, out):
    """f_p = -(K_pp u_p + sum over edges (p, q) of K_pq u_q), gathered per vertex: no races.

    adjacency_ptr/adjacency_edge: CSR list of the edges at each vertex. An edge stored as (p, q)
    contributes K_pq u_q to p and K_pq^T u_p to q.
    """
    for p in prange(out.shape[0]):
        fx, fy, fz = _edge_tensor_times(vertex_lambda, vertex_mu, p, False, displacement[p, 0],
                                        displacement[p, 1], displacement[p, 2])
        for slot in range(adjacency_ptr[p], adjacency_ptr[p + 1]):
            edge = adjacency_edge[slot]
            transpose = edges[edge, 0] != p
            q = edges[edge, 0] if transpose else edges[edge, 1]
            gx, gy, gz = _edge_tensor_times(edge_lambda, edge_mu, edge, transpose, displacement[q, 0],
                                            displacement[q, 1], displacement[q, 2])
            fx += gx
            fy += gy
            fz += gz
        out[p, 0] = -fx
        out[p, 1] = -fy
        out[p, 2] = -fz
