"""The package's folders are layers: no module imports from a layer above its own (issue 12).

Inside core/: the base modules (core/*.py) < model/, serial/, vision/ < scenario/, control/ <
sim/. Around it: core < hw < ros < nodes < tools. A module may import its own layer and those
below; nodes may compose other nodes (team, system). Every import counts, at module level or
inside a function.
"""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / 'ament_formation'

# rank of each folder: an import must go to a rank <= the importer's (same folder always allowed)
CORE_RANK = {'': 0, 'model': 1, 'serial': 1, 'vision': 1, 'scenario': 2, 'control': 2, 'sim': 3}
TOP_RANK = {'core': 0, 'hw': 1, 'ros': 2, 'nodes': 3, 'tools': 4}


def layer_of(module: str) -> tuple[int, int, str] | None:
    """(package rank, core rank, folder) of a dotted ``ament_formation...`` module, else None."""
    parts = module.split('.')
    if parts[0] != 'ament_formation' or len(parts) < 2:
        return None
    top = parts[1]
    if top not in TOP_RANK:
        return None  # ament_formation/__init__ itself
    if top != 'core':
        return TOP_RANK[top], 0, top
    folder = parts[2] if len(parts) > 3 and parts[2] in CORE_RANK else ''
    return 0, CORE_RANK[folder], f'core/{folder}'.rstrip('/')


def module_name(path: Path) -> str:
    rel = path.relative_to(PKG.parent).with_suffix('')
    parts = rel.parts[:-1] if rel.name == '__init__' else rel.parts
    return '.'.join(parts)


def imports(path: Path):
    tree = ast.parse(path.read_text(), filename=str(path))
    pkg = module_name(path).rsplit('.', 0 if path.name == '__init__.py' else 1)[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split('.')[: len(pkg.split('.')) - node.level + 1]
                mod = '.'.join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ''
            # `from ament_formation.core.sim import metrics` imports the module sim.metrics
            yield from (f'{mod}.{a.name}' for a in node.names)


def violations(root: Path = PKG) -> list[str]:
    out = []
    for path in sorted(root.rglob('*.py')):
        me = layer_of(module_name(path))
        if me is None:
            continue
        for mod in imports(path):
            other = layer_of(mod)
            if other is None or other[2] == me[2]:
                continue
            if other[:2] > me[:2]:
                out.append(f'{path.relative_to(root)} ({me[2]}) imports {mod} ({other[2]})')
    return out


def test_no_module_imports_from_a_layer_above_it():
    assert violations() == []


def test_nodes_import_only_core_ros_hw_and_nodes():
    bad = [
        f'{path.name}: {mod}'
        for path in sorted((PKG / 'nodes').glob('*.py'))
        for mod in imports(path)
        if mod.startswith('ament_formation.')
        and mod.split('.')[1] not in ('core', 'ros', 'hw', 'nodes')
    ]
    assert bad == []


def test_the_check_sees_an_upward_import(tmp_path):
    pkg = tmp_path / 'ament_formation'
    (pkg / 'core' / 'model').mkdir(parents=True)
    (pkg / 'ros').mkdir()
    (pkg / 'core' / 'model' / 'dynamics.py').write_text(
        'from ament_formation.core.sim import simulator\n'
        'def f():\n    from ament_formation.ros import qos\n'
    )
    (pkg / 'ros' / 'qos.py').write_text('from ament_formation.nodes.controller import X\n')
    global PKG
    saved, PKG = PKG, pkg
    try:
        found = violations(pkg)
    finally:
        PKG = saved
    assert found == [
        'core/model/dynamics.py (core/model) imports '
        'ament_formation.core.sim.simulator (core/sim)',
        'core/model/dynamics.py (core/model) imports ament_formation.ros.qos (ros)',
        'ros/qos.py (ros) imports ament_formation.nodes.controller.X (nodes)',
    ]
