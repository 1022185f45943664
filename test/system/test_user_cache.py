"""The per-user cache (system/user_cache.py): the key of the engine's sources changes with any of
them and only with them."""

from support.paths import ROOT
from tissue_sim_ros.system.user_cache import sources_key


def test_the_cache_key_changes_with_any_engine_source_and_only_with_them(tmp_path):
    """A kernel's helpers in another file (kernels.py's pass, simd_lanes.py's gather), in any
    sub-package, change the key, so their kernels are compiled afresh; a file that is not Python
    source does not."""
    engine = tmp_path / 'engine'
    source_engine = ROOT / 'tissue_sim_ros' / 'engine'
    for source in source_engine.rglob('*.py'):
        copy = engine / source.relative_to(source_engine)
        copy.parent.mkdir(parents=True, exist_ok=True)
        copy.write_bytes(source.read_bytes())
    key = sources_key(str(engine))
    assert key == sources_key(str(source_engine))
    (engine / 'notes.txt').write_text('not a source')
    assert sources_key(str(engine)) == key
    helper = engine / 'model' / 'simd_lanes.py'
    helper.write_text(helper.read_text() + '# changed\n')
    changed = sources_key(str(engine))
    assert changed != key and changed.startswith('engine-') and len(changed) == len(key)
    helper.rename(engine / 'simd_lanes_renamed.py')
    assert sources_key(str(engine)) not in (key, changed)
