"""The needle against the tissue: contact, puncture, cutting, friction and the reaction wrench.

- :mod:`.pose`: quaternions, the needle axis, slerp, the checks every pose meets;
- :mod:`.parameters`: what a needle and each region bring (geometry, membrane, friction);
- :mod:`.kernels`: the numba kernels (surface ray casts, point location, constraints);
- :mod:`.tip`: the tip's shape, its surface samples and their contact;
- :mod:`.contact`, :mod:`.membrane`: the flat end bonded to the surface; meeting a layer;
- :mod:`.inside`: shaft points, friction, cutting and the layers the tip meets inside;
- :mod:`.step`: the step inside the tissue as one compiled call;
- :mod:`.rod`: a flexible shaft as a discrete elastic rod (energy, quasi-static solve, frames);
- :mod:`.rod_coupling`: the rod and the shaft's points in the tissue, solved together;
- :mod:`.rod_step`: a flexible needle's step inside the tissue as one compiled call;
- :mod:`.shaft`: the tip's frame, the centreline's shape, a flexible shaft's part of the step;
- :mod:`.interaction`: :class:`NeedleTissue`, one needle's state and its step.
"""
__all__ = ['contact', 'inside', 'interaction', 'kernels', 'membrane', 'parameters', 'pose', 'rod', 'rod_coupling',
           'rod_step', 'shaft', 'step', 'tip']
