"""A scene: YAML description -> mesh, regions, model, boundary conditions, solver and needle.

Every key a scene file may hold is in :data:`~tissue_sim_ros.engine.scene.schema.SCHEMA`, with
its default and meaning (the one place they are documented; ``tissue-sim scene-keys`` prints them). Files are safe-loaded;
unknown keys are refused with their dotted name; units are SI and every dimensional key says its
unit in its name. ``config/liver_sample.yaml`` is the default scene.

The scene is the engine's whole-step API: ``advance(duration, position, orientation)`` moves the
needle base linearly (orientation by slerp) from its current pose to the given one over
``duration`` seconds, stepping the tissue with the fixed time step ``dt``.

Several needles (scene key ``needles``): each is a NeedleTissue of its own (contact, punctures,
shaft points, friction) on the same tissue, in ``needles`` (``needle`` is the first, the one
``advance``'s position and orientation move; ``others`` gives the rest their poses). Each step
moves every needle, steps the tissue once, then applies each needle's constraints in turn (a
Gauss-Seidel sweep over the needles), so one needle's push moves the tissue under the others.
The needles do not touch each other (no needle-needle contact).
"""
import math
import time
from pathlib import Path

import numpy as np
import yaml

from tissue_sim_ros.engine.compiled.clock import AVAILABLE as CLOCKS_IN_COMPILED_CODE
from tissue_sim_ros.engine.compiled.substeps import CompiledSubsteps
from tissue_sim_ros.engine.mesh.selectors import RegionSelectors
from tissue_sim_ros.engine.mesh.tetmesh import make_mesh
from tissue_sim_ros.engine.needle.interaction import NeedleTissue, slerp
from tissue_sim_ros.engine.needle.pose import needle_axis
from tissue_sim_ros.engine.scene.build import (build_gravity, build_material, build_mesh, build_model,
                                               build_simulation, build_supports, check_combinations, check_time_step,
                                               needle_geometry, point_sets_of, region_interaction)
from tissue_sim_ros.engine.scene.checks import apply_schema
from tissue_sim_ros.engine.scene.keys import apply_overrides, set_keys
from tissue_sim_ros.engine.scene.schema import SCHEMA
from tissue_sim_ros.engine.scene.targets import Targets
from tissue_sim_ros.engine.scene.variation import drawn_regions
from tissue_sim_ros.errors import SceneError
from tissue_sim_ros.system.paths import shared_file


def default_scene_path():
    """The packaged default scene, config/liver_sample.yaml (source tree or installed share/)."""
    return shared_file('config/liver_sample.yaml')


def _element_regions(mesh, selectors):
    centroids = mesh.rest_positions[mesh.tetrahedra].mean(axis=1)
    index = selectors.element_regions(centroids)
    if np.any(index < 0):
        raise SceneError(f'regions: {int(np.sum(index < 0))} elements (first {int(np.argmax(index < 0))}) '
                         f'belong to no region; add a region with select: all first')
    return index


def surface_gap(mesh, tip, axis, displacement=None):
    """Distance [m] from ``tip`` along ``axis`` to the surface of ``mesh`` at rest, or displaced
    by ``displacement`` (a settled state) (inf: none)."""
    from tissue_sim_ros.engine.needle.kernels import first_surface_hit
    moved = np.zeros_like(mesh.rest_positions) if displacement is None else displacement
    hit, t, _, _, _ = first_surface_hit(mesh.rest_positions, moved,
                                        np.ascontiguousarray(mesh.surface_triangles(), dtype=np.int64),
                                        np.asarray(tip, dtype=float), np.asarray(axis, dtype=float),
                                        0.0, np.inf)
    return float(t) if hit >= 0 else float('inf')


