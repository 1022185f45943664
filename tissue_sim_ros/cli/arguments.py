"""The option types and option groups every ``tissue-sim`` command shares: one name per thing.

Every command that takes a scene takes ``--scene FILE`` and ``--set KEY=VALUE``; every command
that moves the needle takes ``--travel-mm`` (tip travel from its start pose) or ``--depth-mm``
(below the tissue surface); studies take ``--jobs``, ``--scheduler`` and a resumable ``--out``.
An old spelling still works for now, with a one-line deprecation note (:func:`add_scene`).
"""
import argparse
import math
import os
import sys
from pathlib import Path

from tissue_sim_ros.errors import CommandLineError

__all__ = ['NON_NEGATIVE', 'POSITIVE', 'Parser', 'add_max_depth', 'add_pool_and_out', 'add_scene',
           'add_travel_or_depth', 'depth_below_surface', 'input_file', 'number', 'output_dir',
           'travel_and_depth']


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors: the problem and where the usage is, exit status 2."""

    def error(self, message):
        self.exit(2, f'{self.prog}: error: {message} (usage: {self.prog} --help)\n')


def number(low, *, inclusive=False, high=None, whole=False):
    """An argparse type: a finite number > ``low`` (>= with ``inclusive``), < ``high``; an int
    with ``whole``. The refusal names the value and what was expected."""
    expected = (f'{"a whole" if whole else "a finite"} number {">=" if inclusive else ">"} {low:g}'
                + ('' if high is None else f' and < {high:g}'))

    def parse(text):
        try:
            value = int(text) if whole else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f'{text!r}: expected {expected}') from None
        if not (math.isfinite(value) and (value >= low if inclusive else value > low)
                and (high is None or value < high)):
            raise argparse.ArgumentTypeError(f'{text!r}: expected {expected}')
        return value
    return parse


POSITIVE = number(0)
NON_NEGATIVE = number(0, inclusive=True)


def input_file(text):
    """An argparse type: a file that exists (not a directory)."""
    path = Path(text)
    if not path.exists():
        raise argparse.ArgumentTypeError(f'{text!r}: no such file')
    if not path.is_file():
        raise argparse.ArgumentTypeError(f'{text!r}: not a file (a directory?); expected a file')
    return text


def output_dir(text):
    """An argparse type: a directory that exists or can be made, and can be written to."""
    path = Path(text).absolute()
    existing = next(p for p in (path, *path.parents) if p.exists())
    where = repr(text) if existing == path else f'{text!r}: {existing}'
    if not existing.is_dir():
        raise argparse.ArgumentTypeError(f'{where} is a file; expected a directory')
    if not os.access(existing, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f'{where} is not writable')
    return text


class _Deprecated(argparse.Action):
    """An old spelling of an option: stores into the new one's place, with a one-line note."""

    def __call__(self, parser, namespace, values, option_string=None):
        print(f'{parser.prog}: note: {option_string} is deprecated; use {self.metavar}', file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_scene(parser, *, sets=True, help_text='scene YAML (default: the packaged liver sample)'):
    """``--scene FILE`` (the old ``--scene-file`` accepted with a note) and ``--set KEY=VALUE``."""
    parser.add_argument('--scene', type=input_file, default=None, help=help_text)
    parser.add_argument('--scene-file', dest='scene', type=input_file, action=_Deprecated, metavar='--scene',
                        help=argparse.SUPPRESS)
    if sets:
        parser.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                            help='change a scene key (repeatable), as `tissue-sim scene-keys` names '
                                 'them; a list entry by index or name: regions[0].young_modulus_pa=20000, '
                                 'regions[liver].membrane.rupture_force_n=2.1')


def add_travel_or_depth(parser, *, default_help):
    """--travel-mm (tip travel from the start pose) or --depth-mm (depth below the tissue
    surface): the same two names in every command."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument('--travel-mm', type=POSITIVE, default=None,
                       help='tip travel from its start pose along the needle axis [mm]')
    group.add_argument('--depth-mm', type=NON_NEGATIVE, default=None,
                       help=f'tip depth below the tissue surface [mm] ({default_help})')


def travel_and_depth(args, *, default_travel_mm=None, default_depth_mm=None):
    """(travel, depth) in mm, exactly one of them not None (the defaults when neither given)."""
    if args.travel_mm is None and args.depth_mm is None:
        return default_travel_mm, default_depth_mm
    return args.travel_mm, args.depth_mm


def depth_below_surface(args, start_height_mm, default_depth_mm, scene_file=None):
    """--depth-mm, or --travel-mm less the tip's start height above the surface."""
    travel, depth = travel_and_depth(args, default_depth_mm=default_depth_mm)
    if depth is not None:
        return depth
    if travel is None:
        raise CommandLineError('one of --travel-mm and --depth-mm is required')
    if start_height_mm is None:
        from tissue_sim_ros.analysis.charting.auto_keys import resolve_auto_keys
        from tissue_sim_ros.ros.clients.drive import scene_start
        start_height_mm = scene_start(scene_file, resolve_auto=resolve_auto_keys).gap_m * 1e3
    if travel < start_height_mm:
        raise CommandLineError(f'--travel-mm {travel:g}: less than the tip\'s start height above the '
                               f'tissue ({start_height_mm:.3g} mm); the needle would not reach it')
    return travel - start_height_mm


def add_max_depth(parser):
    parser.add_argument('--max-depth-mm', type=POSITIVE, default=None,
                        help='use each trial up to this travel since its contact [mm] (the first '
                             'part of the insertion; default: the whole trial)')


def add_pool_and_out(parser, out_default, extra_out_help=''):
    """--jobs, --scheduler and a resumable --out: a study's process pool or Dask cluster."""
    parser.add_argument('--jobs', type=number(1, inclusive=True, whole=True), default=None,
                        help='worker processes (default: every core this process may use)')
    parser.add_argument('--scheduler', default=None, metavar='ADDRESS',
                        help='run the simulations on a Dask distributed cluster (tcp://host:8786)')
    parser.add_argument('--out', type=output_dir, default=out_default,
                        help=f'output directory (default {out_default}{extra_out_help}); an interrupted run '
                             'resumes there')
