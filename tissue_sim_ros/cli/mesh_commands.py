"""``tissue-sim mesh`` (a closed surface to a tagged tetrahedral mesh with a quality report) and
``tissue-sim organ-example`` (the project's own organ surfaces, meshed: config/organ_example.vtu)."""
import argparse

from tissue_sim_ros.cli.arguments import POSITIVE, input_file
from tissue_sim_ros.errors import CommandLineError

__all__ = ['add_mesh_commands']


def _triple(text):
    try:
        values = [float(v) for v in text.split(',')]
    except ValueError:
        values = []
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f'{text!r}: expected X,Y,Z (three numbers)')
    return values


def _inclusion(text):
    name, _, path = text.partition('=')
    if not name or not path or not name.replace('_', 'a').isalnum():
        raise argparse.ArgumentTypeError(f'{text!r}: expected NAME=SURFACE (a name of letters, digits and _)')
    return name, input_file(path)


def _mesh(args):
    from tissue_sim_ros.meshing.volume import mesh_surface
    names = [name for name, _ in args.inclusion]
    if len(set(names)) != len(names) or 'organ' in names:
        raise CommandLineError(f'--inclusion names {names}: expected unique names other than organ')
    mesh_surface(args.surface, args.out, units=args.units, scale=args.scale,
                 cell_m=None if args.cell_mm is None else args.cell_mm * 1e-3,
                 fine_m=None if args.fine_mm is None else args.fine_mm * 1e-3, along=args.along, focus=args.focus,
                 radius_m=None if args.radius_mm is None else args.radius_mm * 1e-3, inclusions=args.inclusion,
                 epsilon=args.epsilon, coarsen=args.coarsen, threads=args.threads)


def _organ_example(args):
    from tissue_sim_ros.meshing.organ import write_example
    write_example(args.out, args.mesh, cell_m=args.cell_mm * 1e-3, fine_m=args.fine_mm * 1e-3,
                  radius_m=args.radius_mm * 1e-3, threads=args.threads)


def add_mesh_commands(commands):
    mesh = commands.add_parser('mesh', help='a tetrahedral mesh from a closed surface (STL, OBJ, PLY, VTK): '
                               'repaired or refused, inclusions tagged, graded, with a quality report')
    mesh.add_argument('surface', type=input_file, help='the organ surface (closed; small holes are closed)')
    mesh.add_argument('--out', required=True, help='the mesh file (.vtu, .msh, .vtk, ...); the report is written '
                                                   'beside it as .quality.json')
    mesh.add_argument('--units', choices=('mm', 'cm', 'm'), default=None,
                      help='units of the surface files (default: metres; a surface too large for metres is refused)')
    mesh.add_argument('--scale', type=POSITIVE, default=1.0, help='a factor on the surfaces (after --units)')
    mesh.add_argument('--cell-mm', type=POSITIVE, default=None,
                      help="the elements' ideal edge length [mm] (default: the bounding-box diagonal / 20); a "
                           'volume V makes about V / (0.118 cell^3) tetrahedra')
    mesh.add_argument('--fine-mm', type=POSITIVE, default=None, help='the edge length [mm] near --along or --focus')
    where = mesh.add_mutually_exclusive_group()
    where.add_argument('--along', type=input_file, default=None,
                       help='a planned needle path: CSV rows x,y,z in the surface units')
    where.add_argument('--focus', type=_triple, default=None, help='X,Y,Z in the surface units')
    mesh.add_argument('--radius-mm', type=POSITIVE, default=None,
                      help='the fine zone around the path or focus [mm] (default 4 x --fine-mm)')
    mesh.add_argument('--inclusion', type=_inclusion, action='append', default=[], metavar='NAME=SURFACE',
                      help='a closed surface inside the organ (a tumour, a vessel): its elements are tagged 2, 3, '
                           '... in the order given (the organ 1); repeat for several')
    mesh.add_argument('--epsilon', type=POSITIVE, default=None,
                      help="fTetWild's envelope relative to the bounding-box diagonal (default 1e-3, less for small "
                           'inclusions)')
    mesh.add_argument('--coarsen', action='store_true',
                      help="fTetWild's coarsening pass: fewer elements, somewhat lower quality")
    mesh.add_argument('--threads', type=int, default=0, help='mesher threads (default 0: all cores)')
    mesh.set_defaults(run=_mesh)
    example = commands.add_parser('organ-example', help="the project's organ-like surfaces (organ, tumour, vessel) "
                                  'and the planned path, written and meshed for config/organ_example.yaml')
    example.add_argument('--out', default='organ_example', help='folder for the surfaces, path and report')
    example.add_argument('--mesh', default=None, help='the mesh file (default: OUT/organ_example.vtu)')
    example.add_argument('--cell-mm', type=POSITIVE, default=12.0, help='edge length away from the path (default 12)')
    example.add_argument('--fine-mm', type=POSITIVE, default=2.5, help='edge length along the path (default 2.5)')
    example.add_argument('--radius-mm', type=POSITIVE, default=5.0, help='the fine zone round the path (default 5)')
    example.add_argument('--threads', type=int, default=0, help='mesher threads (default 0: all cores)')
    example.set_defaults(run=_organ_example)