def _start_position(mesh, needle, displacement=None):
    """needle.initial_position_m, moved along the axis so that the tip is needle.start_gap_m
    above the surface (settled, with ``displacement``) when that key is given."""
    position = np.asarray(needle['initial_position_m'], dtype=float)
    if needle['start_gap_m'] is None:
        return position
    from tissue_sim_ros.engine.needle.pose import validate_pose
    position, orientation = validate_pose(position, needle['initial_orientation_xyzw'], 'needle.initial_pose')
    axis = needle_axis(orientation)
    gap = surface_gap(mesh, position + needle['length_m'] * axis, axis, displacement)
    if not np.isfinite(gap):
        raise SceneError(f"needle.start_gap_m = {needle['start_gap_m']!r}: the needle's axis from "
                         f'initial_position_m {position.tolist()} meets no tissue surface')
    return position + (gap - needle['start_gap_m']) * axis


class Scene:
    """A ready-to-run needle insertion scene (see the module docstring)."""

    def __init__(self, spec, text='', base_dir='.', mesh_frame_id='world', auto_choices=None):
        """``spec``: the scene's keys (checked here against the schema); ``auto_choices``: how the
        layer above resolved ``model: auto`` and ``solver.mass_scaling: auto`` into these keys
        (:meth:`from_file`'s ``resolve_auto``), kept for reports."""
        self.spec = apply_schema('', _auto_model_section(spec), SCHEMA)
        _refuse_auto_keys(self.spec)
        check_combinations(self.spec)
        self.auto_choices = dict(auto_choices or {})
        self.text = text
        self.base_dir = Path(base_dir)
        self.mesh_frame_id = mesh_frame_id
        s = self.spec
        #: this run's regions (the spread between repeats drawn: engine.scene.variation) and what was drawn
        regions, self.drawn = drawn_regions(s)
        raw_mesh = build_mesh(s['mesh'], self.base_dir)
        self.selectors = RegionSelectors(regions, raw_mesh.element_tags)
        element_region = _element_regions(raw_mesh, self.selectors)
        self.mesh = make_mesh(raw_mesh.rest_positions, raw_mesh.tetrahedra, element_region)
        materials = {k: build_material(r) for k, r in enumerate(regions) if np.any(element_region == k)}
        self.model = build_model(self.mesh, materials, s['model'])
        self.simulation = build_simulation(self.model, s['solver'])
        build_supports(self.simulation, self.mesh, s['boundary'], point_sets_of(s, self.base_dir))
        self.simulation.scale_selected_masses(s['solver']['selective_mass_scaling'])  # 1 unless explicit
        check_time_step(self.simulation, s['solver'])
        #: how the tissue settled under gravity (engine.solver.settle), None without it
        self.settled = build_gravity(self.simulation, s['solver'],
                                     repr([s[k] for k in ('mesh', 'regions', 'model', 'boundary')]))
        interactions = [region_interaction(r) for r in regions]
        self.needle_names, self.needles = [], []
        for i, (name, n) in enumerate(needle_sections(s)):
            geometry = needle_geometry(n, f'needles[{i}]' if s['needles'] else 'needle')
            self.needle_names.append(name)
            self.needles.append(NeedleTissue(self.simulation, element_region, interactions, geometry,
                                             _start_position(self.mesh, n, self.simulation.displacement),
                                             n['initial_orientation_xyzw'],
                                             selectors=self.selectors,
                                             name=f'needles[{i}]' if s['needles'] else 'needle'))
        self.needle = self.needles[0]
        self.targets = Targets(self.mesh.rest_positions, self.mesh.tetrahedra, s['targets'],
                               element_region=element_region, region_names=[r['name'] for r in s['regions']])
        self._target_time = 0.0
        #: run the substeps of a needle outside, at the outer membrane or inside in compiled
        #: slices (engine.compiled.substeps; False: the Python calls, the same arithmetic)
        self.compiled_substeps = True
        self._compiled = None
        self.element_region = element_region
        self.region_names = [r['name'] for r in s['regions']]

    @classmethod
    def from_file(cls, path=None, sets=(), values=None, resolve_auto=None, **sections):
        """Load a scene YAML (default: the packaged liver sample): :func:`read_scene_keys`, then
        ``resolve_auto(spec, base_dir) -> (spec, choices)`` for ``model: auto`` and
        ``solver.mass_scaling: auto``; the engine cannot choose them (the recommendation runs the
        analysis layer's chart), so without it such a scene is refused naming the key."""
        spec, text, base_dir = read_scene_keys(path, sets, values, **sections)
        choices = None
        if resolve_auto is not None and auto_keys(spec):
            spec, choices = resolve_auto(spec, base_dir)
        return cls(spec, text=text, base_dir=base_dir, auto_choices=choices)

    def copy(self):
        """A new scene from the same keys (at rest, its own arrays)."""
        return Scene(self.spec, text=self.text, base_dir=self.base_dir, mesh_frame_id=self.mesh_frame_id,
                     auto_choices=self.auto_choices)

    # -- stepping ---------------------------------------------------------------------------------
    @property
    def dt(self):
        return self.simulation.dt

    @property
    def time(self):
        return self.simulation.time

    def advance(self, duration, position, orientation, deadline=None, max_steps=None, others=None):
        """Move the needle to the given base pose over ``duration`` [s]; returns the substeps run.

        Runs the whole steps that end by the running target time (the sum of all durations since
        reset, ``target_time``); the needle ends on its way to the pose, less than one step before
        it, and reaches it in the next call. ``deadline`` (a time.perf_counter() value): no step
        starts that would, by the last step's wall time, end past it; the steps left are run by
        the next call (duration 0 runs just those), so a real-time caller keeps its slots.
        ``max_steps`` stops the same way after that many steps (a replay of a run that a deadline
        stopped). ``others``: with several needles, a (position, orientation) or None (held) for
        each of ``needles[1:]``, moved the same way.
        Raises PoseError (before any state changes) for a bad pose, SimulationDiverged if
        the tissue diverges.
        """
        if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration >= 0):
            raise SceneError(f'duration = {duration!r}: expected a finite time >= 0 s')
        sim = self.simulation
        targets = [(position, orientation)] + list(others if others is not None else [None] * (len(self.needles) - 1))
        if len(targets) != len(self.needles):
            raise SceneError(f'others: {len(targets) - 1} poses for {len(self.needles) - 1} other needle(s)')
        moves = []
        for k, (needle, target) in enumerate(zip(self.needles, targets)):
            if target is None:
                target = needle.position.copy(), needle.orientation.copy()
            field_name = 'pose' if k == 0 else f'needles[{self.needle_names[k]}].pose'
            p, q = needle.check_pose(target[0], target[1], field_name)
            start_p, start_q = needle.position.copy(), needle.orientation.copy()
            moves.append((needle, start_p, p, p - start_p, np.empty(3), start_q, q, start_q.tolist() != q.tolist()))
        # whole steps toward a running target time, so the remainders of successive calls add up
        # instead of being dropped (20 ms calls with a 1.7 ms step would otherwise run 20.6 ms).
        # No step ends past the target: a step that did would hold the needle at the target for
        # part of it, a velocity dip whose inertial force the bonded contact reports at exactly
        # the step a caller samples (-0.06 N at 10 mm/s, 25x mass scaling, every third tick).
        # The needle stays on its segment at the pose for the simulation's time, and the next
        # call goes on from there at the same speed.
        start_t, end_t = sim.time, self._target_time + duration
        self._target_time = end_t
        steps = 0
        step_wall = 0.0
        # one needle translating, explicit, nothing prescribed: the substeps it allows run in
        # compiled slices (engine.compiled.substeps); the same arithmetic
        compiled = None
        if self.compiled_substeps and CLOCKS_IN_COMPILED_CODE and len(moves) == 1 and not moves[0][7] \
                and sim.integrator == 'explicit' and not sim.has_prescribed:
            if self._compiled is None:
                self._compiled = CompiledSubsteps(self)
            compiled = self._compiled
            compiled.begin(moves[0][1], moves[0][3])
        while sim.time + sim.dt <= end_t + 1e-9 * sim.dt:
            if max_steps is not None and steps >= max_steps:
                return steps
            if deadline is not None:
                now = time.perf_counter()
                if now + step_wall > deadline:
                    return steps
            if compiled is not None and compiled.ready():
                ran, step_wall = compiled.run(start_t, end_t, None if max_steps is None else max_steps - steps,
                                              deadline, step_wall)
                steps += ran
                continue
            s = min(1.0, (sim.time + sim.dt - start_t) / (end_t - start_t))
            for needle, start_p, _, move, position, start_q, q, turning in moves:
                np.multiply(move, s, out=position)     # start + s * move, no array made a step
                position += start_p
                needle.set_pose(position, slerp(start_q, q, s) if turning else None)
            sim.step(1)
            for needle in self.needles:
                needle.after_step(sim.dt)
            if compiled is not None:
                compiled.invalidate()
            steps += 1
            if deadline is not None:
                step_wall = time.perf_counter() - now
        if duration == 0 and steps == 0:
            for needle, _, p, _, _, _, q, _ in moves:
                needle.set_pose(p, q)
                needle.set_pose(p, q)   # no step: no velocity from a pose change
        return steps

    def drop_behind(self, max_behind_s):
        """Owe the simulation at most ``max_behind_s`` [s]: a running target time further ahead
        of it is pulled back (the needle then reaches its pose in that much less simulated time).
        Returns the simulated seconds dropped. The node's rule when its engine cannot keep up."""
        excess = self._target_time - self.simulation.time - max_behind_s
        if excess <= 0.0:
            return 0.0
        self._target_time -= excess
        return excess

    @property
    def target_time(self):
        """The running target time [s]: the sum of the durations asked of ``advance`` since reset
        (the simulation is less than one step short of it, or more where a deadline stopped it)."""
        return self._target_time

    def reset(self):
        """Rest state, needle at its initial pose, time 0."""
        self.simulation.reset()
        np.copyto(self.simulation.external_forces, self.simulation.body_forces)
        for needle in self.needles:
            needle.reset()
        self._target_time = 0.0

    def place_needle(self, position, orientation, needle=0):
        """Start needle ``needle`` (its index) at this pose from now on, resets included
        (``NeedleTissue.set_start``: refused while it touches the tissue or inside it)."""
        name = f'{self.needle_names[needle]}.start' if len(self.needles) > 1 else 'needle.start'
        self.needles[needle].set_start(position, orientation, name)

    # -- state ----------------------------------------------------------------------------------
    def reaction_wrench(self, frame='world', needle=0):
        """(force, torque) the tissue exerts on needle ``needle`` (its index) [N, N m]."""
        return self.needles[needle].reaction_wrench(frame)

    @property
    def phase(self):
        return self.needle.phase

    @property
    def tip_depth(self):
        return self.needle.tip_depth()

    @property
    def tip(self):
        """The first needle's tip [m] (world): where its apex is, the rod's for a flexible one."""
        return self.needle.tip.copy()

    @property
    def tip_deflection(self):
        """The first needle's tip distance from its base frame's axis [m] (0 for a rigid one)."""
        return self.needle.tip_deflection()

    def target_positions(self):
        """(k, 3) where the scene's targets are now [m] (engine.scene.targets)."""
        return self.targets.positions(self.simulation.displacement)

    def targets_relative_to_needle(self):
        """(tip distance, lateral miss, ahead of the tip), each (k,) [m], per target."""
        return self.targets.relative_to_needle(self.target_positions(), self.needle.tip, self.needle.axis)

    @property
    def start_gap_m(self):
        """Tip to tissue surface along the axis at the needle's initial pose [m] (rest mesh)."""
        position, orientation = self.initial_needle_pose
        axis = needle_axis(orientation)
        return surface_gap(self.mesh, position + self.needle.geometry.length_m * axis, axis,
                           self.simulation.initial_displacement)

    @property
    def initial_needle_pose(self):
        """(position, orientation) the first needle starts from and a reset returns it to (copies)."""
        return tuple(a.copy() for a in self.needle._initial_pose)

    @property
    def needle_pose(self):
        return self.needle.position.copy(), self.needle.orientation.copy()

    @property
    def rest_positions(self):
        return self.mesh.rest_positions

    @property
    def displacement(self):
        return self.simulation.displacement

    def surface_triangles(self):
        return self.model.mesh.surface_triangles() if self.model.topology_version == 0 else \
            _current_surface(self.model)

    @property
    def topology_version(self):
        return self.model.topology_version

    @property
    def puncture_events(self):
        return self.needle.puncture_events


