"""The house's rules, read from the sources: layers one way, no import loops, small modules in
small folders, a map in every package, no history in the code, every file it cites there, and
tests that mirror the package."""

import ast
import re
from pathlib import Path

import pytest

from support.paths import ROOT

PACKAGE = ROOT / 'tissue_sim_ros'

#: layers bottom up: a module may import its own layer and those below, never one above
LAYERS = (('tissue_sim_ros.errors', 'tissue_sim_ros.units', 'tissue_sim_ros.system'),
          ('tissue_sim_ros.engine',),
          ('tissue_sim_ros.meshing',),
          ('tissue_sim_ros.io',),
          ('tissue_sim_ros.ros',),
          ('tissue_sim_ros.analysis',),
          ('tissue_sim_ros.bench',),
          ('tissue_sim_ros.cli', 'tissue_sim_ros.client'))
MAX_LINES, MAX_KERNEL_SET_LINES, MAX_MODULES_PER_FOLDER = 500, 800, 15
_COMPILED = re.compile(r'@(numba\.)?(njit|jit|register_jitable|intrinsic|overload)\b')


def _modules():
    """{dotted name: path} of every module of the package."""
    found = {}
    for path in sorted(PACKAGE.rglob('*.py')):
        parts = path.relative_to(ROOT).with_suffix('').parts
        name = '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)
        found[name] = path
    return found


MODULES = _modules()


def _imports(name: str, path: Path) -> set:
    """The package's modules ``name`` imports, at any depth of the file (a function's lazy
    import is an import too)."""
    tree = ast.parse(path.read_text())
    package = name if path.name == '__init__.py' else name.rsplit('.', 1)[0]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                base = '.'.join(package.split('.')[:len(package.split('.')) - node.level + 1] + ([base] if base else []))
            targets = [f'{base}.{alias.name}' for alias in node.names] + [base]
        else:
            continue
        for target in targets:
            while target and target not in MODULES:
                target = target.rpartition('.')[0]
            if target and target != name and target.startswith('tissue_sim_ros'):
                out.add(target)
    return out


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def _layer(name: str) -> int:
    for rank, prefixes in enumerate(LAYERS):
        if any(name == p or name.startswith(p + '.') for p in prefixes):
            return rank
    return 0                                        # the package's own __init__: the ground


def test_no_import_runs_from_a_lower_layer_to_a_higher_one():
    upward = [f'{a} -> {b}' for a, targets in GRAPH.items() for b in sorted(targets)
              if _layer(b) > _layer(a) and a != 'tissue_sim_ros']
    assert not upward, 'imports that run up a layer:\n' + '\n'.join(upward)


def _strongly_connected(graph):
    """Tarjan's components of ``graph`` (iterative)."""
    index, low, on_stack, stack, components, counter = {}, {}, set(), [], [], [0]
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter[0]
                    counter[0] += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                components.append(component)
    return components


def test_the_loop_finder_finds_a_loop():
    graph = {'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': {'a'}}
    assert sorted(map(sorted, (c for c in _strongly_connected(graph) if len(c) > 1))) == [['a', 'b', 'c']]


def test_no_import_loops():
    # a package imports its own modules through its __init__ only to hand names on: not a loop
    graph = {a: {b for b in targets if not (a.startswith(b + '.') and MODULES[b].name == '__init__.py')}
             for a, targets in GRAPH.items()}
    loops = [sorted(c) for c in _strongly_connected(graph) if len(c) > 1]
    assert not loops, 'import loops:\n' + '\n'.join(' <-> '.join(c) for c in loops)


def _is_kernel_set(text: str) -> bool:
    """Most of its functions compiled by numba: a kernel set, allowed to be longer."""
    functions = len(re.findall(r'^\s*def ', text, re.M))
    return functions > 0 and len(_COMPILED.findall(text)) * 2 >= functions


def test_modules_are_small():
    big = []
    for name, path in MODULES.items():
        text = path.read_text()
        lines = text.count('\n')
        limit = MAX_KERNEL_SET_LINES if _is_kernel_set(text) else MAX_LINES
        if lines > limit:
            big.append(f'{name}: {lines} lines (at most {limit})')
    assert not big, '\n'.join(big)


def test_folders_hold_few_modules():
    crowded = []
    for folder in [PACKAGE, *(p for p in PACKAGE.rglob('*') if p.is_dir() and p.name != '__pycache__')]:
        modules = [p for p in folder.glob('*.py') if p.name not in ('__init__.py', '__main__.py')]
        if len(modules) > MAX_MODULES_PER_FOLDER:
            crowded.append(f'{folder.relative_to(ROOT)}: {len(modules)} modules')
    assert not crowded, '\n'.join(crowded)


