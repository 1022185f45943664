"""What a needle and each region bring (engine/needle/parameters.py): the rupture force follows its
rate law."""

import pytest

from support.scenes import push, small_scene


@pytest.mark.parametrize('exponent', [0.25])
def test_the_rupture_force_follows_its_rate_law(exponent):
    """criterion 'force' with rate_exponent n: F_rupture = F0 (v / v0)^n (checked every step), so
    the puncture forces at 1 and 8 mm/s are in the ratio 8^n."""
    membrane = {'criterion': 'force', 'rupture_force_n': 0.1, 'rate_exponent': exponent,
                'reference_speed_m_s': 0.001}
    forces = {}
    for speed in (1e-3, 8e-3):
        scene = small_scene(region={'membrane': membrane})
        for _ in push(scene, 0.008, speed, tick=0.005):
            if scene.puncture_events:
                break
        event = scene.puncture_events[0]
        assert event['speed_m_s'] == pytest.approx(speed, rel=1e-6)
        forces[speed] = event['axial_force_n']
    ratio = forces[8e-3] / forces[1e-3]
    print(f'puncture at 1 mm/s {forces[1e-3]:.4f} N, at 8 mm/s {forces[8e-3]:.4f} N: ratio {ratio:.4f}, '
          f'law {8.0 ** exponent:.4f}')
    assert forces[1e-3] == pytest.approx(0.1, rel=0.02)
    assert ratio == pytest.approx(8.0 ** exponent, rel=0.03)
