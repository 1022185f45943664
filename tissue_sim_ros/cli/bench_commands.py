"""``tissue-sim bench [BENCHMARK]``: every benchmark of :mod:`tissue_sim_ros.bench` but the
node's (``tissue-sim node-bench``, :mod:`.node_commands`). Each prints its figures; none asserts
a time. ``tissue-sim bench`` alone (with its options) is the speed benchmark."""
from tissue_sim_ros.cli.arguments import POSITIVE, add_scene, number, output_dir
from tissue_sim_ros.errors import CommandLineError

__all__ = ['add_bench_commands']


def _speed(args):
    from tissue_sim_ros.bench import speed
    unknown = [m for m in args.models or () if m not in speed.MODELS]
    if unknown:
        raise CommandLineError(f'--models {" ".join(unknown)}: unknown; expected some of '
                               f'{", ".join(speed.MODELS)}')
    speed.run(sizes=args.sizes, models=args.models, precisions=args.precision)


def _cold_start(args):
    from tissue_sim_ros.bench import cold_start
    cold_start.main(scene=args.scene, modes=args.modes)


def _inertia(args):
    from tissue_sim_ros.bench import inertia
    inertia.main(scene=args.scene, sets=args.set, speed_mm_s=args.speed_mm_s, travel_mm=args.travel_mm,
                 scalings=args.scalings, jobs=args.jobs, out=args.out)


def _ripple(args):
    from tissue_sim_ros.bench import ripple
    ripple.main(scene=args.scene, sets=args.set, speed_mm_s=args.speed_mm_s)


def _study(args):
    from tissue_sim_ros.bench import study
    study.main(replay_s=args.replay_s, trials=args.trials, samples=args.samples, skip=args.skip)


def _calibration(args):
    from tissue_sim_ros.bench import calibration
    calibration.main(out=args.out, jobs=args.jobs)


def _organ(args):
    from tissue_sim_ros.bench import organ_scale
    unknown = [m for m in args.models if m not in organ_scale.MODELS]
    if unknown:
        raise CommandLineError(f'--models {" ".join(unknown)}: unknown; expected some of '
                               f'{", ".join(organ_scale.MODELS)}')
    organ_scale.main([int(s) for s in args.sizes], args.models, args.set, args.duration_s, args.out,
                     args.threads, args.accuracy, args.ladder)
def _robot_graph(args):
    from tissue_sim_ros.bench import robot_graph
    robot_graph.main(rounds=args.rounds, seconds=args.seconds, rate_hz=args.rate_hz, goals=args.goals)


def _steering(args):
    from tissue_sim_ros.bench import steering
    steering.main(parts=args.parts, depth_mm=args.depth_mm, speed_mm_s=args.speed_mm_s, jobs=args.jobs, out=args.out)


def _layered(args):
    from tissue_sim_ros.bench import layered
    layered.main(out=args.out, jobs=args.jobs, max_evaluations=args.max_evaluations, mesh=args.mesh,
                 layers=args.layers)


def _dask(args):
    from tissue_sim_ros.bench import study
    study.dask_main(out=args.out, workers=args.workers)


def _speed_options(parser):
    parser.add_argument('--sizes', nargs='+', choices=['1e3', '1e4', '1e5', '5e5'], default=None,
                        help='mesh sizes to run (default: all)')
    parser.add_argument('--models', nargs='+', default=None, metavar='MODEL',
                        help='models to run (default: all): linear, linear+visc, physical, physical+visc, '
                             'geometric, geometric+visc, full, full+visc, full+thr0.02')
    parser.add_argument('--precision', nargs='+', choices=['float64', 'float32'], default=['float64'],
                        help="the element pass's constants and arithmetic (default float64); two "
                             "(--precision float64 float32) are timed paired, in one process")


