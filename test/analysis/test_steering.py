"""A flexible needle's path (analysis/steering.py) in a small phantom: a bevel tip bends toward
the bevel's point along a near-constant curvature that grows as the rod softens and as the tissue
stiffens (the directions of Misra et al. 2010), a flip of the bevel half-way bends it back (an S),
a conical tip stays on the axis within the mesh's noise; the arc's radius on known circles."""
import math

import numpy as np
import pytest

from support.flexible import DEPTH, bend, own_bend, phantom
from tissue_sim_ros.analysis.steering import arc_radius
from tissue_sim_ros.bench.steering import needle_sets


def test_a_path_on_a_circle_tangent_at_the_entry_has_its_radius():
    """Points on a circle of 0.3 m leaving the entry along the axis, either way, any stretch of
    it: its radius, signed by the side; points on the axis: no bend."""
    t = np.linspace(0.02, 0.3, 40)
    assert arc_radius(0.3 * np.sin(t), 0.3 * (1 - np.cos(t))) == pytest.approx(0.3, rel=1e-12)
    assert arc_radius(0.3 * np.sin(t[20:]), -0.3 * (1 - np.cos(t[20:]))) == pytest.approx(-0.3, rel=1e-12)
    assert arc_radius(t, 0.0 * t) == math.inf


@pytest.fixture(scope='module')
def nitinol():
    return own_bend(())


def test_a_bevel_tip_bends_toward_its_point_along_a_near_constant_curvature(nitinol):
    """The bevel's point at +x: the path bends toward +x, and the bevel's own bend (its half
    difference with the bevel turned 180 degrees) bends at a near-constant curvature over its last
    60 %: the arcs from the entry through each third of that stretch (Webster et al. 2006: a
    constant-curvature arc) have radii within 35 % of each other, and the arc through the whole
    stretch fits it within 15 % of its largest value."""
    bent, along, own = nitinol
    print(f'toward the bevel at {along[-1] * 1e3:.1f} mm: path {bent.lateral[-1] * 1e6:.0f} um, own bend '
          f'{own[-1] * 1e6:.0f} um')
    assert bent.lateral[-1] > 0.0 and own[-1] > 50e-6
    last = np.flatnonzero(along >= 0.4 * along[-1])
    radius = arc_radius(along[last], own[last])
    radii = [arc_radius(along[h], own[h]) for h in np.array_split(last, 3)]
    print(f'radius over the last 60 %: {radius:.3g} m; its thirds ' + ', '.join(f'{r:.3g}' for r in radii) + ' m')
    assert 0.0 < radius < 5.0                                     # toward the point
    assert max(radii) < 1.35 * min(radii)
    # and the arc fits the bend: within 15 % of the bend's largest value over the stretch
    arc = radius - np.sqrt(radius ** 2 - along[last] ** 2)
    assert np.abs(arc - own[last]).max() < 0.15 * own[-1]


def test_a_conical_tip_stays_on_the_axis_within_the_meshs_noise(nitinol):
    """A cone pushes the tissue aside evenly: its tip leaves the axis by the mesh's own bias, a
    fraction of the bevel's bend."""
    _, along, own = nitinol
    cone = bend(phantom(*needle_sets('20 G nitinol', 'conical')))[0]
    print(f'conical tip {cone.deflection[-1] * 1e6:.0f} um off the axis; the bevel {own[-1] * 1e6:.0f} um')
    assert cone.deflection[-1] < 0.3 * own[-1]


def test_the_curvature_grows_as_the_rod_softens_and_as_the_tissue_stiffens(nitinol):
    """Misra et al. (2010): a stiffer rod (steel, 3.3 times the bending stiffness) bends less; a
    stiffer tissue (2.7 times the modulus, and a cutting force as much higher: a stiffer gel is
    also tougher) bends it more."""
    _, along, own = nitinol
    _, steel_along, steel = own_bend(('needle.young_modulus_pa=200e9',))
    _, stiff_along, stiff = own_bend(('regions[0].young_modulus_pa=60000', 'regions[0].cutting_force_n=1.33'))
    at = along[-1]
    bends = [float(np.interp(at, a, o)) for a, o in ((along, own), (steel_along, steel), (stiff_along, stiff))]
    print('own bend at {:.1f} mm: nitinol {:.0f} um, steel {:.0f} um, stiffer tissue {:.0f} um'.format(
        at * 1e3, *(1e6 * b for b in bends)))
    assert bends[1] < 0.8 * bends[0] < 0.8 * bends[2]


def test_turning_the_bevel_half_way_bends_the_path_back(nitinol):
    """The input pose's roll turns the bevel: 180 degrees half-way, the path that bent toward +x
    turns toward -x (an S), where the same insertion without the turn goes on toward +x; up to the
    turn the two are the same run, to the last bit."""
    straight = nitinol[0]
    flipped = bend(phantom(*needle_sets('20 G nitinol')), DEPTH, roll_at=0.5 * DEPTH)[1]
    turn = int(np.argmax(flipped.along >= 0.5 * DEPTH - 0.006))        # (the capsule takes ~4 mm)
    peak = int(np.argmax(flipped.lateral))
    print(f'flipped half-way: {flipped.lateral[peak] * 1e6:.0f} um toward the first bevel at '
          f'{flipped.along[peak] * 1e3:.1f} mm, {flipped.lateral[-1] * 1e6:.0f} um at {flipped.along[-1] * 1e3:.1f} '
          f'mm; without the turn {straight.lateral[-1] * 1e6:.0f} um')
    assert np.array_equal(flipped.lateral[:turn], straight.lateral[:turn])
    assert flipped.lateral[peak] > 10e-6 and flipped.along[peak] < 0.7 * flipped.along[-1]
    assert flipped.lateral[-1] < flipped.lateral[peak] - 50e-6
    assert flipped.lateral[-1] < straight.lateral[-1] - 150e-6
    later = flipped.along >= 0.7 * flipped.along[-1]
    assert np.polyfit(flipped.along[later], flipped.lateral[later], 1)[0] < 0.0     # heading for -x
