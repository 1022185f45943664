"""The layered benchmark's bookkeeping (its runs are the benchmark itself, not tests)."""
import json

from tissue_sim_ros.bench import layered


def test_a_proposal_without_a_layer_is_not_calibrated_and_says_which_keys_it_lacks(tmp_path, capsys):
    """A proposal that found fewer layers than the phantom has (the needle never punctured the
    deepest) is reported, not a KeyError half an hour into the benchmark."""
    proposal = tmp_path / 'propose_3_layers'
    proposal.mkdir()
    fits = [{'key': key, 'text': f'{key}=1:2'} for key in layered.KEYS_3 if not key.startswith('regions[2]')]
    proposal.joinpath('propose.json').write_text(json.dumps({'fits': fits, 'layers': [{}, {}]}))
    result = layered._calibrate(tmp_path, 3, tmp_path / 'fit.yaml', tmp_path / 'held.yaml', layered.KEYS_3,
                                tmp_path / 'truth.yaml', 10, 1, 'fine')
    missing = [key for key in layered.KEYS_3 if key.startswith('regions[2]')]
    assert result == {'skipped': missing}
    out = capsys.readouterr().out
    assert 'proposes 2 layer(s)' in out and all(key in out for key in missing)
