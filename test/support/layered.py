"""Synthetic layered studies for the calibration tests: two- and three-layer phantoms on the small
'test' mesh (analysis.synthetic_study.phantom_scene), short insertions, no pause, each repeat
with its own rupture forces and deep boundary drawn from the scene's spread, 5 mN of noise."""
import yaml

from tissue_sim_ros.analysis.synthetic_study import phantom_scene, write_layered_study

#: the tests' spread between repeats: smaller than the phantom's, so that four repeats pin the mean
SPREAD = {'regions[0].membrane.rupture_force_spread_n': 0.1, 'regions[1].membrane.rupture_force_spread_n': 0.1,
          'regions[1].depth_spread_m': 0.0003}


def truth_scene(layers):
    from tissue_sim_ros.engine.scene.keys import set_keys
    scene = phantom_scene(layers, 'test')
    scene['model']['relaxation'] = []
    return set_keys(scene, SPREAD)


def base_scene():
    """The start propose builds on: the phantom's mesh, model, solver and needle, one region."""
    base = phantom_scene(2, 'test')
    base['regions'] = [{'name': 'tissue', 'select': 'all', 'young_modulus_pa': 15000.0,
                        'friction': {'insertion_static_n_per_m': 200.0}}]
    base['model']['relaxation'] = []
    return base


def write_studies(root) -> dict:
    """Two layers at 3 mm/s (fitted) and 2 mm/s (held out), three layers at 3 mm/s: 4 repeats
    each, 16 mm past the surface (22 with three layers) and back."""
    for layers in (2, 3):
        (root / f'truth_{layers}.yaml').write_text(yaml.safe_dump(truth_scene(layers)))
    (root / 'base.yaml').write_text(yaml.safe_dump(base_scene()))
    options = dict(repeats=4, hold_s=0.0, workers=2)
    return {'root': root,
            'fit': write_layered_study(root / 'fit', [], [3.0], scene_file=root / 'truth_2.yaml', travel_m=0.017,
                                       seed=1, **options),
            'held': write_layered_study(root / 'held', [], [2.0], scene_file=root / 'truth_2.yaml', travel_m=0.017,
                                        seed=2, **options),
            'three': write_layered_study(root / 'three', [], [3.0], scene_file=root / 'truth_3.yaml', travel_m=0.023,
                                         seed=3, **options)}