def needle_sections(spec):
    """[(name, needle section)] of a scene's keys: the ``needle`` section alone, named 'needle',
    or one per ``needles`` entry, its keys over the needle section's (checked, errors named
    ``needles[i].key``)."""
    if not spec['needles']:
        return [('needle', spec['needle'])]
    return [(entry['name'], apply_schema(f'needles[{i}]', merge(spec['needle'], {k: v for k, v in entry.items()
                                                                             if k != 'name'}), SCHEMA['needle']))
            for i, entry in enumerate(spec['needles'])]


def read_scene_keys(path=None, sets=(), values=None, **sections) -> tuple[dict, str, Path]:
    """(checked scene keys, the file's text, its directory) of a scene YAML (default: the
    packaged liver sample). ``sections`` replace top-level sections key by key
    (``model={'viscosity_mu_pa_s': 0.0}``); then ``sets`` (``KEY=VALUE`` texts, the ``--set`` of
    the commands) and ``values`` (``{key path: value}``) are set in order (:mod:`.keys`)."""
    path = Path(path) if path is not None else default_scene_path()
    try:
        text = path.read_text()
    except OSError as exc:
        raise SceneError(f'scene_file = {str(path)!r}: {exc.strerror}') from exc
    try:
        spec = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SceneError(f'scene_file = {str(path)!r}: not valid YAML ({exc})') from exc
    if spec is not None and not isinstance(spec, dict):
        raise SceneError(f'scene_file = {str(path)!r}: expected a mapping of scene keys at the top '
                         f'level, found a {type(spec).__name__}')
    if not spec:
        # the built-in defaults are not a tissue anyone measured: an empty file is a mistake
        raise SceneError(f'scene_file = {str(path)!r}: no scene keys (an empty file runs every built-in '
                         'default, a tissue with no membrane: the force stays 0 N); give the keys, start '
                         'from config/liver_sample.yaml, or leave the scene out for that packaged scene')
    spec = set_keys(apply_overrides(merge(_auto_model_section(spec), sections), sets), values)
    return apply_schema('', spec, SCHEMA), text, path.parent


