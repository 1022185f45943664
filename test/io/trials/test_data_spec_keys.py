"""Every key of a data description and its checks (io/trials/data_spec_keys.py): a section comes
back with every key, the defaults the table states filled in; a bad key or value is refused with
its dotted path; every key is described. Truth: the key table itself, walked here."""
import pytest

from tissue_sim_ros.errors import DataSpecError
from tissue_sim_ros.io.trials.data_spec_keys import (DATA_SPEC_KEYS, check_data_spec, check_section,
                                                     describe_data_keys)


def _leaves(keys, prefix=''):
    """{dotted key: default} of the table, by walking its nested sections."""
    out = {}
    for key, spec in keys.items():
        if isinstance(spec, dict):
            out.update(_leaves(spec, f'{prefix}{key}.'))
        else:
            out[f'{prefix}{key}'] = spec[0]
    return out


def test_a_description_comes_back_whole_with_the_defaults_of_the_table():
    spec = check_data_spec({'files': 'raw/*.csv', 'time': {'column': 'Time'},
                            'force': {'columns': ['fx', 'fy', 2], 'unit': 'lbf', 'sign': -1}})
    assert spec['files'] == ['raw/*.csv']
    given = {'files': ['raw/*.csv'], 'time.column': 'Time', 'force.columns': ['fx', 'fy', 2],
             'force.unit': 'lbf', 'force.sign': -1}
    for dotted, default in _leaves(DATA_SPEC_KEYS).items():
        section, _, key = dotted.rpartition('.')
        holder = spec if not section else spec[section]
        if holder is None:                                   # an optional section left out
            continue
        assert holder[key] == given.get(dotted, default), dotted


@pytest.mark.parametrize('section, data, words', [
    ('force', {'column': 'fz', 'sign': 2}, ['force.sign = 2', '+1 or -1']),
    ('force', {'column': 'fz', 'unit': 'furlong'}, ['force.unit', 'furlong']),
    ('force', {'columns': ['fx', 'fy']}, ['force.columns', 'a list of 3 columns']),
    ('force', {'column': -1}, ['force.column = -1', '0-based column index']),
    ('time', {'column': 't', 'rate_hz': 100.0}, ['time: give exactly one of time.column or time.rate_hz']),
    ('time', {'rate_hz': 0.0}, ['time.rate_hz = 0.0', 'a number > 0']),
    ('format', {'skip_rows': True}, ['format.skip_rows = True', 'an integer >= 0']),
    ('format', {'delimter': ','}, ['unknown key format.delimter', 'delimiter']),
])
def test_a_bad_key_or_value_is_refused_with_its_dotted_path(section, data, words):
    with pytest.raises(DataSpecError) as caught:
        check_section(section, data, source='rig.yaml')
    assert str(caught.value).startswith('rig.yaml: ')
    assert all(word in str(caught.value) for word in words), str(caught.value)


def test_every_key_is_described_once_with_its_default():
    lines = describe_data_keys()
    for dotted, default in _leaves(DATA_SPEC_KEYS).items():
        described = [line for line in lines if line.startswith(f'{dotted} (default ')]
        assert len(described) == 1 and f'(default {default!r})' in described[0], dotted


def test_the_data_description_keys_page_is_what_data_keys_prints():
    from support.paths import ROOT
    from tissue_sim_ros.io.trials.data_spec_keys import data_keys_markdown
    page = (ROOT / 'docs' / 'data.md').read_text()
    table = page.split('<!-- data-keys -->\n')[1].split('<!-- /data-keys -->')[0]
    assert table == data_keys_markdown(), 'docs/data.md is stale: tissue-sim data-keys --markdown'