def add_bench_commands(commands):
    """Add ``bench`` and its benchmarks to the subparsers ``commands``."""
    bench = commands.add_parser('bench', help='benchmarks: speed per mesh size (default), cold-start, inertia, '
                                'ripple, study, calibration, layered, dask, robot-graph, steering')
    _speed_options(bench)
    bench.set_defaults(run=_speed)
    which = bench.add_subparsers(dest='benchmark', required=False, metavar='BENCHMARK')
    speed = which.add_parser('speed', help='force evaluation and explicit step per model and mesh size')
    _speed_options(speed)
    speed.set_defaults(run=_speed)
    cold = which.add_parser('cold-start', help='a fresh install\'s first start, compiles included')
    add_scene(cold, sets=False)
    cold.add_argument('--modes', nargs='+', choices=['parallel', 'one-process', 'warm'],
                      default=['parallel', 'one-process', 'warm'])
    cold.set_defaults(run=_cold_start)
    inertia = which.add_parser('inertia', help="the mass scaling's estimated inertia error against the error "
                               'it adds')
    add_scene(inertia)
    inertia.add_argument('--speed-mm-s', type=POSITIVE, default=5.0, help='needle speed [mm/s] (default 5)')
    inertia.add_argument('--travel-mm', type=POSITIVE, default=17.0, help='tip travel [mm] (default 17)')
    inertia.add_argument('--scalings', type=number(1), nargs='+', default=[25.0, 100.0, 400.0, 1600.0],
                         help='mass scalings to measure, each above 1 (default 25 100 400 1600)')
    inertia.add_argument('--jobs', type=number(1, inclusive=True, whole=True), default=None,
                         help='worker processes (default: the cores)')
    inertia.add_argument('--out', type=output_dir, default='out/bench_inertia', help='output directory')
    inertia.set_defaults(run=_inertia)
    ripple = which.add_parser('ripple', help='how smooth the axial force is after a puncture')
    add_scene(ripple)
    ripple.add_argument('--speed-mm-s', type=POSITIVE, default=3.0, help='needle speed [mm/s] (default 3)')
    ripple.set_defaults(run=_ripple)
    study = which.add_parser('study', help='replay and compare timings')
    study.add_argument('--replay-s', type=POSITIVE, default=60.0, help='length of the replayed node log [s]')
    study.add_argument('--trials', type=number(1, inclusive=True, whole=True), default=30)
    study.add_argument('--samples', type=number(1, inclusive=True, whole=True), default=5000)
    study.add_argument('--skip', choices=['replay', 'compare'], default=None)
    study.set_defaults(run=_study)
    calibration = which.add_parser('calibration', help='calibrate on synthetic data with known values')
    calibration.add_argument('--out', type=output_dir, default='out/bench_calibration', help='output directory')
    calibration.add_argument('--jobs', type=number(1, inclusive=True, whole=True), default=None)
    calibration.set_defaults(run=_calibration)
    organ = which.add_parser('organ', help='the node at organ scale: each model on the organ example meshed at '
                             'each size, under node-bench; the largest mesh that holds 50 Hz per model')
    organ.add_argument('--sizes', type=number(100, whole=True), nargs='+', default=[25000, 50000, 100000],
                       help='tetrahedra to aim at (default 25000 50000 100000)')
    organ.add_argument('--models', nargs='+', default=['linear', 'physical', 'geometric', 'full'],
                       help='models (default: linear physical geometric full)')
    organ.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                       help='a scene value for every run (e.g. model.precision=float32, solver.mass_scaling=1600)')
    organ.add_argument('--duration-s', type=number(1, inclusive=True), default=20.0,
                       help='measured window of each run [s] (default 20)')
    organ.add_argument('--threads', type=number(0, inclusive=True, whole=True), default=None,
                       help="the node's engine.threads (default: its parameter file's)")
    organ.add_argument('--accuracy', action='store_true',
                       help="also run the insertion offline: each row's estimated inertia error and, with "
                       '--set, its axial-force NRMSE against the scene as configured')
    organ.add_argument('--ladder', action='store_true',
                       help="the node's degradation ladder on (default off: whether the scene's own settings "
                       'keep real time)')
    organ.add_argument('--out', type=output_dir, default='out/bench_organ', help='output directory')
    organ.set_defaults(run=_organ)
    graph = which.add_parser('robot-graph',
                             help='TF input against the pose topic; the action against the topic '
                             'pair (paired)')
    graph.add_argument('--rounds', type=number(1, inclusive=True, whole=True), default=3, help='paired runs')
    graph.add_argument('--seconds', type=POSITIVE, default=1.2, help='length of each insertion [s]')
    graph.add_argument('--rate-hz', type=POSITIVE, default=1000.0, help="the robot's rate (default 1000)")
    graph.add_argument('--goals', type=number(1, inclusive=True, whole=True), default=6,
                       help='predictions asked each way')
    graph.set_defaults(run=_robot_graph)
    steering = which.add_parser('steering', help="a flexible needle's figures: in air, its bend in the default "
                                'tissue, curvature trends, a 180-degree flip, the step cost with the rod')
    steering.add_argument('--parts', nargs='+', choices=['air', 'tissue', 'phantom', 'flip', 'cost'],
                          default=['air', 'tissue', 'phantom', 'flip', 'cost'], help='which figures (default: all)')
    steering.add_argument('--depth-mm', type=POSITIVE, default=80.0,
                          help='insertion depth below the surface in the default tissue [mm] (default 80)')
    steering.add_argument('--speed-mm-s', type=POSITIVE, default=5.0, help='needle speed [mm/s] (default 5)')
    steering.add_argument('--jobs', type=number(1, inclusive=True, whole=True), default=None,
                          help='worker processes (default: the cores)')
    steering.add_argument('--out', type=output_dir, default=None, help='keep the figures as DIR/steering.json')
    steering.set_defaults(run=_steering)
    layered = which.add_parser('layered', help='propose and calibrate on synthetic two- and three-layer phantoms '
                               'with known values')
    layered.add_argument('--out', type=output_dir, default='out/bench_layered', help='output directory')
    layered.add_argument('--jobs', type=number(1, inclusive=True, whole=True), default=None)
    layered.add_argument('--max-evaluations', type=number(10, inclusive=True, whole=True), default=110,
                         help="the 8-key calibration's budget (default 110)")
    layered.add_argument('--mesh', choices=['graded', 'fine'], default='graded',
                         help="the phantoms' mesh: 'graded' (5880 tetrahedra, default) or 'fine' (14520, a 1.65 mm "
                              "cell around the needle: the layers' moduli act less alike; about 3.7x the time)")
    layered.add_argument('--layers', type=int, nargs='+', choices=[2, 3], default=[2, 3],
                         help='which phantoms, by their layer count (default: both)')
    layered.set_defaults(run=_layered)
    dask = which.add_parser('dask', help='compare in this process, on a process pool and on a local Dask '
                            'scheduler with its own workers')
    dask.add_argument('--out', type=output_dir, default='out/bench_dask', help='output directory')
    dask.add_argument('--workers', type=number(1, inclusive=True, whole=True), default=2,
                      help='Dask workers (one thread each) and pool processes (default 2)')
    dask.set_defaults(run=_dask)
