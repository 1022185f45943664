"""The option types and groups every command shares (cli/arguments.py): each bound on either side
of its edge, files and folders refused by what is wrong with them, and the depth below the
surface from --travel-mm less the start height. Truth: the bounds as stated, the arithmetic."""
import argparse
from types import SimpleNamespace

import pytest

from tissue_sim_ros.cli.arguments import (NON_NEGATIVE, POSITIVE, add_travel_or_depth, depth_below_surface,
                                          input_file, number, output_dir)
from tissue_sim_ros.errors import CommandLineError


@pytest.mark.parametrize('parse, text, value', [
    (POSITIVE, '1e-9', 1e-9), (NON_NEGATIVE, '0', 0.0), (number(0, high=1), '0.999', 0.999),
    (number(1, inclusive=True, whole=True), '1', 1), (number(-5), '-4.5', -4.5),
])
def test_a_number_inside_its_bounds_is_taken(parse, text, value):
    assert parse(text) == value and type(parse(text)) is type(value)


@pytest.mark.parametrize('parse, text, expected', [
    (POSITIVE, '0', 'a finite number > 0'), (POSITIVE, 'inf', 'a finite number > 0'),
    (NON_NEGATIVE, '-1e-12', 'a finite number >= 0'), (number(0, high=1), '1', 'a finite number > 0 and < 1'),
    (number(1, inclusive=True, whole=True), '2.5', 'a whole number >= 1'), (POSITIVE, 'nan', '> 0'),
    (POSITIVE, 'ten', '> 0'),
])
def test_a_number_outside_them_is_refused_naming_the_text_and_the_bound(parse, text, expected):
    with pytest.raises(argparse.ArgumentTypeError) as caught:
        parse(text)
    assert str(caught.value).startswith(f'{text!r}: expected') and expected in str(caught.value)


def test_files_and_folders_are_refused_by_what_is_wrong(tmp_path):
    (tmp_path / 'scene.yaml').write_text('{}\n')
    assert input_file(str(tmp_path / 'scene.yaml')) == str(tmp_path / 'scene.yaml')
    for text, words in ((tmp_path / 'missing.yaml', 'no such file'), (tmp_path, 'not a file')):
        with pytest.raises(argparse.ArgumentTypeError, match=words):
            input_file(str(text))
    assert output_dir(str(tmp_path / 'new' / 'deeper')) == str(tmp_path / 'new' / 'deeper')
    with pytest.raises(argparse.ArgumentTypeError, match=r'scene\.yaml.* is a file; expected a directory'):
        output_dir(str(tmp_path / 'scene.yaml' / 'out'))


def test_the_depth_below_the_surface_is_the_travel_less_the_start_height():
    parser = argparse.ArgumentParser()
    add_travel_or_depth(parser, default_help='default 10')
    args = parser.parse_args(['--travel-mm', '25'])
    assert depth_below_surface(args, 9.0, 10.0) == pytest.approx(16.0)
    assert depth_below_surface(parser.parse_args(['--depth-mm', '4']), 9.0, 10.0) == 4.0
    assert depth_below_surface(parser.parse_args([]), 9.0, 10.0) == 10.0            # the default
    with pytest.raises(CommandLineError, match='--travel-mm 5: less than the tip'):
        depth_below_surface(parser.parse_args(['--travel-mm', '5']), 9.0, 10.0)
    with pytest.raises(CommandLineError, match='one of --travel-mm and --depth-mm'):
        depth_below_surface(SimpleNamespace(travel_mm=None, depth_mm=None), 9.0, None)
    with pytest.raises(SystemExit):                               # not both
        parser.parse_args(['--travel-mm', '25', '--depth-mm', '4'])
