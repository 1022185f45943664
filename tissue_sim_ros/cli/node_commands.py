"""tissue-sim's commands that run or drive the node as a process: drive and node-bench (the
parsers and their handlers)."""
import argparse
import sys

from tissue_sim_ros.cli.arguments import (NON_NEGATIVE, POSITIVE, add_scene, add_travel_or_depth,
                                          depth_below_surface, number, output_dir)
from tissue_sim_ros.errors import CommandLineError


def _drive(args):
    from tissue_sim_ros.analysis.charting.auto_keys import resolve_auto_keys
    from tissue_sim_ros.ros.clients.drive import run_drive
    depth = depth_below_surface(args, args.start_height_mm, None, args.scene)
    code = run_drive(args.speed_mm_s, depth, start_height_mm=args.start_height_mm,
                     rate_hz=args.rate_hz, hold_s=args.hold_s, scene_file=args.scene,
                     wait_for_node_s=args.wait_for_node_s, resolve_auto=resolve_auto_keys)
    if code:
        sys.exit(code)


def _node_bench(args):
    if args.against is not None or args.against_scene is not None:
        _node_bench_paired(args)
        return
    if args.pairs is not None:
        raise CommandLineError('--pairs: only with --against REV or --against-scene SCENE')
    from tissue_sim_ros.bench import node_bench
    node_bench.run(duration_s=args.duration_s, rate_hz=args.rate_hz, scene_file=args.scene,
                   out=args.out, threads=args.threads, executor=args.executor, load=args.load,
                   predictions=args.predictions, prediction_s=args.prediction_s, params=args.param,
                   listen=args.listen)


def _node_bench_paired(args):
    from tissue_sim_ros.bench import node_bench_paired
    if args.out is None:
        raise CommandLineError('--against and --against-scene need --out DIR (the runs, the revision and the '
                               'figures go there)')
    if args.against is not None and args.against_scene is not None:
        raise CommandLineError('--against and --against-scene: one or the other')
    fixed = [name for name, value in (('--threads', args.threads), ('--executor', args.executor),
                                      ('--predictions', args.predictions or None), ('--param', args.param or None),
                                      ('--listen', args.listen or None))
             if value is not None]
    if fixed:
        raise CommandLineError(f'{" ".join(fixed)}: not with --against (both versions run on the same '
                           'options, and an earlier one may not have these)')
    try:
        node_bench_paired.run(args.against, args.out, pairs=args.pairs or 3, duration_s=args.duration_s,
                              rate_hz=args.rate_hz, load=args.load, scene_file=args.scene,
                              against_scene=args.against_scene)
    except node_bench_paired.BenchError as exc:
        raise CommandLineError(str(exc)) from exc


def _node_parameter(text):
    """``name:=value`` for the node's --ros-args -p."""
    name, sep, value = text.partition(':=')
    if not sep or not name.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f'{text!r}: expected NAME:=VALUE, e.g. prediction.max_error:=0.02')
    return f'{name.strip()}:={value.strip()}'


def add_node_commands(commands):
    """Add ``drive`` and ``node-bench`` to the subparsers ``commands``."""
    drive = commands.add_parser('drive', help='publish a scripted needle insertion and retraction on needle/pose')
    drive.add_argument('--speed-mm-s', type=POSITIVE, required=True, help='needle speed [mm/s]')
    add_travel_or_depth(drive, default_help='one of the two is required')
    drive.add_argument('--start-height-mm', type=NON_NEGATIVE, default=None,
                       help="tip height above the surface at the start [mm] (default: the scene's)")
    drive.add_argument('--rate-hz', type=POSITIVE, default=100.0, help='pose rate [Hz] (default 100)')
    drive.add_argument('--hold-s', type=NON_NEGATIVE, default=0.5, help='pause at full depth [s] (default 0.5)')
    drive.add_argument('--wait-for-node-s', type=POSITIVE, default=10.0,
                       help='how long to wait for the node to publish its wrench and take the poses [s] '
                            '(default 10)')
    add_scene(drive, sets=False, help_text='scene the node runs (default: the packaged one)')
    drive.set_defaults(run=_drive)
    node_bench = commands.add_parser('node-bench', help='run the node as a process and print its timing figures')
    node_bench.add_argument('--duration-s', type=number(1, inclusive=True), default=20.0,
                            help='measured run length [s], at least 1 (default 20)')
    node_bench.add_argument('--rate-hz', type=POSITIVE, default=100.0, help='pose rate [Hz] (default 100)')
    add_scene(node_bench, sets=False, help_text='scene (default: the packaged one)')
    node_bench.add_argument('--threads', type=number(0, inclusive=True, whole=True), default=None,
                            help="the node's engine.threads (default: its parameter file's; 0 = auto)")
    node_bench.add_argument('--executor', choices=['events', 'single_threaded'], default=None,
                            help="the node's executor (default: its parameter file's)")
    node_bench.add_argument('--out', type=output_dir, default=None,
                            help='keep the MCAP log and a JSON of the figures here')
    node_bench.add_argument('--load', type=number(0, inclusive=True, whole=True), default=0, metavar='N',
                            help='run N busy processes and one listening ROS client (wrench, cloud) '
                                 'beside the node (default 0: none)')
    node_bench.add_argument('--listen', action='store_true',
                            help='run the listening ROS client (wrench, cloud) beside the node without busy '
                                 'processes: the node builds its cloud only for a subscriber')
    node_bench.add_argument('--predictions', type=number(0, inclusive=True, whole=True), default=0, metavar='N',
                            help='send N candidate paths on plan/candidate at once, 1 s into the window, '
                                 'and report how fast they are answered (default 0: none)')
    node_bench.add_argument('--prediction-s', type=POSITIVE, default=10.0,
                            help='length of each candidate path [s] (default 10)')
    node_bench.add_argument('--param', action='append', default=[], type=_node_parameter, metavar='NAME:=VALUE',
                            help='another node parameter (repeatable), as ros-args -p takes it, e.g. '
                                 'prediction.max_error:=0.02')
    node_bench.add_argument('--against', default=None, metavar='REV',
                            help='also run git revision REV of this checkout, alternating with this one, and '
                                 'compare the node CPU pair by pair (needs --out)')
    node_bench.add_argument('--against-scene', default=None, metavar='SCENE',
                            help='also run this checkout on SCENE, alternating with --scene, and compare the '
                                 "node CPU pair by pair: what a scene's option costs (needs --out)")
    node_bench.add_argument('--pairs', type=number(1, inclusive=True, whole=True), default=None, metavar='N',
                            help='pairs of runs with --against or --against-scene (default 3)')
    node_bench.set_defaults(run=_node_bench)