def test_every_package_has_a_map_and_names_what_it_offers():
    missing = []
    for init in PACKAGE.rglob('__init__.py'):
        tree = ast.parse(init.read_text())
        doc = ast.get_docstring(tree) or ''
        names = {t.id for node in tree.body if isinstance(node, ast.Assign) for t in node.targets
                 if isinstance(t, ast.Name)}
        if len(doc) < 40 or '__all__' not in names:
            missing.append(str(init.relative_to(ROOT)))
        if init.parent != PACKAGE:
            for module in init.parent.glob('*.py'):
                if module.name not in ('__init__.py', '__main__.py') and module.stem not in doc:
                    missing.append(f'{init.relative_to(ROOT)}: its map does not name {module.stem}')
    assert not missing, '\n'.join(missing)


_HISTORY = re.compile(r'\bissues? ?#?\d+|\bbefore \(?[0-9a-f]{7,}\b|\bcommit [0-9a-f]{7,}\b', re.I)


@pytest.mark.parametrize('folder', ['tissue_sim_ros', 'test'])
def test_no_source_line_names_an_issue_or_a_commit(folder):
    found = [f'{path.relative_to(ROOT)}:{n}: {line.strip()}'
             for path in sorted((ROOT / folder).rglob('*.py'))
             for n, line in enumerate(path.read_text().splitlines(), 1) if _HISTORY.search(line)]
    assert not found, '\n'.join(found)


def test_the_history_pattern_catches_what_it_should():
    issue, commit = 'issue' + ' 17', '645b' + '762'          # spelled apart: this file is read too
    assert _HISTORY.search(f'# see {issue} item 2') and _HISTORY.search(f'(before ({commit}))')
    assert not _HISTORY.search('the tissue before the puncture') and not _HISTORY.search('0x7fffffff')


_CITED = re.compile(r'\b((?:docs|config|data|msg_examples|test)/[\w./-]+\.(?:md|yaml|csv|py)|'
                    r'(?:engine|io|ros|analysis|bench|cli|system)/[\w/]+\.py|[A-Z]+\.md)\b')


def test_every_file_the_sources_cite_exists():
    """A docstring or comment that sends the reader to a file names one that is there (paths
    under the package are read from it)."""
    missing = []
    for path in sorted(PACKAGE.rglob('*.py')):
        for n, line in enumerate(path.read_text().splitlines(), 1):
            for cited in _CITED.findall(line):
                if cited in ('README.md',) or (ROOT / cited).exists() or (PACKAGE / cited).exists():
                    continue
                missing.append(f'{path.relative_to(ROOT)}:{n}: {cited}')
    assert not missing, '\n'.join(missing)


TESTS = ROOT / 'test'
#: folders of test/ that mirror no package: shared helpers
TEST_HELPERS = ('support',)


def _test_folders():
    return [p for p in TESTS.rglob('*') if p.is_dir() and p.name != '__pycache__'
            and p.relative_to(TESTS).parts[0] not in TEST_HELPERS]


def test_every_test_file_in_a_mirrored_folder_names_a_module_there():
    """test/<path>/test_<name>.py tests tissue_sim_ros/<path>/<name>.py: a file whose module
    was renamed, moved or removed is found here, not by a reader looking for its tests."""
    orphans = [str(path.relative_to(ROOT)) for folder in _test_folders()
               for path in sorted(folder.glob('test_*.py'))
               if not (PACKAGE / folder.relative_to(TESTS) / f'{path.stem[len("test_"):]}.py').is_file()]
    assert not orphans, 'test files that name no module:\n' + '\n'.join(orphans)


def test_the_tests_mirror_the_sub_packages_and_nothing_else():
    """test/ holds a folder for each sub-package (test/engine/needle for engine/needle), every
    folder of test/ but the helpers' is one, and none is a Python package: a test/io/__init__.py
    would shadow the standard library's io (pytest imports the tests in importlib mode)."""
    packages = {init.parent.relative_to(PACKAGE) for init in PACKAGE.rglob('__init__.py')
                if init.parent != PACKAGE}
    folders = {folder.relative_to(TESTS) for folder in _test_folders()}
    assert sorted(map(str, packages - folders)) == [], 'sub-packages without their test folder'
    assert sorted(map(str, folders - packages)) == [], 'test folders that mirror no sub-package'
    assert sorted(str(p.relative_to(ROOT)) for p in TESTS.rglob('__init__.py')) == []
