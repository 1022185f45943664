"""Reference implementation of St Venant-Kirchhoff in the paper's precomputed form (not the hot path).

Picinbono et al. (seed section 4.2) expand the St Venant-Kirchhoff energy in the vertex
displacements with precomputed stiffness tensors K_jk, vectors c_jkl and scalars d_jklm
(docs/method.md, "St Venant-Kirchhoff", with a_j the shape-function gradients and V the rest
volume):

  K_jk   = V [lambda a_j a_k^T + mu a_k a_j^T + mu (a_j . a_k) I]
  c_jkl  = V [lambda/2 (a_k . a_l) a_j + mu/2 ((a_j . a_k) a_l + (a_j . a_l) a_k)]
  d_jklm = V [lambda/8 (a_j . a_k)(a_l . a_m) + mu/4 (a_k . a_l)(a_j . a_m)]

  f_p = -[ sum_j K_pj u_j + sum_kl (u_k . u_l) c_pkl + 2 sum_jl (c_jpl . u_j) u_l
           + sum_klm d_pklm (u_l . u_m) u_k + sum_jlm d_jplm (u_l . u_m) u_j
           + sum_jkm d_jkpm (u_j . u_k) u_m + sum_jkl d_jklp (u_j . u_k) u_l ]

The kernel in kernels.py computes the same force as -V F S a_p; the tests hold the two equal.
"""
import numpy as np


def all_shape_gradients(shape_gradients):
    """(m, 4, 3): a_0 = -(a_1 + a_2 + a_3) prepended to the stored a_1..a_3."""
    return np.concatenate([-shape_gradients.sum(axis=1, keepdims=True), shape_gradients], axis=1)


def picinbono_tensors(shape_gradients, volume_lambda, volume_mu):
    """K (m,4,4,3,3), c (m,4,4,4,3), d (m,4,4,4,4) from gradients and V lambda, V mu per element."""
    a = all_shape_gradients(shape_gradients)
    dots = np.einsum('mjr,mkr->mjk', a, a)
    lam = volume_lambda[:, None, None]
    mu = volume_mu[:, None, None]
    eye = np.eye(3)
    stiffness = (lam[..., None, None] * np.einsum('mjr,mks->mjkrs', a, a)
                 + mu[..., None, None] * np.einsum('mkr,mjs->mjkrs', a, a)
                 + mu[..., None, None] * dots[..., None, None] * eye)
    c = (0.5 * volume_lambda[:, None, None, None, None] * np.einsum('mkl,mjr->mjklr', dots, a)
         + 0.5 * volume_mu[:, None, None, None, None]
         * (np.einsum('mjk,mlr->mjklr', dots, a) + np.einsum('mjl,mkr->mjklr', dots, a)))
    d = (volume_lambda[:, None, None, None, None] / 8.0 * np.einsum('mjk,mlq->mjklq', dots, dots)
         + volume_mu[:, None, None, None, None] / 4.0 * np.einsum('mkl,mjq->mjklq', dots, dots))
    return stiffness, c, d


def picinbono_forces(tetrahedra, shape_gradients, volume_lambda, volume_mu, displacement):
    """St Venant-Kirchhoff internal forces (n, 3) from the precomputed K, c, d (numpy, per element)."""
    stiffness, c, d = picinbono_tensors(shape_gradients, volume_lambda, volume_mu)
    u = displacement[tetrahedra]                             # (m, 4, 3)
    uu = np.einsum('mkr,mlr->mkl', u, u)                     # u_k . u_l
    cu = np.einsum('mjplr,mjr->mpl', c, u)                   # c_jpl . u_j
    f = np.einsum('mpjrs,mjs->mpr', stiffness, u)
    f += np.einsum('mkl,mpklr->mpr', uu, c)
    f += 2.0 * np.einsum('mpl,mlr->mpr', cu, u)
    f += np.einsum('mpklq,mlq,mkr->mpr', d, uu, u)
    f += np.einsum('mjplq,mlq,mjr->mpr', d, uu, u)
    f += np.einsum('mjkpq,mjk,mqr->mpr', d, uu, u)
    f += np.einsum('mjklp,mjk,mlr->mpr', d, uu, u)
    out = np.zeros_like(displacement)
    for local in range(4):
        np.add.at(out, tetrahedra[:, local], -f[:, local])
    return out
