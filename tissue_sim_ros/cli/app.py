"""``tissue-sim``: the parser, the dispatch, and one line for any refusal (exit status 2).

Thin: each command is a call into the layers below with the options it was given."""
import signal
import sys
import threading
from pathlib import Path

from tissue_sim_ros.cli.arguments import (NON_NEGATIVE, POSITIVE, Parser, add_max_depth, add_pool_and_out,
                                          add_scene, add_travel_or_depth, depth_below_surface, input_file,
                                          number, output_dir, travel_and_depth)
from tissue_sim_ros.cli.bench_commands import add_bench_commands
from tissue_sim_ros.cli.mesh_commands import add_mesh_commands
from tissue_sim_ros.cli.node_commands import add_node_commands
from tissue_sim_ros.errors import CommandLineError, SimulationDiverged, TissueSimError


def _compress(args):
    from tissue_sim_ros.analysis.charting.compression import plate_compression, plot_compression
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    result = plate_compression(final_strain=args.strain, speed=args.speed_mm_s * 1e-3)
    print(f'plate compression of a liver-like block: {result.n_elements} tetrahedra, dt = {result.time_step:.3g} s')
    print(f'{"travel [mm]":>12} {"reaction [N]":>13} {"E A strain [N]":>15}')
    for k in range(0, len(result.time), max(1, len(result.time) // 10)):
        print(f'{result.plate_travel[k] * 1e3:>12.3f} {result.reaction[k]:>13.5f} '
              f'{result.expected_slope * result.plate_travel[k]:>15.5f}')
    print(f'final reaction {result.reaction[-1]:.5f} N at {result.plate_travel[-1] * 1e3:.3f} mm after the hold; '
          f'simulated {result.time[-1]:.3f} s in {result.wall_time:.2f} s wall '
          f'(real-time factor {result.time[-1] / result.wall_time:.1f})')
    plot_compression(result, out / 'compression.png')
    print(f'wrote {out / "compression.png"}')


def _insert(args):
    from tissue_sim_ros.analysis.insert import main
    travel, depth = travel_and_depth(args)       # neither: the scene's planned travel, else 35 mm
    main(args.scene, args.speed_mm_s, args.out, travel_mm=travel, depth_mm=depth, hold_s=args.hold_s,
         sets=args.set)


def _demo(args):
    from tissue_sim_ros.analysis.demo import run
    run(args.out, args.speed_mm_s, depth_below_surface(args, None, 15.0))


def _scene_keys(args):
    from tissue_sim_ros.engine.scene.schema import describe_keys, keys_markdown
    print(keys_markdown() if args.markdown else '\n'.join(describe_keys()), end='' if args.markdown else '\n')


def _compare(args):
    from tissue_sim_ros.analysis.compare.compare import main
    if bool(args.data_spec) == bool(args.files):
        raise CommandLineError('give --data-spec SPEC.yaml or data files (with column options), not both')
    options = {'time.column': _column(args.time_column), 'time.unit': args.time_unit,
               'time.rate_hz': args.rate_hz, 'force.column': _column(args.force_column),
               'force.columns': None if args.force_columns is None else [_column(c) for c in args.force_columns],
               'force.unit': args.force_unit, 'force.sign': args.force_sign, 'force.reduce': args.reduce,
               'force.direction': args.direction,
               'position.column': _column(args.position_column), 'position.unit': args.position_unit,
               'position.sign': args.position_sign if args.position_column is not None else None,
               'motion.speed_mm_s': args.speed_mm_s, 'motion.travel_mm': args.motion_travel_mm,
               'motion.start_s': args.start_s, 'motion.hold_s': args.hold_s,
               'motion.retract': True if args.retract else None,
               'file_name.pattern': args.file_pattern}
    main(data_spec=args.data_spec, files=args.files, options=options, scene_file=args.scene,
         sets=args.set, align=args.align, gap_mm=args.start_gap_mm, max_depth_mm=args.max_depth_mm,
         per_trial=args.per_trial, simulated_repeats=args.simulated_repeats,
         tick_ms=args.tick_ms, workers=args.jobs, scheduler=args.scheduler, out=args.out)


def _concrete(args):
    """(scene file, sets) the studies below reload in their workers: the scene's auto keys
    chosen first, into DIR/scene.yaml, when it has any."""
    from tissue_sim_ros.analysis.charting.auto_keys import concrete_scene_file
    return concrete_scene_file(args.scene, args.set, args.out)


def _chart(args):
    from tissue_sim_ros.analysis.charting.chart import main
    scene_file, sets = _concrete(args)
    return main(scene_file=scene_file, sets=sets, quick=args.quick, speed_mm_s=args.speed_mm_s,
                travel_mm=args.travel_mm, out=args.out, workers=args.jobs, scheduler=args.scheduler,
                reference_selective=args.reference_selective, row_limit_min=args.row_limit_min)


def _recommend(args):
    from tissue_sim_ros.analysis.charting.recommend import main
    scene_file, sets = _concrete(args)
    return main(scene_file=scene_file, sets=sets, tolerance=args.tolerance, rate_hz=args.rate_hz,
                quick=args.quick, speed_mm_s=args.speed_mm_s, travel_mm=args.travel_mm, out=args.out,
                workers=args.jobs, scheduler=args.scheduler, reference_selective=args.reference_selective,
                row_limit_min=args.row_limit_min)


def _stability(args):
    from tissue_sim_ros.analysis.charting.stability import main
    scene_file, sets = _concrete(args)
    return main(scene_file=scene_file, sets=sets, quick=args.quick, speed_mm_s=args.speed_mm_s, out=args.out,
                workers=args.jobs, scheduler=args.scheduler)


def _calibrate(args):
    from tissue_sim_ros.analysis.calibration.calibrate import parse_phase_weights, main
    try:
        parse_phase_weights(args.phase_weight)
    except ValueError as exc:
        raise CommandLineError(str(exc)) from None
    main(data_spec=args.data_spec, fits=args.fit, validate_spec=args.validate_spec,
         leave_one_speed_out=args.leave_one_speed_out, scene_file=args.scene,
         sets=args.set, coarse_sets=args.coarse_set, align=args.align, gap_mm=args.start_gap_mm,
         max_depth_mm=args.max_depth_mm,
         tick_ms=args.tick_ms, phase_weights=args.phase_weight, inertia_bound=args.inertia_bound,
         global_search=args.global_search, max_evaluations=args.max_evaluations, per_repeat=args.per_repeat,
         refit_steps=args.refit_steps, fine_steps=args.fine_steps, workers=args.jobs,
         scheduler=args.scheduler, out=args.out)


def _propose(args):
    from tissue_sim_ros.analysis.calibration.propose import main
    main(data_spec=args.data_spec, scene_file=args.scene, sets=args.set, out=args.out, refine_runs=args.refine_runs,
         align=args.align, max_depth_mm=args.max_depth_mm, tick_ms=args.tick_ms, workers=args.jobs,
         scheduler=args.scheduler)


def _data_keys(args):
    from tissue_sim_ros.io.trials.data_spec_keys import data_keys_markdown, describe_data_keys
    print(data_keys_markdown() if args.markdown else '\n'.join(describe_data_keys()), end='' if args.markdown else '\n')


def _inspect(args):
    from tissue_sim_ros.analysis.compare.inspect_data import main
    main(data_spec=args.data_spec, out=args.out)


def _column(text):
    """A column option: a 0-based index when it is a whole number, else a header name."""
    if text is None:
        return None
    return int(text) if text.strip().isdigit() else text


def _predict(args):
    from tissue_sim_ros.analysis.predict import main
    main(args.scene, args.path, args.out, sets=args.set, wrench_frame=args.wrench_frame, max_error=args.max_error)


def _replay(args):
    from tissue_sim_ros.analysis.replay import main
    main(args.log, args.out, args.scene, args.set)


def _recover(args):
    from tissue_sim_ros.io.mcap.recovery import recover_log
    from tissue_sim_ros.errors import RecoverError
    try:
        _, line = recover_log(args.log, args.out)
    except RecoverError as exc:
        print(f'tissue-sim recover: error: {exc}', file=sys.stderr)
        sys.exit(2)
    print(line)


def build_parser():
    from tissue_sim_ros import __version__
    parser = Parser(prog='tissue-sim', description='Real-time tensor-mass soft-tissue simulation.')
    parser.add_argument('--version', action='version', version=f'tissue-sim {__version__}')
    commands = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    compress = commands.add_parser('compress', help='headless plate compression of a liver-like block, with a plot')
    compress.add_argument('--out', type=output_dir, default='out', help='output directory (default: out)')
    compress.add_argument('--strain', type=number(0, high=1), default=0.10,
                          help='final nominal strain (default 0.10)')
    compress.add_argument('--speed-mm-s', type=POSITIVE, default=10.0, help='plate speed [mm/s] (default 10)')
    compress.set_defaults(run=_compress)
    insert = commands.add_parser('insert', help='simulate a straight needle insertion and retraction (no ROS)')
    add_scene(insert)
    insert.add_argument('--speed-mm-s', type=POSITIVE, default=3.0, help='needle speed [mm/s] (default 3)')
    add_travel_or_depth(insert, default_help="default: the scene's needle.planned_travel_m, else --travel-mm 35; "
                                              'the default scene starts 9 mm above the tissue')
    insert.add_argument('--hold-s', type=NON_NEGATIVE, default=0.0,
                        help='pause at the deepest point before retracting [s] (default 0)')
    insert.add_argument('--out', type=output_dir, default='out', help='output directory for insert.csv, .png, .md and .json (default: out)')
    insert.set_defaults(run=_insert)
    demo = commands.add_parser('demo', help='the main job: node + scripted insertion + MCAP read back, summary and plot')
    demo.add_argument('--out', type=output_dir, default='out', help='output directory (default: out)')
    demo.add_argument('--speed-mm-s', type=POSITIVE, default=5.0, help='needle speed [mm/s] (default 5)')
    add_travel_or_depth(demo, default_help='default 15')
    demo.set_defaults(run=_demo)
    keys = commands.add_parser('scene-keys', help='list every scene-file key with its default and meaning')
    keys.add_argument('--markdown', action='store_true', help='as the tables of docs/scenes.md')
    keys.set_defaults(run=_scene_keys)
    recover = commands.add_parser('recover', help='repair an MCAP log cut short (a hard kill): keep '
                                  'every intact message, print what was kept and lost')
    recover.add_argument('log', metavar='LOG.mcap', help='the log to repair (read only)')
    recover.add_argument('--out', default=None, metavar='REPAIRED.mcap',
                         help='the repaired copy, a new file (default: LOG.recovered.mcap '
                              'beside the log; none for a complete log)')
    recover.set_defaults(run=_recover)
    compare = commands.add_parser('compare', help='simulate the measured motion of load-cell trials and '
                                  'report how far the model is from the data, beside the data\'s spread')
    compare.add_argument('files', nargs='*', metavar='FILE', help='data files (CSV/TSV/text or MCAP) '
                         'read with the column options below; or give --data-spec')
    compare.add_argument('--data-spec', type=input_file, default=None, metavar='SPEC.yaml',
                         help='a data description of the whole study (docs/data.md: describing your '
                              'load-cell data)')
    add_scene(compare)
    compare.add_argument('--align', choices=['contact', 'xcorr', 'depth'], default='contact',
                         help='contact: same time since contact; xcorr: then the lag of best '
                              'correlation (<= 0.5 s); depth: force against depth, insertion only')
    compare.add_argument('--start-gap-mm', type=NON_NEGATIVE, default=None,
                         help="the data's travel at contact [mm] (default: found in the force)")
    add_max_depth(compare)
    compare.add_argument('--per-trial', action='store_true',
                         help="simulate every trial's own motion (default: one simulation per speed)")
    compare.add_argument('--tick-ms', type=POSITIVE, default=10.0, help='simulation sampling [ms] (default 10)')
    compare.add_argument('--simulated-repeats', type=number(0, inclusive=True, whole=True), default=0,
                         help="with a scene that states its spread (regions[].membrane.rupture_force_spread_n, "
                              "regions[].depth_spread_m): simulate each speed this many times more, with "
                              "variation.seed 1..N, and set their punctures' spread beside the repeats' (default 0)")
    add_pool_and_out(compare, 'out/compare')
    columns = compare.add_argument_group('columns of the data files (without --data-spec)')
    columns.add_argument('--time-column', default=None, help='time column: header name or 0-based index')
    columns.add_argument('--time-unit', default=None, help='s, ms, us, ns (default s)')
    columns.add_argument('--rate-hz', type=POSITIVE, default=None, help='sample rate when there is no time column')
    columns.add_argument('--force-column', default=None, help='the axial force column')
    columns.add_argument('--force-columns', nargs=3, default=None, metavar=('FX', 'FY', 'FZ'),
                         help='three force columns, reduced by --reduce')
    columns.add_argument('--force-unit', default=None, help='N, mN, kN, gf, kgf, lbf, ozf (default N)')
    columns.add_argument('--force-sign', type=int, choices=[1, -1], default=None,
                         help='+1 or -1: makes the force positive while the tissue resists')
    columns.add_argument('--reduce', choices=['norm', 'projection'], default=None)
    columns.add_argument('--direction', type=float, nargs=3, default=None, metavar=('X', 'Y', 'Z'),
                         help='--reduce projection: the needle axis in the sensor frame')
    columns.add_argument('--position-column', default=None, help='needle travel column (optional)')
    columns.add_argument('--position-unit', default=None, help='m, mm, um, cm, in (default m)')
    columns.add_argument('--position-sign', type=int, choices=[1, -1], default=1)
    columns.add_argument('--speed-mm-s', type=POSITIVE, default=None, help='without a position: stage speed')
    columns.add_argument('--motion-travel-mm', type=POSITIVE, default=None, help='without a position: stage travel')
    columns.add_argument('--start-s', type=NON_NEGATIVE, default=None, help='without a position: stage start time')
    columns.add_argument('--hold-s', type=NON_NEGATIVE, default=None, help='without a position: pause at depth')
    columns.add_argument('--retract', action='store_true', help='without a position: the stage came back')
    columns.add_argument('--file-pattern', default=None,
                         help='a regular expression with named groups speed and repeat, searched in the file names')
    compare.set_defaults(run=_compare)
    calibrate = commands.add_parser('calibrate', help='fit scene keys to load-cell trials (several speeds '
                                    'at once), cross-validated on held-out speeds')
    calibrate.add_argument('--data-spec', type=input_file, required=True, metavar='FIT.yaml',
                           help='the data description of the trials to fit')
    calibrate.add_argument('--validate-spec', type=input_file, default=None, metavar='HELD_OUT.yaml',
                           help='trials to predict, not fitted (e.g. another speed)')
    calibrate.add_argument('--leave-one-speed-out', action='store_true',
                           help='cross-validate: first calibrate once per speed without it and predict it '
                                '(each in DIR/leave_out_<speed>; one calibration per speed more), then on all')
    calibrate.add_argument('--fit', action='append', default=[], required=True, metavar='KEY=LOW:HIGH[:log]',
                           help='a scene key to fit and its bounds (repeatable), e.g. '
                                'regions[0].young_modulus_pa=5000:50000:log')
    add_scene(calibrate, help_text='starting scene YAML (default: the packaged one)')
    calibrate.add_argument('--coarse-set', action='append', default=[], metavar='KEY=VALUE',
                           help='search on a cheaper scene (e.g. mesh.fine_size_m=0.003), then finish on '
                                'the scene as asked (repeatable)')
    calibrate.add_argument('--align', choices=['contact', 'xcorr', 'depth'], default='contact',
                           help="how simulation and data are put side by side (compare's --align)")
    calibrate.add_argument('--start-gap-mm', type=NON_NEGATIVE, default=None,
                           help='travel from the start to contact, when known (default: from the force)')
    add_max_depth(calibrate)
    calibrate.add_argument('--tick-ms', type=POSITIVE, default=10.0, help='simulation sampling [ms] (default 10)')
    calibrate.add_argument('--phase-weight', action='append', default=[], metavar='PHASE=W',
                           help='weight of a phase in the objective (approach, loading, inserted, hold, '
                                'retraction; default 1 each)')
    calibrate.add_argument('--inertia-bound', type=POSITIVE, default=0.02,
                           help="the mass scaling's inertia error allowed, as a fraction of the force "
                                'range (default 0.02)')
    calibrate.add_argument('--global', dest='global_search', nargs='?', const='de', default=False,
                           choices=['de', 'optuna'],
                           help='start with a global search for hard cases: de (differential evolution, the '
                                'default) or optuna (its TPE sampler; needs optuna installed)')
    calibrate.add_argument('--max-evaluations', type=number(1, inclusive=True, whole=True), default=150,
                           help='parameter vectors the search may evaluate (each: one simulation per '
                                'speed; default 150); then the best so far is the result')
    calibrate.add_argument('--per-repeat', action='store_true',
                           help="simulate each repeat with its own layers' rupture forces and depths, matched "
                                'to its punctures at the start (one simulation per repeat per evaluation, and 3 '
                                'evaluations to match): the spread between repeats does not pull the shared '
                                'keys; the scene written is the mean repeat with the matched spread')
    calibrate.add_argument('--refit-steps', type=number(0, inclusive=True, whole=True), default=3,
                           help='with --coarse-set: Gauss-Newton steps of the loading keys\' re-fit on the '
                                'scene as asked, on the loading (its simulations stop at the first puncture; '
                                'default 3; 0: none)')
    calibrate.add_argument('--fine-steps', type=number(0, inclusive=True, whole=True), default=3,
                           help="with --coarse-set: then Gauss-Newton steps on the scene as asked from its "
                                'own Jacobian where they start (one evaluation per key, which also gives the '
                                "standard errors), updated by Broyden's rule, one evaluation each (default 3; 0: "
                                "none, standard errors from that scene's Jacobian at the re-fitted point)")
    add_pool_and_out(calibrate, 'out/calibrate')
    calibrate.set_defaults(run=_calibrate)
    propose = commands.add_parser('propose', help='a layered scene proposed from load-cell data: the layers the '
                                  'repeats share, starting values from the curves, refined by a few simulations; '
                                  'the start calibrate takes')
    propose.add_argument('--data-spec', type=input_file, required=True, metavar='SPEC.yaml',
                         help='the data description of the study (docs/data.md)')
    add_scene(propose, help_text="base scene: its mesh, model, solver and needle (default: the packaged one)")
    propose.add_argument('--refine-runs', type=number(0, inclusive=True, whole=True), default=3,
                         help='simulations that refine the starting values, each value moved by what its feature '
                              'misses (default 3; 0: the values read from the data)')
    propose.add_argument('--align', choices=['contact', 'xcorr', 'depth'], default='contact',
                         help="how simulation and data are put side by side (compare's --align)")
    add_max_depth(propose)
    propose.add_argument('--tick-ms', type=POSITIVE, default=10.0, help='simulation sampling [ms] (default 10)')
    add_pool_and_out(propose, 'out/propose')
    propose.set_defaults(run=_propose)
    data_keys = commands.add_parser('data-keys', help='list every key of a data description with its default '
                                    'and meaning')
    data_keys.add_argument('--markdown', action='store_true', help="as the table of docs/data.md")
    data_keys.set_defaults(run=_data_keys)
    inspect = commands.add_parser('inspect', help='what a data description reads: trials, speeds, units, ranges, '
                                  'contact, punctures and layers, without a simulation')
    inspect.add_argument('--data-spec', type=input_file, required=True, metavar='SPEC.yaml',
                         help='the data description of the study (docs/data.md)')
    inspect.add_argument('--out', type=output_dir, default='out/inspect', help='output directory (default out/inspect)')
    inspect.set_defaults(run=_inspect)
    replay = commands.add_parser('replay', help='run a recorded node log through the engine again: '
                                 'the same wrenches (exact), or the same motion through --scene/--set')
    replay.add_argument('log', type=input_file, metavar='LOG.mcap', help='a log the node recorded (or '
                        'any rosbag2 MCAP with needle/wrench and needle/pose)')
    replay.add_argument('--out', type=output_dir, default='out/replay',
                        help='output directory: replay.mcap, .csv, .png, .json, .md (default out/replay)')
    add_scene(replay, help_text="another scene for the same motion (default: the log's own scene)")
    replay.set_defaults(run=_replay)
    predict = commands.add_parser('predict', help='what a candidate needle path would do (force, tip '
                                  'depth, target displacements) from the scene at rest, as the node '
                                  'answers on plan/candidate')
    add_scene(predict)
    predict.add_argument('--path', type=input_file, required=True,
                         help='CSV of the needle base poses: t, x, y, z, qx, qy, qz, qw (s, m; the first '
                              "pose the scene's initial one; example: config/candidate_path.csv)")
    predict.add_argument('--wrench-frame', choices=['needle', 'world'], default='needle',
                         help="the force and torque's frame (default needle, as the node's wrench.frame_id)")
    predict.add_argument('--max-error', type=NON_NEGATIVE, default=0.0,
                         help="run on the cheapest degradation-ladder rung whose measured error (NRMSE of "
                              'the axial force against the scene as configured) is within this, as the '
                              "node's prediction.max_error (default 0: as configured)")
    predict.add_argument('--out', type=output_dir, default='out/predict',
                         help='output directory for predict.csv, .png, .md, .json (default: out/predict)')
    predict.set_defaults(run=_predict)
    _add_model_studies(commands)
    add_bench_commands(commands)
    add_node_commands(commands)
    add_mesh_commands(commands)
    return parser


def _add_model_studies(commands):
    """chart, recommend and stability: studies of the models and methods on a scene."""
    def study(name, help_text, quick_help, run, out_default, extra_out_help=''):
        parser = commands.add_parser(name, help=help_text)
        add_scene(parser)
        parser.add_argument('--quick', action='store_true', help=quick_help)
        parser.add_argument('--speed-mm-s', type=POSITIVE, default=5.0, help='needle speed [mm/s] (default 5)')
        add_pool_and_out(parser, out_default, extra_out_help)
        parser.set_defaults(run=run)
        return parser

    chart = study('chart', "speed against accuracy over models, meshes, time steps and integrators on the "
                  "scene's insertion and a plate compression, with the Pareto front",
                  "three mesh levels, the reference on the scene's mesh (under 5 minutes on 2 cores)",
                  _chart, 'out/chart')
    chart.add_argument('--travel-mm', type=POSITIVE, default=None,
                       help="tip travel from 1 mm above the surface [mm] (default: the scene's "
                            'needle.planned_travel_m from its start pose, else 12: past the default '
                            "scene's capsule puncture)")
    recommend = study('recommend', 'the cheapest model, mesh, step and integrator within a force error '
                      'tolerance that keeps real time (runs the chart)', "the chart's quick preset", _recommend,
                      'out/recommend', '; the chart in its chart/')
    recommend.add_argument('--tolerance', type=POSITIVE, default=0.05,
                           help="the force NRMSE allowed against the chart's reference (default 0.05)")
    recommend.add_argument('--rate-hz', type=POSITIVE, default=50.0, help="the node's tick rate (default 50)")
    recommend.add_argument('--travel-mm', type=POSITIVE, default=None,
                           help="tip travel [mm] (default: the scene's planned travel, else 12)")
    for parser in (chart, recommend):
        parser.add_argument('--reference-selective', type=number(1, inclusive=True), default=1.0, metavar='R',
                            help='the reference run with selective mass scaling R (solver.selective_mass_scaling): '
                                 "for an organ mesh with viscosity, whose unscaled step is microseconds; its "
                                 'estimated inertia error is reported (default 1: none)')
        parser.add_argument('--row-limit-min', type=POSITIVE, default=None, metavar='MIN',
                            help='stop an insertion row other than the reference after MIN minutes of wall '
                                 'time; it is reported as stopped (default: none)')
    study('stability', "each model's and integrator's largest stable time step against the estimate, and "
          'induced failures (caught or survived)', 'the coarse mesh and shorter searches (under 5 minutes on '
          '2 cores)', _stability, 'out/stability')


def _describe(exc):
    """One line for an error: an OSError names its file; other messages fold onto one line."""
    if isinstance(exc, OSError) and exc.filename is not None:
        text = f'{exc.filename}: {exc.strerror or exc}'
    else:
        text = str(exc)
    if isinstance(exc, SimulationDiverged) and 'inverted' in text:
        text += ('; a small-strain model inverts elements at large deformation: '
                 'model.geometric: true handles it')
    return ' '.join(text.split())


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread so that the command ends as from Ctrl-C: its worker
    processes stopped, its outputs closed (a resumable study resumes)."""


def _on_sigterm(signum, frame):
    raise _Terminated


def main(argv=None):
    """Run a command; bad input (a scene, a mesh, a file, a value), a diverged simulation or a
    node that would not start is one error line naming it (exit status 2), not a traceback;
    Ctrl-C and SIGTERM end it cleanly (130, 143)."""
    args = build_parser().parse_args(argv)
    previous = signal.signal(signal.SIGTERM, _on_sigterm) if threading.current_thread() is threading.main_thread() \
        else None
    try:
        args.run(args)
    except KeyboardInterrupt:
        print(f'tissue-sim {args.command}: interrupted', file=sys.stderr)
        return 130
    except _Terminated:
        print(f'tissue-sim {args.command}: terminated', file=sys.stderr)
        return 128 + signal.SIGTERM
    except (TissueSimError, OSError) as exc:
        print(f'tissue-sim {args.command}: error: {_describe(exc)}', file=sys.stderr)
        return 2
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return 0
