"""Every scene key (engine/scene/schema.py): the generated page docs/scenes.md is the schema."""

from support.paths import ROOT
from tissue_sim_ros.engine.scene.schema import keys_markdown


def test_the_scene_keys_page_is_the_schema():
    """docs/scenes.md is generated (tissue-sim scene-keys --markdown): stale when it differs."""
    page = (ROOT / 'docs' / 'scenes.md').read_text()
    assert page == keys_markdown(), 'docs/scenes.md is stale: tissue-sim scene-keys --markdown > docs/scenes.md'
    for dotted in ('regions[].young_modulus_pa', 'model.relaxation[].time_constant_s', 'solver.mass_scaling'):
        assert f'`{dotted}`' in page