def auto_keys(spec: dict) -> list[str]:
    """The keys of checked scene keys ``spec`` that ask the layer above to choose
    (``model.auto: true``, ``solver.mass_scaling: auto``)."""
    return ((['model.auto'] if spec['model']['auto'] else [])
            + (['solver.mass_scaling'] if spec['solver']['mass_scaling'] == 'auto' else []))


def _refuse_auto_keys(spec: dict) -> None:
    found = auto_keys(spec)
    if found:
        value = 'true' if found[0] == 'model.auto' else "'auto'"
        raise SceneError(f'{found[0]} = {value}: chosen by measuring the scene (tissue-sim recommend, the '
                         "mass-scaling rule), which the engine cannot do: load the scene through "
                         'tissue-sim or tissue_sim_node (they resolve it) or give the concrete keys')


def _auto_model_section(spec):
    """`model: auto` is short for `model: {auto: true}` (the full model's keys at their defaults)."""
    if isinstance(spec, dict) and spec.get('model') == 'auto':
        return dict(spec, model={'auto': True})
    return spec


def scene_yaml(spec, base_dir='.', header=()) -> str:
    """A complete scene file's text: ``header`` as comment lines, then every key of ``spec`` (a
    mesh file made absolute from ``base_dir``, so the file loads from anywhere)."""
    import json
    spec = json.loads(json.dumps(spec))
    if spec['mesh'].get('file'):
        spec['mesh']['file'] = str((Path(base_dir) / spec['mesh']['file']).resolve())
    comments = ''.join(f'# {line}\n' for line in header)
    return comments + yaml.safe_dump(spec, sort_keys=False)


def _current_surface(model):
    from tissue_sim_ros.engine.mesh.tetmesh import surface_triangles
    return surface_triangles(model.tetrahedra, model.mesh.rest_positions)


def merge(base, overrides):
    """Recursive dict merge: ``overrides`` wins key by key (lists are replaced whole)."""
    out = dict(base)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out
